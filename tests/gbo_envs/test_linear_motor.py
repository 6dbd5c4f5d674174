"""LinearMotor-v0: calibration of the unmodelled damping, stability margins and the paper's setup."""

from __future__ import annotations

import control as ct
import gymnasium as gym
import numpy as np
import pytest

import gbo_envs
from gbo_envs import ground_truth
from gbo_envs.envs.linear_motor import LINEAR_MOTOR, vertex_gains
from gbo_envs.physics.actuator import Saturation
from gbo_envs.physics.sensor import Quantization
from tests.support import gain_grid

ENV_ID = "gbo_envs/LinearMotor-v0"


def _env(**kwargs):
    return gym.make(ENV_ID, **kwargs).unwrapped


def test_registered_with_paper_setup():
    env = gym.make(ENV_ID)
    assert ENV_ID in gbo_envs.ENV_IDS
    assert env.spec.max_episode_steps == 25
    plant_env = env.unwrapped
    np.testing.assert_allclose(plant_env.action_space.low, [5123.8, 40.1])
    np.testing.assert_allclose(plant_env.action_space.high, [6136.2, 51.0])
    np.testing.assert_allclose(plant_env.weights, [0.10, 0.18, 0.69, 0.04])
    loop = plant_env.loop
    assert (loop.dt, loop.duration, loop.r1, loop.r2) == (0.001, 0.30, 0.030, 0.040)
    assert loop.n_steps == 301
    assert loop.plant.num == (0.44262,) and loop.plant.den == (0.070983, 0.8, 0.0)
    assert loop.plant.delay == 0.001 and loop.plant.output == "position"
    assert loop.controller.gain_names == ("Kp", "Kd") and loop.controller.filter_time == 0.001
    assert plant_env.cost_noise_std == pytest.approx(0.001)


def test_current_limit_and_sensor_resolution_in_the_loop():
    env = _env(noise=False)
    effects = env.loop.effects
    assert [type(b) for b in effects] == [Saturation, Quantization]
    assert effects[0].limit == 7.0 and effects[1].step == 5e-6
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([5500.0, 45.0]))
    # the measured position is a whole number of 5 um sensor steps
    steps = info["y"] / 5e-6
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    # the commanded current far exceeds the 7 A the drive delivers at the step
    assert np.max(np.abs(info["u"])) > 100.0
    # without the limit the same gains ring far more: the limit shapes the response
    free = _env(noise=False, current_limit=None)
    free.reset(seed=0)
    _, _, _, _, info_free = free.step(np.array([5500.0, 45.0]))
    assert info_free["metrics"]["overshoot_pct"] > info["metrics"]["overshoot_pct"] + 20.0


def test_effects_kwarg_overrides_and_extends_builtins():
    env = _env(effects={"saturation": {"limit": 5.0}, "coulomb_friction": {"torque": 0.1}})
    names = [b.name for b in env.loop.effects]
    assert names == ["saturation", "quantization", "coulomb_friction"]
    assert env.loop.effects[0].limit == 5.0
    with pytest.raises(ValueError, match="current_limit: must be > 0"):
        _env(current_limit=-1.0)
    with pytest.raises(ValueError, match="damping"):
        _env(damping=-0.1)


def test_cost_normalised_by_the_four_vertices():
    env = _env(noise=False)
    vertices = vertex_gains(env.action_space.low, env.action_space.high)
    assert vertices.shape == (4, 2)
    metrics, cost = env.evaluate(vertices)
    np.testing.assert_allclose(env.normalizers, metrics.mean(axis=0))
    # J averages the weight sum over the vertices: 1.01, as the paper's weights add up to 1.01
    assert cost.mean() == pytest.approx(env.weights.sum()) and env.weights.sum() == pytest.approx(1.01)


def test_bare_nominal_model_overshoots():
    """The undamped double integrator overshoots 6-36 % over the set (docs/design.md, "Calibration")."""
    env = _env(noise=False, damping=0.0)
    metrics, _ = env.evaluate(gain_grid(env, 20))
    assert metrics[:, 0].min() > 5.0
    assert metrics[:, 0].max() > 30.0


def test_calibrated_optimum_matches_the_paper():
    """Ground truth at the paper's 100 x 100 grid: Kp <= 5650, Kd >= 47 and overshoot under 1.12 %."""
    env = _env()
    truth = ground_truth(env, resolution=100)
    kp, kd = truth.gains
    assert kp <= 5650.0 and kd >= 47.0
    metrics, cost = env.evaluate(truth.gains[None, :])
    assert metrics[0, 0] < 1.12
    assert cost[0] == pytest.approx(truth.cost)
    # the recorded figures of the calibration (module docstring)
    np.testing.assert_allclose(truth.gains, [5348.78, 50.78], atol=0.01)
    assert truth.cost == pytest.approx(0.84897, abs=1e-4)
    assert metrics[0, 0] == pytest.approx(0.05, abs=1e-6)
    # the best gains with Kd < 47 or Kp > 5650 are clearly worse than the optimum
    grid = np.column_stack([m.ravel() for m in np.meshgrid(*truth.axes, indexing="ij")])
    outside = (grid[:, 0] > 5650.0) | (grid[:, 1] < 47.0)
    assert truth.costs.ravel()[outside].min() > truth.cost + 0.02


@pytest.mark.parametrize("damping", [0.6, 0.9])
def test_calibration_is_robust_to_the_damping(damping):
    env = _env(damping=damping)
    truth = ground_truth(env, resolution=50)
    kp, kd = truth.gains
    assert kp <= 5650.0 and kd >= 47.0
    metrics, _ = env.evaluate(truth.gains[None, :])
    assert metrics[0, 0] < 1.12


def _loops(env, gains):
    """Continuous (5th-order Pade for the delay) and sampled (ZOH, Tustin) open loops at ``gains``."""
    plant, dt = env.loop.plant, env.loop.dt
    g = ct.tf(plant.num, plant.den)
    num_c, den_c = env.loop.controller.transfer_function(gains)
    pade_num, pade_den = ct.pade(plant.delay, 5)
    continuous = g * ct.tf(num_c, den_c) * ct.tf(pade_num, pade_den)
    delay_steps = int(round(plant.delay / dt))
    b0, b1, a1 = (float(c[0]) for c in env.loop.controller.coefficients(np.atleast_2d(gains), dt))
    sampled = (ct.c2d(g, dt, "zoh") * ct.tf([1.0], [1.0] + [0.0] * delay_steps, dt)
               * ct.tf([b0, b1], [1.0, a1], dt))
    return continuous, sampled


# python-control evaluates the open loop at s = 0 (its integrators: an infinite gain) on the way to the margins
@pytest.mark.filterwarnings("ignore:divide by zero encountered:RuntimeWarning",
                            "ignore:invalid value encountered in divide:RuntimeWarning")
def test_phase_margin_above_20_degrees_over_the_feasible_set():
    env = _env()
    margins = []
    for gains in gain_grid(env, 11):
        continuous, sampled = _loops(env, gains)
        pm_c = ct.stability_margins(continuous)[1]
        pm_d = ct.stability_margins(sampled)[1]
        margins.append((pm_c, pm_d))
    margins = np.array(margins)
    assert margins.min() > 20.0
    # the figures of the module docstring (sampled loop, the tighter of the two)
    assert margins[:, 1].min() == pytest.approx(25.2, abs=0.1)
    assert margins[:, 1].max() == pytest.approx(29.8, abs=0.1)
    assert margins[:, 0].min() == pytest.approx(34.3, abs=0.2)


def test_sampled_loop_model_matches_the_simulator():
    """The python-control loop used for the margins is the loop the env simulates (linear, no effects)."""
    env = _env(noise=False, current_limit=None, sensor_resolution=None)
    gains = np.array([5500.0, 45.0])
    _, sampled = _loops(env, gains)
    closed = ct.feedback(sampled, 1)
    t = env.loop.time
    _, y = ct.forced_response(closed, T=t, U=np.full(t.size, env.loop.step_height))
    response = env.loop.simulate(gains[None, :])
    np.testing.assert_allclose(response.y[0] - env.loop.r1, y, atol=1e-9)


def test_noise_defaults_and_switch():
    noisy = _env()
    assert noisy.cost_noise_std == LINEAR_MOTOR["cost_noise_std"] == 0.001
    quiet = _env(noise=False)
    assert quiet.cost_noise_std == 0.0 and quiet.loop.output_noise_std == 0.0
