"""Controllers of any order: the PID and the cascade, their Tustin realisation, anti-windup, and both
simulation paths; the first-order PI and PDT1 loops stay bit for bit what they were."""

from __future__ import annotations

from fractions import Fraction

import gymnasium as gym
import numpy as np
import pytest
from scipy.signal import cont2discrete, freqs

from gbo_envs import ClosedLoop
from gbo_envs.controllers import CascadeController, PIController, PIDController, tustin
from gbo_envs.envs.dc_motor import DCMotorEnv, dc_motor_plant
from gbo_envs.envs.linear_motor import LinearMotorEnv, linear_motor_plant
from gbo_envs.physics import Quantization, Saturation, kernels

DC_GAINS = np.array([[0.11, 0.87], [0.54, 1.16], [1.10, 2.08], [0.85, 1.07]])
LM_GAINS = np.array([[5123.8, 40.1], [5341.0, 49.7], [6136.2, 51.0], [5600.0, 44.0]])
PID_GAINS = np.array([[0.855, 0.915, 0.2], [0.43, 1.83, 0.1], [1.71, 0.46, 0.4]])
CASCADE_GAINS = np.array([[41.7, 26.7, 83.3, 1.0], [33.3, 33.4, 66.7, 0.0], [52.1, 21.4, 104.2, 0.5]])


def dc_pid_loop(**controller) -> ClosedLoop:
    return ClosedLoop(dc_motor_plant(9.544, 4.145, 4.199, 0.002), PIDController(**{"filter_time": 0.02, **controller}),
                      0.002, 5.0, 245.0, 306.0)


def slider_loop(effects=(), **controller) -> ClosedLoop:
    return ClosedLoop(linear_motor_plant(0.44262, 0.070983, 0.8, 0.001), CascadeController(**controller), 0.001, 0.3,
                      0.03, 0.04, effects=effects)


# -- PI and PDT1: bit for bit ----------------------------------------------------------------------------------

def _digest(*arrays) -> list[float]:
    """Checksums of the responses: their sum, sum of squares, a sum weighted along the record, min and max."""
    values = np.concatenate([np.ravel(np.asarray(array, dtype=float)) for array in arrays])
    ramp = np.linspace(1.0, 2.0, values.size)
    return [float(np.sum(values)), float(np.sum(values**2)), float(np.sum(ramp * values)), float(np.min(values)),
            float(np.max(values))]


class _UnknownSaturation(Saturation):
    """A block the kernels do not know: the loop keeps its numpy stepping."""


def _first_order_digests() -> dict[str, list[float]]:
    out = {}
    dc = DCMotorEnv(noise=False).loop
    for method in ("linear", "stepping"):
        response = dc.simulate(DC_GAINS, method=method)
        out[f"dc-{method}"] = _digest(response.u, response.y)
        response = dc.replace(output_noise_std=0.5).simulate(DC_GAINS, rng=np.random.default_rng(4), method=method,
                                                             draws=np.array([0, 1, 0, 2]))
        out[f"dc-noisy-{method}"] = _digest(response.u, response.y)
    lm = LinearMotorEnv(noise=False).loop
    response = lm.simulate(LM_GAINS)
    out["lm-stepping"] = _digest(response.u, response.y)
    response = lm.replace(effects=(_UnknownSaturation(limit=7.0),) + tuple(lm.sensor_effects)).simulate(LM_GAINS)
    out["lm-numpy"] = _digest(response.u, response.y)
    bare = LinearMotorEnv(noise=False, current_limit=None, sensor_resolution=None).loop
    for method in ("linear", "stepping"):
        response = bare.simulate(LM_GAINS, method=method)
        out[f"lm-bare-{method}"] = _digest(response.u, response.y)
    for env_id in FIRST_ORDER_ENVS:
        env = gym.make(env_id, expectation_draws=4) if "Rig" in env_id else gym.make(env_id)
        env.reset(seed=7)
        low, high = env.action_space.low, env.action_space.high
        trace = []
        for fraction in (0.2, 0.7):
            obs, reward, _, _, info = env.step(low + fraction * (high - low))
            trace += [obs, [reward, info["true_cost"]], info["u"], info["y"]]
        out[env_id] = _digest(*trace)
    return out


FIRST_ORDER_ENVS = ["gbo_envs/DCMotor-v0", "gbo_envs/DCMotorDrift-v0", "gbo_envs/DCMotorStep-v0",
                    "gbo_envs/DCMotorRig-v0", "gbo_envs/LinearMotor-v0", "gbo_envs/LinearMotorDrift-v0",
                    "gbo_envs/LinearMotorStep-v0", "gbo_envs/LinearMotorRig-v0"]
#: Checksums of the responses computed with the code before controllers of any order existed (the first-order law only,
#: commit 7380b0b). Run under the same libraries, that code and today's give sha256-identical responses (checked on
#: 2026-12-02 with scipy 1.17.1, numpy 2.4.6, numba 0.68.1); the checksums are compared within RTOL, since a new
#: scipy or numba release moves the last bits of the recursions (7380b0b's own sha256 pins failed under these
#: releases), while any change of the loop moves them by far more (a gain changed by 1e-7 of itself: see below).
PINNED = {
    "dc-linear": [4265085.750513, 1041192354.824, 6820514.710061, 114.5065962918, 327.9777927011],
    "dc-noisy-linear": [4265068.947869, 1041197203.845, 6820504.341956, 113.793709571, 329.1473724752],
    "dc-stepping": [4265085.750313, 1041192354.419, 6820514.709537, 114.5065962918, 327.9777927089],
    "dc-noisy-stepping": [4265068.947515, 1041197203.417, 6820504.34118, 113.7937096734, 329.1473724836],
    "lm-stepping": [3546.870697688, 750830.1171742, 4255.785572078, -17.12196970759, 401.362],
    "lm-numpy": [3546.870697688, 750830.1171742, 4255.785572078, -17.12196970759, 401.362],
    "lm-bare-linear": [120.4436936923, 1076361.717746, 167.406195652, -184.0181721469, 401.362],
    "lm-bare-stepping": [120.4436936923, 1076361.717772, 167.4061956524, -184.018172155, 401.362],
    "gbo_envs/DCMotor-v0": [2161268.069878, 533427590.5907, 3356836.055358, -0.979849631114, 319.2715759635],
    "gbo_envs/DCMotorDrift-v0": [2162894.312232, 533863205.1595, 3359472.088726, -0.9772165382189, 319.2089172975],
    "gbo_envs/DCMotorStep-v0": [2161268.069878, 533427590.5907, 3356836.055358, -0.979849631114, 319.2715759635],
    "gbo_envs/DCMotorRig-v0": [2191110.031712, 541993721.6569, 3398801.412717, -1.00661517744, 322.5961596924],
    "gbo_envs/LinearMotor-v0": [13013.6532637, 62753511.25485, 16445.05347871, -16.59494222786, 5832.48],
    "gbo_envs/LinearMotorDrift-v0": [13011.66996563, 62753682.89828, 16442.0193769, -16.78552652545, 5832.48],
    "gbo_envs/LinearMotorStep-v0": [13013.6532637, 62753511.25485, 16445.05347871, -16.59494222786, 5832.48],
    "gbo_envs/LinearMotorRig-v0": [13135.60005189, 62753555.08973, 16603.20435557, -14.63518733251, 5832.48],
}

#: Relative tolerance of the checksums: the linear (lfilter) and stepping paths of one loop differ by 5e-11.
RTOL = 1e-10


def test_pi_and_pdt1_loops_are_those_of_the_first_order_code():
    actual = _first_order_digests()
    assert actual.keys() == PINNED.keys()
    for case, checksums in PINNED.items():
        np.testing.assert_allclose(actual[case], checksums, rtol=RTOL, err_msg=case)


def test_the_checksums_see_a_gain_moved_by_a_ten_millionth():
    response = DCMotorEnv(noise=False).loop.simulate(DC_GAINS * (1.0 + 1e-7), method="linear")
    moved = np.asarray(_digest(response.u, response.y))
    assert not np.allclose(moved, PINNED["dc-linear"], rtol=RTOL, atol=0.0)


# -- PID ----------------------------------------------------------------------------------------------------------

def test_pid_names_units_and_continuous_law():
    pid = PIDController(filter_time=0.02)
    assert pid.gain_names == ("Kp", "Ki", "Kd") and pid.has_integrator and pid.has_state_space
    assert pid.units_for("A", "m") == ("A/m", "A/(m s)", "A s/m")
    w = np.array([0.1, 3.0, 50.0, 900.0])
    s = 1j * w
    _, got = freqs(*pid.transfer_function([0.8, 1.5, 0.3]), w)
    np.testing.assert_allclose(got, 0.8 + 1.5 / s + 0.3 * s / (0.02 * s + 1), rtol=1e-9)
    four = PIDController(filter_time=None)
    assert four.gain_names == ("Kp", "Ki", "Kd", "Tf") and four.units_for("A", "m")[3] == "s"
    _, same = freqs(*four.transfer_function([0.8, 1.5, 0.3, 0.02]), w)
    np.testing.assert_allclose(same, got, rtol=1e-12)
    # the filter time as a gain simulates as the fixed one
    fixed = dc_pid_loop().simulate(PID_GAINS)
    as_gain = dc_pid_loop(filter_time=None).simulate(np.column_stack([PID_GAINS, np.full(3, 0.02)]))
    assert np.array_equal(fixed.y, as_gain.y)


def test_tustin_is_scipys_bilinear_transform_row_by_row():
    pid = PIDController(filter_time=0.02)
    a, b, c, d = pid.continuous(PID_GAINS)
    ad, bd, cd, dd = tustin(a, b, c, d, 0.002)
    for i in range(len(PID_GAINS)):
        ref = cont2discrete((a[i], b[i], c[i][None, :], d[i][None, :]), 0.002, method="bilinear")
        for mine, theirs in zip((ad[i], bd[i], cd[i], dd[i]), ref[:4]):
            np.testing.assert_allclose(mine, np.reshape(theirs, mine.shape), rtol=1e-13, atol=1e-15)


def test_pid_z_transfer_is_the_exact_tustin_substitution():
    """``s -> (2/dt)(1 - q)/(1 + q)`` in exact rationals, ``q = z^-1``."""
    kp, ki, kd, tf, h = (Fraction(v) for v in (0.855, 0.915, 0.2, 0.02, 0.002))
    low_pass = [2 * tf + h, -(2 * tf - h)]  # (2 Tf + h) - (2 Tf - h) q
    den = [low_pass[0], low_pass[1] - low_pass[0], -low_pass[1]]  # times (1 - q)
    integral = [ki * h / 2 * x for x in (low_pass[0], low_pass[0] + low_pass[1], low_pass[1])]  # (1 + q) low_pass
    derivative = [2 * kd, -4 * kd, 2 * kd]  # 2 Kd (1 - q)^2
    num = [kp * dn + i + dv for dn, i, dv in zip(den, integral, derivative)]
    num_z, num_r, den_z = PIDController(filter_time=0.02).z_transfer(PID_GAINS[:1], 0.002)
    assert num_r is None
    np.testing.assert_allclose(num_z[0], [float(x / den[0]) for x in num], rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(den_z[0], [float(x / den[0]) for x in den], rtol=1e-13, atol=1e-14)


def test_pid_without_derivative_is_the_papers_pi():
    pi = ClosedLoop(dc_motor_plant(9.544, 4.145, 4.199, 0.002), PIController(), 0.002, 5.0, 245.0, 306.0)
    gains = np.array([[0.54, 1.16], [0.85, 1.07]])
    pid = dc_pid_loop().simulate(np.column_stack([gains[:, 0], gains[:, 0] * gains[:, 1], np.zeros(2)]))
    np.testing.assert_allclose(pid.y, pi.simulate(gains, method="stepping").y, rtol=0, atol=1e-9)


def test_pid_linear_and_stepping_paths_agree():
    loop = dc_pid_loop()
    linear, stepping = (loop.simulate(PID_GAINS, method=m) for m in ("linear", "stepping"))
    np.testing.assert_allclose(linear.y, stepping.y, rtol=0, atol=1e-6 * 61.0)
    np.testing.assert_allclose(linear.u, stepping.u, rtol=0, atol=1e-6 * np.max(np.abs(stepping.u)))
    assert np.array_equal(loop.simulate(PID_GAINS).y, stepping.y)  # "auto" steps a state-space law


def test_pid_stepping_matches_an_extended_precision_recursion():
    loop = dc_pid_loop()
    gains = PID_GAINS[:1]
    y = loop.simulate(gains, method="stepping").y[0]
    ld = np.longdouble
    law = loop.controller.state_space(gains, loop.dt)
    a, b, c, d = (np.asarray(m[0], dtype=ld) for m in (law.a, law.b, law.c, law.d))
    plant = loop._discrete
    phi, gamma, out = (np.asarray(m, dtype=ld) for m in (plant.phi, plant.gamma0, plant.c))
    x_rest, u_rest = plant.equilibrium(245.0)
    x, xc, u_rest = np.asarray(x_rest[:, 0], dtype=ld), np.zeros(2, dtype=ld), ld(u_rest[0])
    commands, exact = [], []
    for k in range(loop.n_steps):
        exact.append(out @ x)
        e = ld(306.0) - exact[-1]
        commands.append(u_rest + d[0] * e + c @ xc)
        xc = a @ xc + b[:, 0] * e
        x = phi @ x + gamma * (commands[k - plant.delay_steps] if k >= plant.delay_steps else u_rest)
    np.testing.assert_allclose(y, np.array(exact, dtype=float), rtol=0, atol=1e-10)


def test_bad_pid_and_limit_arguments_are_named():
    with pytest.raises(ValueError, match="filter_time"):
        PIDController(filter_time=0.0)
    with pytest.raises(ValueError, match="output_limit"):
        PIDController(output_limit=-1.0)
    with pytest.raises(ValueError, match="anti_windup"):
        PIDController(anti_windup="reset")
    with pytest.raises(ValueError, match="tracking_time"):
        PIDController(output_limit=1.0, anti_windup="back-calculation")
    with pytest.raises(ValueError, match="Tf"):
        PIDController(filter_time=None).continuous(np.array([[1.0, 1.0, 1.0, 0.0]]))
    with pytest.raises(ValueError, match="gains"):
        PIDController().state_space(np.ones((2, 2)), 0.01)


# -- cascade ------------------------------------------------------------------------------------------------------

def test_cascade_feedback_law_is_pi_times_position_p_plus_filtered_speed():
    cascade = CascadeController(speed_filter_time=0.001)
    assert cascade.gain_names == ("Kv", "Kp", "Ki", "Kff")
    assert cascade.units_for("A", "m") == ("1/s", "A/(m/s)", "1/s", "1")
    kv, kp, ki, kff = 40.0, 25.0, 80.0, 0.6
    w = np.array([1.0, 30.0, 300.0, 3000.0])
    s = 1j * w
    expected = kp * (1 + ki / s) * (kv + s / (0.001 * s + 1))
    _, got = freqs(*cascade.transfer_function([kv, kp, ki, kff]), w)
    np.testing.assert_allclose(got, expected, rtol=1e-9)
    # from the reference, with the setpoint filter F = 1/(Tr s + 1): Kp (1 + Ki/s) F (Kv + Kff s)
    _, got = freqs(*cascade.reference_transfer_function([kv, kp, ki, kff]), w)
    np.testing.assert_allclose(got, kp * (1 + ki / s) * (kv + kff * s) / (0.01 * s + 1), rtol=1e-9)
    raw = CascadeController(reference_filter_time=None)  # the reference speed from the filtered difference
    _, got = freqs(*raw.reference_transfer_function([kv, kp, ki, kff]), w)
    np.testing.assert_allclose(got, kp * (1 + ki / s) * (kv + kff * s / (0.001 * s + 1)), rtol=1e-9)
    assert CascadeController(feedforward=False).gain_names == ("Kv", "Kp", "Ki")


def test_cascade_speed_estimate_is_the_filtered_difference_the_loop_uses():
    cascade = CascadeController(speed_filter_time=0.002)
    y = 0.03 + 0.01 * (1 - np.exp(-np.arange(50) / 10.0))
    v = cascade.speed_estimate(y, 0.001)
    a = (2 * 0.002 - 0.001) / (2 * 0.002 + 0.001)
    expected, previous = [], 0.0
    for k in range(50):
        previous = a * previous + (1 - a) * (y[k] - y[k - 1 if k else 0]) / 0.001
        expected.append(previous)
    np.testing.assert_allclose(v, expected, rtol=1e-12)
    # the law's speed path (Kv = Ki = Kff = 0, Kp = 1: u = -v_hat = the filtered difference of e = r - y)
    num, _, den = cascade.z_transfer(np.array([[0.0, 1.0, 0.0, 0.0]]), 0.001)
    q = np.exp(-1j * np.array([1.0, 100.0, 2000.0]) * 0.001)  # z^-1 on the unit circle
    law = np.polyval(num[0][::-1], q) / np.polyval(den[0][::-1], q)
    np.testing.assert_allclose(law, (1 - a) / 0.001 * (1 - q) / (1 - a * q), rtol=1e-7)


def test_cascade_linear_and_stepping_paths_agree():
    loop = slider_loop()
    linear, stepping = (loop.simulate(CASCADE_GAINS, method=m) for m in ("linear", "stepping"))
    np.testing.assert_allclose(linear.y, stepping.y, rtol=0, atol=1e-9 * 0.01)
    np.testing.assert_allclose(linear.u, stepping.u, rtol=0, atol=1e-6)
    assert not stepping.unstable.any()
    # the step ends at the reference: the speed integrator removes the drag's error
    np.testing.assert_allclose(stepping.y[:, -1], 0.04, atol=2e-5)


@pytest.mark.parametrize("aw", ["clamping", "back-calculation", "none"])
def test_a_limited_cascade_clips_its_command_and_is_stepped_the_same_compiled_and_in_numpy(aw, monkeypatch):
    loop = slider_loop(effects=(Quantization(step=5e-6),), output_limit=7.0, anti_windup=aw, tracking_time=0.005)
    with pytest.raises(ValueError, match="output_limit"):
        loop.simulate(CASCADE_GAINS, method="linear")
    compiled = loop.simulate(CASCADE_GAINS)
    monkeypatch.setattr(kernels, "KERNEL_CODES", {})
    numpy = loop.simulate(CASCADE_GAINS)
    assert np.array_equal(compiled.u, numpy.u) and np.array_equal(compiled.y, numpy.y)
    assert np.max(np.abs(compiled.u)) == 7.0  # the step saturates the current, and no more


@pytest.mark.parametrize("aw", ["clamping", "back-calculation"])
def test_anti_windup_keeps_the_speed_integrator_from_overshooting(aw):
    gains = CASCADE_GAINS[:1]
    wound = slider_loop(output_limit=7.0, anti_windup="none").simulate(gains)
    held = slider_loop(output_limit=7.0, anti_windup=aw, tracking_time=0.005).simulate(gains)
    loop = slider_loop()
    overshoot = [loop.metrics(r)[0, 0] for r in (wound, held)]
    assert overshoot[0] > 10.0 > 1.0 > overshoot[1]  # % of the 10 mm step


def test_anti_windup_acts_only_at_the_limit():
    gains = np.array([[41.7, 26.7, 83.3, 1.0]])
    free = slider_loop().simulate(gains)
    wide = slider_loop(output_limit=1e6).simulate(gains)  # never reached: the linear response
    np.testing.assert_allclose(wide.y, free.y, rtol=0, atol=1e-12)
