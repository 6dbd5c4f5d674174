"""The exact sampled-data simulator against python-control and against itself."""

from __future__ import annotations

import control as ct
import numpy as np
import pytest

from gbo_envs import ClosedLoop, ContinuousPlant, PDT1Controller, PIController
from tests.support import DC_PLANT, U_REST, dc_loop

GAINS = np.array([[0.54, 1.16], [1.10, 2.08], [0.11, 0.87], [0.85, 1.07]])


@pytest.mark.parametrize("gains", GAINS)
def test_matches_python_control_sampled_data_loop_exactly(gains):
    """Same loop built with python-control: ZOH plant, one-sample delay, Tustin PI."""
    loop = dc_loop()
    plant_d = ct.c2d(ct.tf([9.544], [1.0, 4.145, 4.199]), 0.002, method="zoh") * ct.tf([1.0], [1.0, 0.0], 0.002)
    pi_d = ct.c2d(ct.tf([gains[0], gains[0] * gains[1]], [1.0, 0.0]), 0.002, method="tustin")
    closed = ct.feedback(pi_d * plant_d, 1)
    _, y_ref = ct.step_response(closed, loop.time)
    ours = loop.simulate(gains[None, :]).y[0]
    assert np.max(np.abs(245.0 + 61.0 * y_ref - ours)) < 1e-6 * 61.0


@pytest.mark.parametrize("gains", GAINS)
def test_close_to_continuous_loop_with_pade_delay(gains):
    """The continuous PI loop (delay as 5th-order Pade) differs only by the 2 ms digital controller."""
    loop = dc_loop()
    pade = ct.tf(*ct.pade(0.002, 5))
    closed = ct.feedback(ct.tf([gains[0], gains[0] * gains[1]], [1.0, 0.0]) * ct.tf([9.544], [1, 4.145, 4.199])
                         * pade, 1)
    _, y_ref = ct.step_response(closed, loop.time)
    ours = loop.simulate(gains[None, :]).y[0]
    assert np.max(np.abs(245.0 + 61.0 * y_ref - ours)) < 0.003 * 61.0


def test_batch_rows_equal_single_runs():
    loop = dc_loop()
    batch = loop.simulate(GAINS)
    for i, gains in enumerate(GAINS):
        single = loop.simulate(gains)
        assert np.array_equal(batch.y[i], single.y[0])
        assert np.array_equal(batch.u[i], single.u[0])


def test_starts_at_rest_at_r1_with_equilibrium_command():
    response = dc_loop().simulate(GAINS[:1])
    assert response.y[0, 0] == pytest.approx(245.0)
    # before the step the plant rests at u = r1 tau2 / L; the first command adds Kp (r2 - r1)
    assert response.u[0, 0] == pytest.approx(U_REST + (0.54 + 0.54 * 1.16 * 0.001) * 61.0)


@pytest.mark.parametrize("delay", [0.0, 0.002, 0.003, 0.0071])
def test_exact_discretisation_reproduces_delayed_continuous_step(delay):
    """A held step is exact under ZOH: the sampled plant must hit the continuous response at every sample."""
    plant = ContinuousPlant((9.544,), (1.0, 4.145, 4.199), delay=delay).discretize(0.002)
    n = 500
    u = np.ones(n)
    x = np.zeros(plant.order)
    history = np.zeros(n + plant.delay_steps + 2)
    history[plant.delay_steps + 1:] = 0.0
    y = np.empty(n)
    for k in range(n):
        y[k] = plant.c @ x
        lagged0 = u[k - plant.delay_steps] if k - plant.delay_steps >= 0 else 0.0
        lagged1 = u[k - plant.delay_steps - 1] if k - plant.delay_steps - 1 >= 0 else 0.0
        x = plant.phi @ x + plant.gamma0 * lagged0 + plant.gamma1 * lagged1
    t = np.arange(n) * 0.002
    shifted = np.clip(t - delay, 0.0, None)
    # analytic step response of 9.544 / ((s - p1)(s - p2)) with real poles p1, p2
    p1, p2 = np.roots([1.0, 4.145, 4.199])
    exact = 9.544 * (1.0 / (p1 * p2) + np.exp(p1 * shifted) / (p1 * (p1 - p2))
                     + np.exp(p2 * shifted) / (p2 * (p2 - p1)))
    assert np.max(np.abs(y - exact.real)) < 1e-10


def test_unstable_loop_is_flagged_and_stays_finite():
    response = dc_loop().simulate(np.array([[1000.0, 1.0], [0.54, 1.16]]))
    assert response.unstable.tolist() == [True, False]
    assert np.all(np.isfinite(response.y)) and np.all(np.isfinite(response.u))


def test_position_loop_with_integrating_plant_rests_with_zero_input():
    plant = ContinuousPlant((0.44262,), (0.070983, 1.0, 0.0), delay=0.001, output="position")
    loop = ClosedLoop(plant, PDT1Controller(), dt=0.001, duration=0.3, r1=0.03, r2=0.04)
    response = loop.simulate(np.array([[5341.0, 49.7]]))
    assert response.y[0, 0] == pytest.approx(0.03)
    assert abs(response.y[0, -1] - 0.04) < 1e-4


@pytest.mark.parametrize("kwargs, match", [
    ({"duration": 0.001}, "duration"),
    ({"r1": 306.0}, "r1, r2"),
    ({"output_noise_std": -1.0}, "output_noise_std"),
])
def test_bad_loop_arguments_are_named(kwargs, match):
    base = {"duration": 5.0, "r1": 245.0, "r2": 306.0}
    base.update(kwargs)
    with pytest.raises(ValueError, match=match):
        ClosedLoop(DC_PLANT, PIController(), dt=0.002, **base)


@pytest.mark.parametrize("kwargs, match", [
    ({"num": (1.0, 0.0, 0.0), "den": (1.0, 1.0)}, "strictly proper"),
    ({"num": (1.0,), "den": (1.0, 1.0), "delay": -0.1}, "delay"),
    ({"num": (1.0,), "den": (0.0, 1.0)}, "leading coefficient"),
    ({"num": (1.0,), "den": (1.0, 1.0), "output": "torque"}, "output"),
])
def test_bad_plants_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ContinuousPlant(**kwargs)


@pytest.mark.parametrize("method", ["linear", "stepping"])
def test_a_metrics_only_simulation_gives_the_same_outputs_and_flags_without_the_command(method):
    # gains from the feasible set to far beyond it: some loops diverge
    gains = np.column_stack([np.linspace(0.05, 30.0, 40), np.linspace(0.1, 60.0, 40)[::-1]])
    rng = np.random.default_rng
    loop = dc_loop().replace(output_noise_std=0.1)
    full = loop.simulate(gains, rng=rng(3), method=method)
    lean = loop.simulate(gains, rng=rng(3), method=method, inputs=False)
    assert full.unstable.any() and not full.unstable.all()
    assert np.array_equal(lean.unstable, full.unstable) and np.array_equal(lean.y, full.y)
    assert full.u.shape == full.y.shape and lean.u.shape == (gains.shape[0], 0)
