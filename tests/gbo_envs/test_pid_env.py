"""DCMotorPID-v0: the paper's DC motor under a PID with a filtered derivative, three gains."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.stats import qmc

import gbo_envs
from gbo_envs.envs.dc_motor_pid import DC_MOTOR_PID, corner_gains
from gbo_envs.envs.margins import loop_margins

ENV_ID = "gbo_envs/DCMotorPID-v0"


@pytest.fixture(scope="module")
def env():
    return gym.make(ENV_ID, noise=False).unwrapped


def test_registered_with_three_gains_and_the_dc_motor_experiment(env):
    assert ENV_ID in gbo_envs.ENV_IDS and gym.spec(ENV_ID).max_episode_steps == 35
    assert env.gain_names == ("Kp", "Ki", "Kd")
    assert env.gain_units == ("(input units)/(rad/s)", "(input units)/((rad/s) s)", "(input units) s/(rad/s)")
    np.testing.assert_array_equal(env.action_space.low, [0.43, 0.46, 0.10])
    np.testing.assert_array_equal(env.action_space.high, [1.71, 1.83, 0.40])
    assert env.observation_space.shape == (10,)
    assert env.loop.n_steps == 2501 and env.loop.controller.filter_time == 0.02


def test_a_step_returns_the_record_as_the_pi_env_does():
    pid, pi = gym.make(ENV_ID), gym.make("gbo_envs/DCMotor-v0")
    pid.reset(seed=0)
    pi.reset(seed=0)
    obs, reward, terminated, truncated, info = pid.step(np.array([0.855, 0.915, 0.2]))
    reference = pi.step(np.array([0.85, 1.07]))[4]
    assert set(info) == set(reference)
    assert info["y"].shape == info["u"].shape == info["t"].shape == (2501,)
    assert not info["unstable"] and not terminated and not truncated and reward == -info["cost"]
    assert info["experiment"].gains.shape == (3,) and obs.shape == (10,)
    assert info["y"][-1] == pytest.approx(306.0, abs=0.5)


def test_every_corner_of_the_feasible_set_keeps_the_stated_margins(env):
    """The docstring's evidence: the nominal design's margins, then every corner stable with PM >= 30 deg."""
    nominal = loop_margins(env.loop, DC_MOTOR_PID["nominal"])
    assert nominal.stable
    assert nominal.gain_margin_db == pytest.approx(44.3, abs=0.05)
    assert nominal.phase_margin_deg == pytest.approx(87.2, abs=0.05)
    corners = corner_gains(env.action_space.low, env.action_space.high)
    margins = [loop_margins(env.loop, corner) for corner in corners]
    assert all(m.stable and m.gain_margin_db > 0 and m.phase_margin_deg > 0 for m in margins)
    worst_phase = min(range(8), key=lambda i: margins[i].phase_margin_deg)
    worst_gain = min(range(8), key=lambda i: margins[i].gain_margin_db)
    np.testing.assert_allclose(corners[worst_phase], [0.43, 1.83, 0.10])
    assert margins[worst_phase].phase_margin_deg == pytest.approx(32.8, abs=0.05)
    np.testing.assert_allclose(corners[worst_gain], [1.71, 1.83, 0.40])
    assert margins[worst_gain].gain_margin_db == pytest.approx(38.3, abs=0.05)


def test_the_box_is_the_widest_that_keeps_30_degrees(env):
    nominal = np.array(DC_MOTOR_PID["nominal"])
    for factor, keeps in ((2.0, True), (2.5, False)):
        worst = min(loop_margins(env.loop, c).phase_margin_deg for c in corner_gains(nominal / factor,
                                                                                   nominal * factor))
        assert (worst >= 30.0) is keeps
    np.testing.assert_allclose(env.action_space.low, nominal / 2, atol=0.005)
    np.testing.assert_allclose(env.action_space.high, nominal * 2, atol=0.005)


def test_normalizers_are_the_mean_metrics_over_the_corners(env):
    corners = corner_gains(env.action_space.low, env.action_space.high)
    np.testing.assert_allclose(env.normalizers, env.evaluate(corners)[0].mean(axis=0), rtol=1e-12)
    assert np.all(env.evaluate(corners)[1] < 10.0)  # no corner diverges


def test_a_coarse_search_finds_the_stated_optimum_better_than_every_corner_and_the_nominal(env):
    low, high = env.action_space.low, env.action_space.high
    points = qmc.scale(qmc.Sobol(3, seed=1).random(256), low, high)
    start = points[int(np.argmin(env.evaluate(points)[1]))]
    best = minimize(lambda z: env.evaluate(np.clip(z, low, high)[None])[1][0], start, method="Nelder-Mead",
                    options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 400})
    assert best.fun == pytest.approx(0.1585, abs=0.002)  # J* of the docstring and of cost_noise_std
    assert best.fun < env.evaluate(np.array([DC_MOTOR_PID["nominal"]]))[1][0] / 2
    assert best.fun < env.evaluate(corner_gains(low, high))[1].min()
    assert DC_MOTOR_PID["cost_noise_std"] == pytest.approx(0.03 / 0.79 * best.fun, rel=0.05)


def test_noise_free_step_is_the_ground_truth_expectation(env):
    gains = np.array([1.2, 1.1, 0.3])
    env.reset(seed=0)
    info = env.step(gains)[4]
    assert info["cost"] == info["true_cost"] == pytest.approx(env.evaluate(gains[None])[1][0], rel=1e-12)
