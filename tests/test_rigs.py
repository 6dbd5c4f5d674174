"""Rig stand-ins: the documented effects are in the loop and change the cost surface, the loop stays sound."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs
from gbo_envs import ground_truth
from gbo_envs.physics.actuator import Saturation
from gbo_envs.physics.friction import CoulombFriction
from gbo_envs.physics.sensor import Quantization

ENCODER_STEP = 2 * np.pi / (2048 * 0.002)


def _grid(env, resolution):
    axes = [np.linspace(lo, hi, resolution) for lo, hi in zip(env.action_space.low, env.action_space.high)]
    return np.column_stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")])


def test_registered():
    for env_id, steps in (("gbo_envs/DCMotorRig-v0", 35), ("gbo_envs/LinearMotorRig-v0", 25)):
        assert env_id in gbo_envs.ENV_IDS
        assert gym.make(env_id).spec.max_episode_steps == steps


def test_dc_rig_effects():
    env = gym.make("gbo_envs/DCMotorRig-v0").unwrapped
    assert [type(b) for b in env.loop.effects] == [Saturation, CoulombFriction, Quantization]
    limit, friction, encoder = env.loop.effects
    assert limit.limit == 160.0 and friction.torque == 5.0
    assert encoder.step == pytest.approx(1.5339807878856412) and encoder.mode == "floor"
    # the identified plant underneath is DCMotor-v0's
    assert env.loop.plant == gym.make("gbo_envs/DCMotor-v0").unwrapped.loop.plant
    # the measured speed is a whole number of encoder increments per 2 ms sample
    env.reset(seed=0)
    info = env.step(np.array([0.6, 1.2]))[4]
    counts = info["y"] / ENCODER_STEP
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)


def test_linear_rig_effects():
    env = gym.make("gbo_envs/LinearMotorRig-v0").unwrapped
    assert [type(b) for b in env.loop.effects] == [Saturation, Quantization, CoulombFriction]
    assert [b.side for b in env.loop.effects] == ["actuator", "sensor", "actuator"]
    limit, sensor, friction = env.loop.effects
    assert limit.limit == 7.0 and sensor.step == 5e-6 and friction.torque == 0.5
    assert env.loop.plant == gym.make("gbo_envs/LinearMotor-v0").unwrapped.loop.plant
    env.reset(seed=0)
    info = env.step(np.array([5500.0, 45.0]))[4]
    steps = info["y"] / 5e-6
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)


@pytest.mark.parametrize(("rig_id", "model_id"), [("gbo_envs/DCMotorRig-v0", "gbo_envs/DCMotor-v0"),
                                                  ("gbo_envs/LinearMotorRig-v0", "gbo_envs/LinearMotor-v0")])
def test_rig_cost_surface_differs_from_the_identified_model(rig_id, model_id):
    rig = gym.make(rig_id).unwrapped
    model = gym.make(model_id).unwrapped
    grid = _grid(rig, 15)
    rig_metrics, rig_cost = rig.evaluate(grid)
    model_metrics, model_cost = model.evaluate(grid)
    assert np.max(np.abs(rig_cost - model_cost)) > 0.05
    assert not np.allclose(rig.normalizers, model.normalizers, rtol=0.02)
    # well-behaved over the whole feasible set: stable, bounded overshoot
    assert not np.any(rig_cost == rig.unstable_cost)
    assert rig_metrics[:, 0].max() < 50.0


def test_dc_rig_command_limit_winds_up_the_integrator():
    """The 160-unit limit clips the high-gain corner, whose overshoot grows (43 % instead of 35 %)."""
    rig = gym.make("gbo_envs/DCMotorRig-v0").unwrapped
    model = gym.make("gbo_envs/DCMotor-v0").unwrapped
    grid = _grid(rig, 20)
    rig_os = rig.evaluate(grid)[0][:, 0]
    model_os = model.evaluate(grid)[0][:, 0]
    assert model_os.max() == pytest.approx(35.5, abs=0.5)
    assert rig_os.max() == pytest.approx(42.8, abs=0.5)
    # the model asks up to 190 units there, above the limit
    response = model.loop.simulate(np.array([[1.10, 2.08]]))
    assert response.u.max() > 180.0


def test_linear_rig_friction_damps_and_leaves_a_small_offset():
    rig = gym.make("gbo_envs/LinearMotorRig-v0", noise=False).unwrapped
    model = gym.make("gbo_envs/LinearMotor-v0", noise=False).unwrapped
    grid = _grid(rig, 20)
    rig_response = rig.loop.simulate(grid)
    model_response = model.loop.simulate(grid)
    rig_os = rig.loop.metrics(rig_response)[:, 0]
    model_os = model.loop.metrics(model_response)[:, 0]
    assert rig_os.max() < model_os.max() - 4.0  # 16 % instead of 22 %
    # no integrator in the PDT1 controller: friction 0.5 A / Kp leaves at most ~0.1 mm, here <= 20 um
    offset = np.abs(rig_response.y[:, -1] - rig.loop.r2)
    assert offset.max() <= 20e-6 + 1e-12
    assert offset.max() > np.abs(model_response.y[:, -1] - model.loop.r2).max()


def test_linear_rig_optimum_stays_in_the_papers_region():
    truth = ground_truth("gbo_envs/LinearMotorRig-v0", resolution=50)
    kp, kd = truth.gains
    assert kp <= 5650.0 and kd >= 47.0


def test_rig_arguments():
    env = gym.make("gbo_envs/DCMotorRig-v0", command_limit=170.0, friction=0.0, encoder_lines=4096).unwrapped
    assert env.loop.effects[0].limit == 170.0 and env.loop.effects[1].torque == 0.0
    assert env.loop.effects[2].step == pytest.approx(ENCODER_STEP / 2)
    with pytest.raises(ValueError, match="encoder_lines"):
        gym.make("gbo_envs/DCMotorRig-v0", encoder_lines=0)
    with pytest.raises(ValueError, match="coulomb_friction"):
        gym.make("gbo_envs/LinearMotorRig-v0", friction=-0.5)
    lm = gym.make("gbo_envs/LinearMotorRig-v0", effects={"saturation": {"limit": 6.0}}).unwrapped
    assert [b.name for b in lm.loop.effects] == ["saturation", "quantization", "coulomb_friction"]
    assert lm.loop.effects[0].limit == 6.0
