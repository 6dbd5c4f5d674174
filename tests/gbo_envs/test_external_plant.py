"""ExternalPlantEnv: a user's experiment function behind the env API, with the built-in envs' metrics and cost."""

from __future__ import annotations

import subprocess
import sys
import threading

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import agents
import gbo_envs
from gbo_envs import CostSpec, FailurePolicy, PIController, PlantStructure, StepExperiment
from gbo_envs.closed_loop import ClosedLoop
from gbo_envs.envs.dc_motor import dc_motor_plant
from gbo_envs.envs.external import ExperimentFailed, ExternalPlantEnv
from tests.support import DC_MOTOR_PARAMS, REPO_ROOT


def _runner(loop: ClosedLoop):
    """A user's rig function that runs the DC motor loop."""
    def run_experiment(gains):
        response = loop.simulate(np.asarray(gains)[None, :])
        return response.t, response.r, response.u[0], response.y[0]

    return run_experiment


def _external(dc_motor, run=None, **failure) -> ExternalPlantEnv:
    """The DC motor behind ExternalPlantEnv, with its normalisers; ``failure``: FailurePolicy settings."""
    low, high = dc_motor.action_space.low, dc_motor.action_space.high
    return ExternalPlantEnv(run or _runner(dc_motor.loop), np.column_stack([low, high]), controller=PIController(),
                            experiment=StepExperiment((245.0, 306.0), dt=0.002, duration=5.0),
                            cost=CostSpec(normalizers=dc_motor.normalizers), failure_policy=FailurePolicy(**failure))


def test_costs_identical_to_dc_motor_noise_free(dc_motor):
    low, high = dc_motor.action_space.low, dc_motor.action_space.high
    calls = []
    run = _runner(dc_motor.loop)
    env = ExternalPlantEnv(lambda g: calls.append(g) or run(g), {"Kp": (low[0], high[0]), "Ki": (low[1], high[1])},
                           experiment=StepExperiment((245.0, 306.0), dt=0.002, duration=5.0), controller=PIController(),
                           reference_gains=np.linspace(low, high, 5))
    # measuring the normalisers cost 5 experiments, and gives the built-in env's normalisers exactly
    assert len(calls) == 5 and len(env.reference_records) == 5
    np.testing.assert_array_equal(env.normalizers, dc_motor.normalizers)
    reference = gym.make("gbo_envs/DCMotor-v0", noise=False)
    env.reset(seed=0)
    reference.reset(seed=0)
    rng = np.random.default_rng(4)
    for _ in range(6):
        gains = low + rng.random(2) * (high - low)
        obs, reward, _, _, info = env.step(gains)
        obs_ref, reward_ref, _, _, info_ref = reference.step(gains)
        assert info["cost"] == info_ref["cost"] == -reward
        assert info["metrics"] == info_ref["metrics"]
        np.testing.assert_array_equal(obs, obs_ref)
        np.testing.assert_array_equal(info["y"], info_ref["y"])
        assert info["failed"] is False and "true_cost" not in info
    assert env.experiment_index == 6 and len(calls) == 11


def test_gymnasium_checks_and_every_tuner_api(dc_motor):
    env = _external(dc_motor)
    check_env(env, skip_render_check=True)
    assert env.gain_names == ("Kp", "Ki")
    result = agents.make("random").run(env, budget=4, seed=1)
    reference = agents.make("random").run(gym.make("gbo_envs/DCMotor-v0", noise=False), budget=4, seed=1)
    assert [row["cost"] for row in result.plant_rows] == [row["cost"] for row in reference.plant_rows]


def test_loop_builds_a_twin(dc_motor):
    from agents.twin import TwinEnv

    env = _external(dc_motor)
    model_loop = env.loop.replace(plant=dc_motor.loop.plant)
    assert model_loop.plant is dc_motor.loop.plant and env.loop.plant is not dc_motor.loop.plant
    gains = np.array([[0.5, 1.2], [0.9, 1.9]])
    np.testing.assert_array_equal(model_loop.simulate(gains).y, dc_motor.loop.simulate(gains).y)
    twin = TwinEnv(env, dc_motor_plant(*DC_MOTOR_PARAMS, 0.002))
    np.testing.assert_allclose(twin.evaluate(gains)[1], dc_motor.evaluate(gains)[1], rtol=1e-12)
    bare = ExternalPlantEnv(_runner(dc_motor.loop), [(0.1, 1.0), (0.5, 2.0)], experiment=StepExperiment((245, 306)),
                            cost=CostSpec(normalizers=dc_motor.normalizers))
    assert bare.gain_names == ("gain_0", "gain_1")
    with pytest.raises(ValueError, match="needs controller"):
        bare.loop.replace(plant=dc_motor.loop.plant)
    with pytest.raises(NotImplementedError):
        env.evaluate(gains)


def _malformed_cases(loop):
    good = _runner(loop)

    def edit(fn):
        return lambda g: fn(*[np.array(a, dtype=float) for a in good(g)])

    def with_nan(t, r, u, y):
        y[100] = np.nan
        return t, r, u, y

    def backwards(t, r, u, y):
        t[50] = t[49]
        return t, r, u, y

    return {
        "wrong lengths": (edit(lambda t, r, u, y: (t, r, u[:-1], y)), "must have equal lengths"),
        "NaN": (edit(with_nan), "y: must be finite, got nan"),
        "t not increasing": (edit(backwards), "t: must increase strictly, got 0.098 s at sample 50"),
        "three arrays": (edit(lambda t, r, u, y: (t, u, y)), "expected 4 arrays"),
        "not arrays": (lambda g: None, "expected (t, r, u, y)"),
        "wrong dt": (edit(lambda t, r, u, y: (2 * t, r, u, y)), "sample time"),
        "short": (edit(lambda t, r, u, y: (t[:1000], r[:1000], u[:1000], y[:1000])), "ends at"),
        "other reference": (edit(lambda t, r, u, y: (t, r - 30.0, u, y)), "r ends at"),
        "raises": (lambda g: 1 / 0, "ZeroDivisionError"),
        "mapping without y": (lambda g: {"t": [0, 1], "r": [0, 1], "u": [0, 1]}, "lacks y"),
    }


def test_malformed_records_fail_loudly_with_a_reason(dc_motor, caplog):
    cases = _malformed_cases(dc_motor.loop)
    for label, (fn, reason) in cases.items():
        env = _external(dc_motor, run=fn, failure_cost=7.5)
        env.reset(seed=0)
        with caplog.at_level("WARNING", logger="gbo_envs.envs.external"):
            _, reward, _, _, info = env.step([0.5, 1.2])
        assert info["failed"] is True, label
        assert reason in info["failure_reason"], (label, info["failure_reason"])
        assert info["cost"] == -reward == 7.5
        assert "y" not in info and np.isnan(info["metrics"]["itae"])
        assert env.failures[0]["reason"] == info["failure_reason"] and env.experiment_index == 1
        assert info["failure_reason"] in caplog.text


def test_stop_and_skip_raise_with_the_record(dc_motor):
    for policy in ("stop", "skip"):
        env = _external(dc_motor, run=lambda g: 1 / 0, on_failure=policy)
        env.reset(seed=0)
        with pytest.raises(ExperimentFailed, match="ZeroDivisionError") as caught:
            env.step([0.5, 1.2])
        assert caught.value.policy == policy
        assert caught.value.record["failed"] is True and caught.value.record["experiment_index"] == 0
        assert env.experiment_index == 1


def test_timeout_runs_in_a_worker_and_blocks_until_the_rig_is_free(dc_motor):
    release = threading.Event()
    good = _runner(dc_motor.loop)
    calls = []

    def slow_first(gains):
        calls.append(1)
        if len(calls) == 1:
            release.wait(10.0)
        return good(gains)

    env = _external(dc_motor, run=slow_first, timeout_s=0.2)
    env.reset(seed=0)
    _, _, _, _, info = env.step([0.5, 1.2])
    assert info["failed"] and "timed out after 0.2 s" in info["failure_reason"]
    _, _, _, _, info = env.step([0.5, 1.2])  # the first call still hangs: the rig is not touched again
    assert info["failed"] and "rig busy" in info["failure_reason"] and len(calls) == 1
    release.set()
    _, _, _, _, info = env.step([0.5, 1.2])
    assert not info["failed"] and len(calls) == 2
    assert info["cost"] == dc_motor.evaluate(np.array([[0.5, 1.2]]))[1][0]


def test_argument_errors(dc_motor):
    run = _runner(dc_motor.loop)
    bounds, experiment = [(0.1, 1.0), (0.5, 2.0)], StepExperiment((245, 306))
    with pytest.raises(ValueError, match="normalizers=.*reference_gains"):
        ExternalPlantEnv(run, bounds, experiment=experiment)
    with pytest.raises(ValueError, match="reference"):
        StepExperiment((1.0, 1.0))
    with pytest.raises(ValueError, match="on_failure"):
        _external(dc_motor, on_failure="ignore")
    with pytest.raises(ValueError, match=r"gain_bounds: the gains \('Kp', 'Kd'\) differ from the controller's"):
        ExternalPlantEnv(run, {"Kp": (0.1, 1.0), "Kd": (0.5, 2.0)}, experiment=experiment, controller=PIController())
    with pytest.raises(ValueError, match="reference_gains: the experiment"):
        ExternalPlantEnv(lambda g: 1 / 0, bounds, experiment=experiment, reference_gains=[[0.5, 1.0]])
    with pytest.raises(TypeError, match="experiment: expected a StepExperiment"):
        ExternalPlantEnv(run, bounds, experiment=(245, 306))
    with pytest.raises(TypeError, match="positional"):
        ExternalPlantEnv(run, bounds, experiment)  # everything after the gain bounds is keyword-only
    with pytest.raises(ValueError, match="outside the feasible set"):
        _external(dc_motor).step([5.0, 1.0])
    assert "ExternalPlantEnv" in gbo_envs.__all__


@pytest.mark.parametrize(("make", "message"), [
    (lambda: StepExperiment((245, 306), dt=0.0), "dt: must be a number > 0 or None, got 0.0"),
    (lambda: StepExperiment((245, 306), dt=0.01, duration=0.01), "duration: must exceed dt = 0.01 s, got 0.01"),
    (lambda: StepExperiment((245, np.inf)), "reference: expected"),
    (lambda: StepExperiment((1, 2, 3)), "reference: expected"),
    (lambda: FailurePolicy(timeout_s=-1), "timeout_s: must be a number > 0 or None, got -1"),
    (lambda: FailurePolicy(failure_cost=np.nan), "failure_cost: must be finite, got nan"),
    (lambda: FailurePolicy(dt_rtol=0), "dt_rtol: must be > 0, got 0"),
    (lambda: PlantStructure(output="torque"), "output, n_integrators"),
    (lambda: PlantStructure(n_integrators=-1), "output, n_integrators"),
    (lambda: CostSpec(weights=(1, 1, 1)), "weights: expected 4 finite numbers"),
    (lambda: CostSpec(normalizers=(1, 1, 1, 0)), r"normalizers: every entry must be > 0"),
    (lambda: CostSpec(unstable_cost=np.inf), r"unstable_cost: must be a finite number > 0 .*, got inf"),
    (lambda: CostSpec(unstable_cost=0.0), r"unstable_cost: must be a finite number > 0 .*, got 0.0"),
])
def test_option_objects_check_their_settings(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_option_objects_are_frozen_values():
    assert StepExperiment((245, 306), dt=0.002) == StepExperiment((245.0, 306.0), dt=0.002)
    assert CostSpec(normalizers=np.ones(4)) == CostSpec(normalizers=(1, 1, 1, 1))
    assert hash(CostSpec(weights=np.ones(4))) == hash(CostSpec(weights=[1, 1, 1, 1]))
    with pytest.raises(AttributeError):
        FailurePolicy().on_failure = "stop"


@pytest.mark.slow
def test_example_runs(tmp_path):
    out = subprocess.run([sys.executable, str(REPO_ROOT / "examples" / "external_plant.py"), "--tuner", "random",
                          "--budget", "8", "--db", str(tmp_path / "rig.sqlite"), "--csv", str(tmp_path / "rig.csv")],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "8 experiments" in out.stdout and "1 failed" in out.stdout and "rig link dropped" in out.stdout
    import pandas as pd

    frame = pd.read_csv(tmp_path / "rig.csv")
    assert list(frame.columns[:7]) == ["experiment", "t", "r", "u", "y", "Kp", "Ki"]
    assert frame["experiment"].nunique() == 7  # the failed experiment has no record to export
