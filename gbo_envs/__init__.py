"""gbo-envs: motor plants as Gymnasium environments for data-efficient controller tuning.

Importing the package registers every environment (all ``register`` calls
live here, as in Gymnasium's classic_control)::

    import gymnasium as gym, gbo_envs
    env = gym.make("gbo_envs/DCMotor-v0")
"""

from __future__ import annotations

from gymnasium.envs.registration import register

from gbo_envs.closed_loop import ClosedLoop, StepResponse
from gbo_envs.controllers import CascadeController, PDT1Controller, PIController, PIDController
from gbo_envs.envs.base import ControllerTuningEnv
from gbo_envs.envs.cost_spec import CostSpec
from gbo_envs.envs.dc_motor import DCMotorPlant
from gbo_envs.envs.external import ExperimentFailed, ExternalPlantEnv, PlantStructure
from gbo_envs.envs.linear_motor import LinearMotorDrive, LinearMotorPlant
from gbo_envs.envs.linear_motor_cascade import CascadeDrive
from gbo_envs.envs.plant_options import MeasurementNoise
from gbo_envs.envs.rig_options import FailurePolicy, StepExperiment
from gbo_envs.experiment import Experiment, RecordError, validate_signals
from gbo_envs.ground_truth import FeasibleSet, GroundTruth, feasible_set, ground_truth
from gbo_envs.metrics import METRIC_NAMES, step_metrics, weighted_cost
from gbo_envs.physics.lti import ContinuousPlant

__all__ = [
    "CascadeController",
    "CascadeDrive",
    "ClosedLoop",
    "ContinuousPlant",
    "ControllerTuningEnv",
    "CostSpec",
    "DCMotorPlant",
    "Experiment",
    "ExperimentFailed",
    "ExternalPlantEnv",
    "FailurePolicy",
    "FeasibleSet",
    "GroundTruth",
    "LinearMotorDrive",
    "LinearMotorPlant",
    "METRIC_NAMES",
    "MeasurementNoise",
    "PDT1Controller",
    "PIController",
    "PIDController",
    "PlantStructure",
    "RecordError",
    "StepExperiment",
    "StepResponse",
    "feasible_set",
    "ground_truth",
    "step_metrics",
    "validate_signals",
    "weighted_cost",
    "ENV_IDS",
]

#: Every registered environment id.
ENV_IDS: list[str] = []


def _register(name: str, entry_point: str, max_episode_steps: int, **kwargs) -> None:
    env_id = f"gbo_envs/{name}"
    register(id=env_id, entry_point=entry_point, max_episode_steps=max_episode_steps, kwargs=kwargs)
    ENV_IDS.append(env_id)


_register("DCMotor-v0", "gbo_envs.envs.dc_motor:DCMotorEnv", max_episode_steps=35)
_register("DCMotorDrift-v0", "gbo_envs.envs.time_varying:DCMotorDriftEnv", max_episode_steps=35)
_register("DCMotorStep-v0", "gbo_envs.envs.time_varying:DCMotorStepEnv", max_episode_steps=35)
_register("DCMotorRig-v0", "gbo_envs.envs.rigs:DCMotorRigEnv", max_episode_steps=35)
_register("DCMotorPID-v0", "gbo_envs.envs.dc_motor_pid:DCMotorPIDEnv", max_episode_steps=35)
_register("LinearMotor-v0", "gbo_envs.envs.linear_motor:LinearMotorEnv", max_episode_steps=25)
_register("LinearMotorDrift-v0", "gbo_envs.envs.time_varying:LinearMotorDriftEnv", max_episode_steps=25)
_register("LinearMotorStep-v0", "gbo_envs.envs.time_varying:LinearMotorStepEnv", max_episode_steps=25)
_register("LinearMotorRig-v0", "gbo_envs.envs.rigs:LinearMotorRigEnv", max_episode_steps=25)
_register("LinearMotorCascade-v0", "gbo_envs.envs.linear_motor_cascade:LinearMotorCascadeEnv", max_episode_steps=50)
_register("LinearMotorCascadeRig-v0", "gbo_envs.envs.linear_motor_cascade_rig:LinearMotorCascadeRigEnv",
          max_episode_steps=50)
