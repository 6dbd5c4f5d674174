"""Twin estimators: identify_linear, LinearTwin and GreyBoxTwin conventions, the one RMSE, and the grey-box solver
against a plain ``scipy.optimize.least_squares`` call."""

from __future__ import annotations

from dataclasses import fields

import gymnasium as gym
import numpy as np
import pytest
from scipy.optimize import least_squares
from sklearn.base import clone
from sklearn.exceptions import NotFittedError

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin import DelaySearch, GreyBoxTwin, IdentifyOptions, LinearTwin, SrivcOptions, TwinEnv, identify_linear
from agents.twin.csvio import records_from_loop
from agents.twin.fidelity import rmse
from agents.twin.least_squares import fit_problems, make_problem, residual
from agents.twin.linear_fit import linear_fit
from agents.twin.model import ModelSpec
from agents.twin.records import Batch
from agents.twin.simulation import simulate_sets

TRUE = np.array([9.544, 4.145, 4.199])


@pytest.fixture(scope="module")
def clean_records():
    env = gym.make("gbo_envs/DCMotor-v0", noise=False)
    env.reset(seed=0)
    return [env.step(np.array(g))[4] for g in ([0.5, 1.2], [0.9, 2.0])]


@pytest.fixture(scope="module")
def saturating():
    """Records of a DC motor whose command saturates at 150 V, and a grey-box twin fitted on two of them."""
    env = gym.make("gbo_envs/DCMotor-v0", effects={"saturation": {"limit": 150.0}}, output_noise_std=0.05)
    env.reset(seed=2)
    rng = np.random.default_rng(2)
    records = [env.step(rng.uniform(env.action_space.low, env.action_space.high))[4] for _ in range(3)]
    return env, records, GreyBoxTwin(effects=["saturation"]).fit(records[:2])


def _options(**settings) -> IdentifyOptions:
    """The flat settings (:func:`identify_linear`'s keywords) in their groups, unchecked."""
    groups = {name: {key: settings.pop(key) for key in list(settings) if key in {f.name for f in fields(kind)}}
              for name, kind in (("delay_search", DelaySearch), ("solver", SrivcOptions))}
    return IdentifyOptions(**settings, delay_search=DelaySearch(**groups["delay_search"]),
                           solver=SrivcOptions(**groups["solver"]))


def test_identify_linear_is_what_linear_twin_fits(clean_records):
    fit = identify_linear(clean_records, max_delay=0.006)
    twin = LinearTwin(IdentifyOptions(delay_search=DelaySearch(max_delay=0.006))).fit(clean_records)
    np.testing.assert_allclose(fit.params, TRUE, rtol=1e-3)
    np.testing.assert_array_equal(twin.params_, fit.params)
    assert twin.delay_ == fit.delay and twin.rmse_ == fit.rmse and fit.param_names == ("b0", "a1", "a2")
    assert twin.plant_.output == "speed" and fit.plant("position").output == "position"


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"n_poles": 0}, r"n_poles: must be an int in \[1, inf\), got 0"),
    ({"tol": 0.0}, r"tol: must be a finite float in \(0, inf\), got 0.0"),
    ({"hold": "spline"}, r"hold: must be one of \('auto', 'zoh', 'foh'\), got 'spline'"),
    ({"delay": -0.001}, r"delay: must be None or a finite float in \[0, inf\), got -0.001"),
    ({"delay": np.inf}, r"delay: must be None or a finite float in \[0, inf\), got inf"),
    ({"polish": 1}, r"polish: must be a bool, got 1"),
    ({"n_zeros": 2}, r"n_zeros: must be an integer with 0 <= n_zeros < n_poles = 2"),
    ({"n_integrators": 2}, r"n_integrators: must be an integer with 0 <= n_integrators < n_poles = 2"),
])
def test_bad_settings_name_the_parameter_and_its_range(clean_records, kwargs, message):
    with pytest.raises(ValueError, match=message):
        LinearTwin(_options(**kwargs)).fit(clean_records)
    with pytest.raises(ValueError, match=message):
        identify_linear(clean_records, **kwargs)


def test_linear_twin_rejects_a_bad_output(clean_records):
    with pytest.raises(ValueError, match=r"output: must be one of \('speed', 'position'\), got 'torque'"):
        LinearTwin(output="torque").fit(clean_records)


def test_score_is_the_negative_normalised_rmse(clean_records):
    env = gym.make("gbo_envs/DCMotor-v0", output_noise_std=0.5)
    env.reset(seed=3)
    noisy = [env.step(np.array(g))[4] for g in ([0.5, 1.2], [0.9, 2.0], [0.7, 1.0])]
    twin = LinearTwin(IdentifyOptions(delay_search=DelaySearch(max_delay=0.006))).fit(noisy[:2])
    assert twin.score(noisy[:2]) == pytest.approx(-twin.rmse_, rel=1e-12)
    held_out = twin.score(noisy[2:])
    assert -0.02 < held_out < -0.004  # white noise of 0.5 rad/s on a step of about 61 rad/s
    assert twin.score(clean_records) > held_out  # noise-free records replay better


def test_greybox_twin_finds_the_saturation_limit(saturating):
    env, records, twin = saturating
    assert twin.effect_params_["saturation"]["limit"] == pytest.approx(150.0, rel=0.02)
    np.testing.assert_allclose(twin.params_, TRUE, rtol=0.05)
    assert twin.param_names_ == ("b0", "a1", "a2") and twin.greybox_.spec.effect_names == ("saturation",)
    assert twin.rmse_abs_ == pytest.approx(0.05, rel=0.3)  # the sensor-noise floor
    assert twin.score(records[:2]) == pytest.approx(-twin.rmse_, rel=1e-6)
    assert twin.score(records[2:]) > -3 * twin.rmse_  # the held-out record replays as well
    assert [len(y) for y in twin.predict(records)] == [len(r["y"]) for r in records]
    loop = TwinEnv(env, twin).loop
    assert [b.name for b in loop.effects] == ["saturation", "offset"]


def test_greybox_twin_follows_sklearn_conventions(saturating):
    _, records, twin = saturating
    est = GreyBoxTwin(effects=["saturation"], n_samples=200)
    assert est.get_params() == {"effects": ["saturation"], "max_iter": 25, "n_integrators": 0, "n_poles": 2,
                                "n_samples": 200, "n_zeros": 0, "output": "speed"}
    with pytest.raises(NotFittedError):
        est.predict(records)
    with pytest.raises(NotFittedError):
        est.score(records)
    assert not hasattr(clone(twin), "plant_") and clone(twin).get_params() == twin.get_params()
    with pytest.raises(ValueError, match="unknown effect 'backlsh'"):
        GreyBoxTwin(effects=["backlsh"]).fit(records)
    with pytest.raises(ValueError, match=r"max_iter: must be an int in \[0, inf\), got -1"):
        GreyBoxTwin(max_iter=-1).fit(records)
    with pytest.raises(ValueError, match="n_samples: must be None"):
        GreyBoxTwin(n_samples=100).fit(Batch.from_records(records))
    with pytest.raises(ValueError, match="stacked with n_samples=60"):
        GreyBoxTwin(n_samples=100).fit(Batch.from_records(records, n_samples=60))
    stacked = GreyBoxTwin(n_samples=60).fit(Batch.from_records(records, n_samples=60))  # as the records themselves
    np.testing.assert_array_equal(stacked.greybox_.theta, GreyBoxTwin(n_samples=60).fit(records).greybox_.theta)
    assert stacked.n_samples_ == 60


def test_rmse_masks_normalises_and_flags_divergence():
    error = np.array([[3.0, 4.0, 99.0], [1.0, 1.0, 1.0]])
    mask = np.array([[True, True, False], [True, True, True]])
    assert rmse(error, mask=mask) == pytest.approx(np.sqrt((9 + 16 + 3) / 5))
    assert rmse(error, mask=mask, height=np.array([5.0, 1.0])) == pytest.approx(np.sqrt((9 / 25 + 16 / 25 + 3) / 5))
    assert rmse(np.array([1.0, -1.0])) == 1.0
    assert rmse(np.array([1.0, np.nan])) == np.inf
    assert rmse(error[:1, :2], height=np.array([0.0])) == np.inf  # a record without a step


def test_fit_problems_matches_a_plain_least_squares_call():
    """fit_problems (grouped forward-difference Jacobian, free mask) lands where scipy's own 2-point call does."""
    env = gym.make("gbo_envs/DCMotor-v0", effects={"saturation": {"limit": 150.0}}, output_noise_std=0.05)
    loop = env.unwrapped.loop.replace(duration=1.5)
    gains = np.array([[0.3, 1.0], [0.9, 1.2], [1.05, 2.0]])
    data = Batch.from_records(records_from_loop(loop, gains, rng=np.random.default_rng(1)))
    base = linear_fit(data, refine=False)
    spec = ModelSpec().with_effect("saturation")
    rows = np.arange(data.n_records)
    start = np.concatenate([base.theta, [140.0]])
    ours = make_problem(data, spec, start, base.y0, base.bias, rows, np.array([100.0]), np.array([300.0]),
                        np.array([50.0]))
    free = np.flatnonzero(ours.free)
    x0, theta0 = ours.theta[free].copy(), ours.theta.copy()

    def full(x):
        theta = theta0.copy()
        theta[free] = x
        return theta

    def fun(x):
        return residual(data, rows, simulate_sets(data, [(spec, full(x), rows)])[0]).ravel()

    plain = least_squares(fun, x0, bounds=(ours.lower[free], ours.upper[free]), x_scale=ours.scale[free],
                          method="trf", ftol=1e-9, xtol=1e-12, gtol=1e-12, max_nfev=80)
    fit_problems(data, [ours], max_iter=79, tol=1e-9)
    assert ours.cost < 0.2 * float(np.sum(fun(x0) ** 2))
    assert ours.cost == pytest.approx(float(np.sum(plain.fun**2)), rel=1e-3)
    tolerance = 0.03 * np.maximum(np.abs(plain.x), ours.scale[free])
    assert np.all(np.abs(ours.theta[free] - plain.x) <= tolerance)
    assert ours.theta[spec.n_linear + 1] == pytest.approx(150.0, rel=0.01)  # the saturation limit
    np.testing.assert_allclose(ours.theta[:3], TRUE, rtol=0.01)


def test_decimated_input_is_the_mean_over_each_hold_interval():
    from agents.twin.records import as_records, decimate

    t = np.arange(11) * 0.1
    record = as_records([{"t": t, "r": np.full(11, 2.0), "u": t**2, "y": t.copy()}])[0]
    sampled, held = decimate(record, 4), decimate(record, 4, mean_input=True)
    np.testing.assert_array_equal(held.t, sampled.t)
    np.testing.assert_array_equal(held.y, sampled.y)  # the outputs stay exact measurements
    np.testing.assert_array_equal(sampled.u, record.u[[0, 3, 6, 9]])
    np.testing.assert_allclose(held.u, [np.mean(record.u[0:3]), np.mean(record.u[3:6]), np.mean(record.u[6:9]),
                                        np.mean(record.u[9:11])])
    assert decimate(record, None, mean_input=True) is record


def test_greybox_twin_on_decimated_records_finds_the_true_plant():
    """100 of 2,500 noise-free samples with the drive at its limit most of the transient: the twin must be the
    plant (a point-sampled input gave a 4 % low gain and a 5-unit input offset, whose loop has its cost optimum
    at 3 times the plant's optimal cost)."""
    env = gym.make("gbo_envs/DCMotor-v0", noise=False, effects={"saturation": {"limit": 138.0}})
    env.reset(seed=0)
    records = [env.step(np.array(g))[4] for g in ([0.3, 1.0], [0.9, 2.0], [0.6, 1.5])]
    twin = GreyBoxTwin(effects=["saturation"], n_samples=100).fit(records)
    np.testing.assert_allclose(twin.params_, TRUE, rtol=2e-3)
    assert twin.effect_params_["saturation"]["limit"] == pytest.approx(138.0, abs=0.05)
    offset = [b.value for b in twin.effects_ if b.name == "offset"]
    assert abs(offset[0]) < 0.1  # input units; the plant has no input offset


def test_decimation_keeps_every_sample_where_the_command_switches_within_a_hold():
    from agents.twin.records import as_records, decimate_records, hold_spread

    t = np.arange(301) * 1e-3
    smooth = as_records([{"t": t, "r": np.full(301, 1.0), "u": np.exp(-t / 0.05), "y": 1.0 - np.exp(-t / 0.05)}])
    kept = decimate_records(smooth, 100, mean_input=True)
    assert kept[0].n_steps == 100 and kept[0].dt == pytest.approx(3e-3)
    bang = np.where(t < 0.015, 300.0, np.where(t < 0.03, -300.0, 0.0)) * (-1.0) ** np.arange(301)
    switching = as_records([{"t": t, "r": np.full(301, 1.0), "u": bang, "y": t.copy()}])
    assert hold_spread(switching[0], 3) > 0.5
    assert decimate_records(switching, 100, mean_input=True)[0] is switching[0]
    # one stride for records of different lengths, so that they keep one sample time
    both = decimate_records([smooth[0], as_records([{"t": t[:201], "r": np.ones(201), "u": np.exp(-t[:201] / 0.05),
                                                    "y": t[:201].copy()}])[0]], 100)
    assert both[0].dt == both[1].dt == pytest.approx(2e-3)


def test_greybox_twin_finds_the_linear_motors_drive_limit_on_decimated_records():
    """The linear motor's step is a near bang-bang move at its 7 A limit (commands of hundreds of A switching
    within 3 ms): a hold's mean command is not its saturated mean, so its records must not be decimated (on
    100 of 301 samples the fitted limit was 38 A)."""
    env = gym.make("gbo_envs/LinearMotor-v0")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    records = [env.step(rng.uniform(env.action_space.low, env.action_space.high))[4] for _ in range(3)]
    twin = GreyBoxTwin(effects=["saturation"], n_poles=2, n_integrators=1, output="position", n_samples=100)
    twin.fit(records)
    assert twin.effect_params_["saturation"]["limit"] == pytest.approx(7.0, rel=0.01)
    np.testing.assert_allclose(twin.params_, [0.44262 / 0.070983, 0.8 / 0.070983], rtol=0.01)


def test_a_position_outputs_error_is_taken_on_its_increments():
    from agents.twin.least_squares import residual
    from agents.twin.model import output_error

    t = np.arange(6) * 0.01
    y = np.array([0, 1, 2, 3, 3, 3.0])
    data = Batch.from_records([{"t": t, "r": np.full(6, 3.0), "u": np.ones(6), "y": y}])  # a closed loop
    y_sim = np.array([[0, 1, 2, 2.5, 2.5, 2.5]])  # stuck 0.5 short: an offset that persists
    e = data.y - y_sim
    np.testing.assert_allclose(output_error(data.y, y_sim, data.mask, ModelSpec(output="speed")), e)
    increments = output_error(data.y, y_sim, data.mask, ModelSpec(output="position"), data.closed_loop)
    np.testing.assert_allclose(increments, [[0, 0, 0, 0.5, 0, 0]])  # counted once
    np.testing.assert_allclose(residual(data, np.array([0]), y_sim, increments=True), -increments)
    # an open-loop record (no controller to take the offset out): its position error is the error
    open_loop = Batch.from_records([{"t": t, "r": np.ones(6), "u": np.ones(6), "y": y}])
    assert not open_loop.closed_loop[0]
    np.testing.assert_allclose(output_error(open_loop.y, y_sim, open_loop.mask, ModelSpec(output="position"),
                                            open_loop.closed_loop), e)
    np.testing.assert_allclose(residual(open_loop, np.array([0]), y_sim, increments=True), -e)


def test_a_fitted_twin_scores_its_own_and_new_rig_records_at_its_fit_error():
    """``score`` refits only each record's rest level and plant-input bias. Behind dry friction the error is
    flat in a bias inside the stiction band, so the start decides: from the bias that holds the linear part at
    rest under the first command, the rig twin scored its own records at 5-10 times its ``rmse_`` and guided BO
    refitted it after every experiment."""
    env = gym.make("gbo_envs/LinearMotorRig-v0")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    records = [env.step(rng.uniform(env.action_space.low, env.action_space.high))[4] for _ in range(3)]
    twin = GreyBoxTwin(effects={"saturation": {"limit": 7.0}, "coulomb_friction": {"torque": 0.5}}, n_poles=2,
                       n_integrators=1, output="position").fit(records[:2])
    assert -twin.score(records[:2]) == pytest.approx(twin.rmse_, rel=0.1)
    assert -twin.score(records[2:]) < 1.5 * twin.rmse_


@pytest.mark.slow
def test_diagnosis_names_the_linear_rigs_friction_and_drive_limit():
    """LinearMotorRig-v0: a 7 A drive limit and 0.5 A of dry friction behind a 5 um sensor. On the position
    itself a replayed slider that sticks a moment off the plant's stays off, and the ladder took a time delay
    or cogging in place of the friction, with a 9-88 A limit."""
    from agents.twin.selection import diagnosed_twin

    env = gym.make("gbo_envs/LinearMotorRig-v0")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    records = [env.step(rng.uniform(env.action_space.low, env.action_space.high))[4] for _ in range(4)]
    twin, _ = diagnosed_twin(records, ModelSpec(n_poles=2, n_integrators=1, output="position"))
    assert set(twin.effect_params_) == {"saturation", "coulomb_friction"}
    assert twin.effect_params_["saturation"]["limit"] == pytest.approx(7.0, rel=0.1)
    assert twin.effect_params_["coulomb_friction"]["torque"] == pytest.approx(0.5, rel=0.5)
