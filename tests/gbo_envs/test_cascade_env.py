"""LinearMotorCascade-v0 and LinearMotorCascadeRig-v0: the linear motor under a position -> speed cascade, 4 gains."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.stats import qmc

import gbo_envs
from gbo_envs.controllers import CascadeController
from gbo_envs.envs.dc_motor_pid import corner_gains
from gbo_envs.envs.linear_motor_cascade import LINEAR_CASCADE, nominal_cascade
from gbo_envs.envs.margins import loop_margins
from gbo_envs.physics.encoder import PositionEncoder
from gbo_envs.physics.friction import CoulombFriction
from gbo_envs.physics.sensor import Quantization

ENV_ID = "gbo_envs/LinearMotorCascade-v0"
RIG_ID = "gbo_envs/LinearMotorCascadeRig-v0"
MIDDLE = np.array([42.7, 27.4, 85.45, 0.5])


@pytest.fixture(scope="module")
def env():
    return gym.make(ENV_ID, noise=False).unwrapped


def test_registered_with_four_gains_on_the_linear_motor(env):
    for env_id in (ENV_ID, RIG_ID):
        assert env_id in gbo_envs.ENV_IDS and gym.spec(env_id).max_episode_steps == 50
    assert env.gain_names == ("Kv", "Kp", "Ki", "Kff") and env.gain_units == ("1/s", "A/(m/s)", "1/s", "1")
    np.testing.assert_array_equal(env.action_space.low, [33.3, 21.4, 66.7, 0.0])
    np.testing.assert_array_equal(env.action_space.high, [52.1, 33.4, 104.2, 1.0])
    np.testing.assert_allclose(env.weights, [0.10, 0.18, 0.69, 0.04])
    loop = env.loop
    assert (loop.dt, loop.duration, loop.r1, loop.r2, loop.n_steps) == (0.001, 0.30, 0.030, 0.040, 301)
    assert loop.plant.den == (0.070983, 0.8, 0.0) and loop.plant.delay == 0.001
    assert isinstance(loop.controller, CascadeController) and loop.controller.output_limit == 7.0
    assert [type(b) for b in loop.effects] == [Quantization] and env.observation_space.shape == (11,)


def test_a_step_returns_the_record_as_the_pd_env_does():
    cascade, pd = gym.make(ENV_ID), gym.make("gbo_envs/LinearMotor-v0")
    cascade.reset(seed=0)
    pd.reset(seed=0)
    info = cascade.step(MIDDLE)[4]
    assert set(info) == set(pd.step(np.array([5500.0, 45.0]))[4])
    assert info["y"].shape == info["u"].shape == (301,) and info["experiment"].gains.shape == (4,)
    # the drive's current command stays within its 7 A limit and saturates at the step
    assert np.max(np.abs(info["u"])) == pytest.approx(7.0)
    assert info["y"][-1] == pytest.approx(0.040, abs=1e-5) and not info["unstable"]
    # the speed estimate is a function of the record's y
    speed = cascade.unwrapped.loop.controller.speed_estimate(info["y"], 0.001)
    assert 0.2 < speed.max() < 1.0  # m/s


def test_nominal_design_is_the_symmetric_and_technical_optimum(env):
    nominal = nominal_cascade()
    sigma = 0.001 + 0.0005 + 0.001 + 0.0005
    assert LINEAR_CASCADE["small_time_constant"] == pytest.approx(sigma)
    np.testing.assert_allclose(nominal, [1 / (8 * sigma), (0.070983 / 0.8) / (2 * 0.44262 / 0.8 * sigma),
                                         1 / (4 * sigma), 1.0])
    margins = loop_margins(env.loop, nominal)
    assert margins.stable
    assert margins.phase_margin_deg == pytest.approx(30.8, abs=0.05)
    assert margins.gain_margin_db == pytest.approx(11.3, abs=0.05)
    assert margins.gain_reduction_margin_db == pytest.approx(-17.4, abs=0.05)


def test_every_corner_of_the_feasible_set_is_stable_with_the_stated_margins(env):
    corners = corner_gains(env.action_space.low, env.action_space.high)
    assert corners.shape == (16, 4)
    margins = [loop_margins(env.loop, corner) for corner in corners]
    assert all(m.stable and m.gain_margin_db > 0 and m.phase_margin_deg > 20.0 for m in margins)
    worst_phase = min(range(16), key=lambda i: margins[i].phase_margin_deg)
    worst_gain = min(range(16), key=lambda i: margins[i].gain_margin_db)
    np.testing.assert_allclose(corners[worst_phase][:3], [52.1, 21.4, 104.2])
    assert margins[worst_phase].phase_margin_deg == pytest.approx(21.8, abs=0.1)
    np.testing.assert_allclose(corners[worst_gain][:3], [52.1, 33.4, 104.2])
    assert margins[worst_gain].gain_margin_db == pytest.approx(8.7, abs=0.1)
    # Kff shapes only the reference path: the same margins at Kff = 0 and 1
    assert margins[0].phase_margin_deg == pytest.approx(margins[1].phase_margin_deg, abs=1e-6)


def test_the_box_is_the_widest_that_keeps_the_papers_20_degrees(env):
    nominal = nominal_cascade()
    for factor, keeps in ((1.25, True), (1.5, False)):
        corners = corner_gains(np.r_[nominal[:3] / factor, 0.0], np.r_[nominal[:3] * factor, 0.0])
        assert (min(loop_margins(env.loop, c).phase_margin_deg for c in corners) > 20.0) is keeps
    np.testing.assert_allclose(env.action_space.low[:3], nominal[:3] / 1.25, atol=0.05)
    np.testing.assert_allclose(env.action_space.high[:3], nominal[:3] * 1.25, atol=0.05)


def test_normalizers_are_the_mean_metrics_over_the_16_corners_the_overshoot_at_least_one_sensor_count(env):
    corners = corner_gains(env.action_space.low, env.action_space.high)
    metrics, costs = env.evaluate(corners)
    mean = metrics.mean(axis=0)
    one_count = 100.0 * 5e-6 / 0.01  # %: one 5 um count of the 10 mm step
    assert 0.0 < mean[0] < one_count  # the corners hardly overshoot: a quarter count on average
    np.testing.assert_allclose(env.normalizers, np.r_[one_count, mean[1:]], rtol=1e-12)
    assert costs.mean() == pytest.approx(0.935, abs=5e-4) and np.all(costs < 10.0)
    # one count of overshoot costs the overshoot's weight, 0.10, not four times it
    assert env.weights[0] * one_count / env.normalizers[0] == pytest.approx(0.10)
    finer = gym.make(ENV_ID, noise=False, sensor_resolution=None).unwrapped  # an ideal sensor: the mean stands
    fine_metrics, _ = finer.evaluate(corners)
    np.testing.assert_allclose(finer.normalizers, fine_metrics.mean(axis=0), rtol=1e-12)


def test_every_gain_matters_and_a_coarse_search_beats_the_corners_and_the_nominal(env):
    low, high = env.action_space.low, env.action_space.high
    for i in range(4):  # one gain from its low to its high end, the others in the middle
        ends = np.tile(MIDDLE, (2, 1))
        ends[:, i] = low[i], high[i]
        costs = env.evaluate(ends)[1]
        assert abs(costs[1] - costs[0]) > 0.01, env.gain_names[i]
    points = qmc.scale(qmc.Sobol(4, seed=2).random(512), low, high)
    start = points[int(np.argmin(env.evaluate(points)[1]))]
    best = minimize(lambda z: env.evaluate(np.clip(z, low, high)[None])[1][0], start, method="Nelder-Mead",
                    options={"xatol": 1e-3, "fatol": 1e-6, "maxiter": 300})
    corners = env.evaluate(corner_gains(low, high))[1]
    assert best.fun < corners.min() < env.evaluate(nominal_cascade()[None])[1][0]
    assert 0.58 < best.fun < 0.625


def test_anti_windup_keeps_the_clipped_step_from_overshooting():
    clamped, wound = (gym.make(ENV_ID, noise=False, anti_windup=aw).unwrapped for aw in ("clamping", "none"))
    gains = np.array([52.1, 21.4, 104.2, 1.0])
    held, free = (e.evaluate(gains[None])[0][0] for e in (clamped, wound))
    assert held[0] < 0.1 < 5.0 < free[0]  # overshoot in %
    assert gym.make(ENV_ID, noise=False, current_limit=None).unwrapped.loop.nonlinear  # the sensor remains


def test_the_rig_adds_the_sensor_noise_and_the_friction_and_hunts_where_the_model_does_not(env):
    rig = gym.make(RIG_ID, expectation_draws=8).unwrapped
    assert [type(b) for b in rig.loop.effects] == [PositionEncoder, CoulombFriction]
    assert rig.loop.effects[1].torque == 0.5 and rig.loop.stochastic and rig.loop.controller.output_limit == 7.0
    rig.reset(seed=0)
    infos = [rig.step(MIDDLE)[4] for _ in range(3)]
    assert len({i["cost"] for i in infos}) == 3 and all(i["true_cost"] == infos[0]["true_cost"] for i in infos)
    assert all(np.max(np.abs(i["u"])) == pytest.approx(7.0) for i in infos)
    # stick-slip: short of the target, then past it by tens of um, where the model settles without overshoot
    error = np.mean([i["y"] for i in infos], axis=0) - 0.040
    assert error[150] < -10e-6 and error.max() > 40e-6
    assert rig.evaluate(MIDDLE[None])[0][0, 0] > 0.3 > 0.05 > env.evaluate(MIDDLE[None])[0][0, 0]


def test_noise_free_steps_are_the_expectation():
    for env_id, kwargs in ((ENV_ID, {}), (RIG_ID, {"expectation_draws": 8})):
        plant = gym.make(env_id, noise=False, **kwargs)
        plant.reset(seed=1)
        info = plant.step(MIDDLE)[4]
        assert info["cost"] == info["true_cost"] == pytest.approx(plant.unwrapped.evaluate(MIDDLE[None])[1][0],
                                                                  rel=1e-12)
