"""Rig stand-ins: the documented effects are in the loop and change the cost surface, the loop stays sound."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from scipy import ndimage

import gbo_envs
from gbo_envs import ground_truth
from gbo_envs.physics.actuator import Saturation
from gbo_envs.physics.encoder import PositionEncoder, SpeedEncoder
from gbo_envs.physics.friction import CoulombFriction
from tests.support import gain_grid

SPEED_STEP = 2 * np.pi / (2048 * 0.020)


def test_registered():
    for env_id, steps in (("gbo_envs/DCMotorRig-v0", 35), ("gbo_envs/LinearMotorRig-v0", 25)):
        assert env_id in gbo_envs.ENV_IDS
        assert gym.make(env_id).spec.max_episode_steps == steps


def test_dc_rig_effects():
    env = gym.make("gbo_envs/DCMotorRig-v0").unwrapped
    assert [type(b) for b in env.loop.effects] == [Saturation, CoulombFriction, SpeedEncoder]
    limit, friction, encoder = env.loop.effects
    assert limit.limit == 160.0 and friction.torque == 5.0
    assert (encoder.lines, encoder.window) == (2048, 10)
    # the paper's v = 1600 counts over the window is 245 rad/s
    assert 1600 * encoder.speed_resolution(0.002) == pytest.approx(245.4, abs=0.1)
    assert env.loop.plant == gym.make("gbo_envs/DCMotor-v0").unwrapped.loop.plant
    # the measured speed is a whole number of increments per 20 ms window, and it dithers at rest
    env.reset(seed=0)
    info = env.step(np.array([0.6, 1.2]))[4]
    counts = info["y"] / SPEED_STEP
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert np.unique(np.round(counts[:50])).size >= 2


def test_linear_rig_effects():
    env = gym.make("gbo_envs/LinearMotorRig-v0").unwrapped
    assert [type(b) for b in env.loop.effects] == [Saturation, PositionEncoder, CoulombFriction]
    assert [b.side for b in env.loop.effects] == ["actuator", "sensor", "actuator"]
    limit, sensor, friction = env.loop.effects
    assert limit.limit == 7.0 and sensor.resolution == 5e-6 and sensor.jitter == 1.25e-6 and friction.torque == 0.5
    assert env.loop.plant == gym.make("gbo_envs/LinearMotor-v0").unwrapped.loop.plant
    env.reset(seed=0)
    info = env.step(np.array([5500.0, 45.0]))[4]
    steps = info["y"] / 5e-6
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)


@pytest.mark.parametrize("env_id", gbo_envs.ENV_IDS)
def test_noise_free_step_is_the_ground_truth_cell(env_id):
    env = gym.make(env_id, noise=False)
    if env.action_space.shape != (2,):  # more gains: the step against the expectation (no grid)
        env.reset(seed=3)
        gains = (env.action_space.low + env.action_space.high) / 2
        info = env.step(gains)[4]
        assert info["cost"] == info["true_cost"] == pytest.approx(env.unwrapped.evaluate(gains[None], 0)[1][0],
                                                                  rel=1e-12)
        return
    truth = ground_truth(env_id, resolution=4, n_jobs=1, noise=False)
    for cell in [(0, 0), (1, 2), (3, 1)]:
        env.reset(seed=3)  # the ground truth is the plant at the first experiment (time-varying envs)
        gains = np.array([axis[i] for axis, i in zip(truth.axes, cell)])
        info = env.step(gains)[4]
        # equal up to rounding: batches of different size sum the metrics in a different order
        assert info["cost"] == pytest.approx(truth.costs[cell], rel=1e-12)
        assert info["true_cost"] == info["cost"]


@pytest.mark.parametrize("rig_id", ["gbo_envs/DCMotorRig-v0", "gbo_envs/LinearMotorRig-v0"])
def test_rig_ground_truth_is_a_common_random_numbers_mean(rig_id):
    env = gym.make(rig_id, expectation_draws=16).unwrapped  # the mechanism, at any K
    a, b = np.array([env.action_space.low, env.action_space.high])
    alone = env.evaluate(a[None, :])[1]
    together = env.evaluate(np.array([b, a, b]))[1]
    assert together[1] == pytest.approx(alone[0], rel=1e-12)  # the draws do not depend on the batch
    # a noisy experiment is one draw: it scatters around the expectation it reports as true_cost
    env.reset(seed=0)
    infos = [env.step(a)[4] for _ in range(8)]
    assert all(i["true_cost"] == pytest.approx(alone[0], rel=1e-12) for i in infos)
    assert len({i["cost"] for i in infos}) == 8
    other = gym.make(rig_id, expectation_draws=16, expectation_seed=1).unwrapped.evaluate(a[None, :])[1]
    assert other[0] != alone[0] and other[0] == pytest.approx(alone[0], rel=0.01)


@pytest.mark.parametrize("rig_id", ["gbo_envs/DCMotorRig-v0", "gbo_envs/LinearMotorRig-v0"])
def test_rig_near_optimal_set_is_one_connected_region(rig_id):
    truth = ground_truth(rig_id)  # the shipped 100 x 100 table, equal to the live one (test_ground_truth_tables)
    inside = truth.costs <= 1.1 * truth.cost
    labels, regions = ndimage.label(inside)
    largest = np.bincount(labels.ravel())[1:].max()
    assert largest >= 0.95 * inside.sum()


@pytest.mark.parametrize(("rig_id", "model_id"), [("gbo_envs/DCMotorRig-v0", "gbo_envs/DCMotor-v0"),
                                                  ("gbo_envs/LinearMotorRig-v0", "gbo_envs/LinearMotor-v0")])
def test_rig_cost_surface_differs_from_the_identified_model(rig_id, model_id):
    rig = gym.make(rig_id, expectation_draws=16).unwrapped  # magnitudes far above the Monte Carlo error
    model = gym.make(model_id).unwrapped
    grid = gain_grid(rig, 15)
    rig_metrics, rig_cost = rig.evaluate(grid)
    model_metrics, model_cost = model.evaluate(grid)
    assert np.max(np.abs(rig_cost - model_cost)) > 0.05
    assert not np.allclose(rig.normalizers, model.normalizers, rtol=0.02)
    # well-behaved over the whole feasible set: stable, bounded overshoot
    assert not np.any(rig_cost == rig.unstable_cost)
    assert rig_metrics[:, 0].max() < 50.0


@pytest.mark.slow
def test_dc_rig_command_limit_winds_up_the_integrator():
    """The 160-unit limit clips the high-gain corner, whose overshoot grows (43 % instead of 35 %)."""
    rig = gym.make("gbo_envs/DCMotorRig-v0", expectation_draws=56).unwrapped  # the mechanism, not J's precision
    model = gym.make("gbo_envs/DCMotor-v0").unwrapped
    grid = gain_grid(rig, 20)
    rig_os = rig.evaluate(grid)[0][:, 0]
    model_os = model.evaluate(grid)[0][:, 0]
    assert model_os.max() == pytest.approx(35.5, abs=0.5)
    assert rig_os.max() == pytest.approx(42.8, abs=0.5)
    # the model asks up to 190 units there, above the limit
    response = model.loop.simulate(np.array([[1.10, 2.08]]))
    assert response.u.max() > 180.0


def test_linear_rig_friction_damps_and_leaves_a_small_offset():
    rig = gym.make("gbo_envs/LinearMotorRig-v0", noise=False, sensor_jitter=0.0).unwrapped
    model = gym.make("gbo_envs/LinearMotor-v0", noise=False).unwrapped
    assert not rig.loop.stochastic
    grid = gain_grid(rig, 20)
    rig_response = rig.loop.simulate(grid)
    model_response = model.loop.simulate(grid)
    rig_os = rig.loop.metrics(rig_response)[:, 0]
    model_os = model.loop.metrics(model_response)[:, 0]
    assert rig_os.max() < model_os.max() - 4.0  # 16 % instead of 22 %
    # no integrator in the PDT1 controller: friction 0.5 A / Kp leaves at most ~0.1 mm, here <= 20 um
    offset = np.abs(rig_response.y[:, -1] - rig.loop.r2)
    assert offset.max() <= 20e-6 + 1e-12
    assert offset.max() > np.abs(model_response.y[:, -1] - model.loop.r2).max()


def test_linear_rig_ranks_the_papers_gains_as_the_paper_does():
    """Paper, Table Exper_LM_opts: the grid-search and guided-BO gains beat BO's low-Kd gains (overshoot)."""
    rig = gym.make("gbo_envs/LinearMotorRig-v0", noise=False).unwrapped
    metrics, cost = rig.evaluate(np.array([[5341.25, 49.68], [5138.75, 49.31], [6128.75, 40.81]]))
    assert cost[0] < cost[2] and cost[1] < cost[2]
    assert metrics[2, 0] > 10.0 > 1.0 > metrics[0, 0]  # overshoot in %


def test_rig_arguments():
    env = gym.make("gbo_envs/DCMotorRig-v0", command_limit=170.0, friction=0.0, encoder_lines=4096,
                   encoder_window=5).unwrapped
    assert env.loop.effects[0].limit == 170.0 and env.loop.effects[1].torque == 0.0
    assert env.loop.effects[2].speed_resolution(0.002) == pytest.approx(2 * SPEED_STEP / 2)
    lm = gym.make("gbo_envs/LinearMotorRig-v0", effects={"saturation": {"limit": 6.0}}).unwrapped
    assert [b.name for b in lm.loop.effects] == ["saturation", "position_encoder", "coulomb_friction"]
    assert lm.loop.effects[0].limit == 6.0


@pytest.mark.parametrize(("rig_id", "kwargs", "parameter"), [
    ("gbo_envs/DCMotorRig-v0", {"encoder_lines": 0}, "encoder_lines"),
    ("gbo_envs/DCMotorRig-v0", {"encoder_lines": 20.48}, "encoder_lines"),
    ("gbo_envs/DCMotorRig-v0", {"encoder_window": 0}, "encoder_window"),
    ("gbo_envs/DCMotorRig-v0", {"encoder_jitter": -1e-3}, "encoder_jitter"),
    ("gbo_envs/DCMotorRig-v0", {"expectation_draws": 0}, "expectation_draws"),
    ("gbo_envs/DCMotorRig-v0", {"expectation_draws": 2.5}, "expectation_draws"),
    ("gbo_envs/LinearMotorRig-v0", {"sensor_resolution": 0.0}, "sensor_resolution"),
    ("gbo_envs/LinearMotorRig-v0", {"sensor_resolution": float("nan")}, "sensor_resolution"),
    ("gbo_envs/LinearMotorRig-v0", {"sensor_jitter": -1e-6}, "sensor_jitter"),
    ("gbo_envs/LinearMotorRig-v0", {"expectation_draws": -3}, "expectation_draws"),
    ("gbo_envs/LinearMotorRig-v0", {"expectation_seed": -1}, "expectation_seed"),
    ("gbo_envs/LinearMotorRig-v0", {"friction": -0.5}, "coulomb_friction"),
])
def test_rig_bad_arguments_name_the_parameter(rig_id, kwargs, parameter):
    with pytest.raises(ValueError, match=parameter):
        gym.make(rig_id, **kwargs)


def test_expectation_holds_one_chunk_of_draws_at_a_time():
    """The K-draw expectation keeps one chunk's responses alive, not every chunk's (a rig grid took GBs)."""
    import tracemalloc

    from gbo_envs.envs.base import expected_outcome

    loop = gym.make("gbo_envs/DCMotorRig-v0", expectation_draws=16).unwrapped.loop
    gains = np.tile([[0.5, 1.2]], (12, 1))

    def peak(n_gains: int) -> int:
        tracemalloc.start()
        expected_outcome(loop, gains[:n_gains], 16, 0, cost=None, max_rows=16)  # one gain per chunk
        used = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return used

    assert peak(12) < 2.0 * peak(1)
