"""Digital twin: SRIVC identification, fidelity of the twin env, sklearn conventions, input validation."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest
from sklearn.base import clone
from sklearn.exceptions import NotFittedError
from sklearn.model_selection import GridSearchCV

from agents.twin import DelaySearch, IdentifyOptions, LinearTwin, SrivcOptions, TwinEnv, make_twin_env
from gbo_envs import ClosedLoop, ContinuousPlant, ControllerTuningEnv, CostSpec, PDT1Controller
from tests.support import DC_MOTOR_PARAMS, gain_grid

TRUE = DC_MOTOR_PARAMS
KNOWN_DELAY = IdentifyOptions(delay_search=DelaySearch(delay=0.002))  # the DC motor's delay, 2 ms


def _records(n: int, seed: int = 0, **kwargs) -> tuple[gym.Env, list[dict]]:
    env = gym.make("gbo_envs/DCMotor-v0", **kwargs)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    low, high = env.action_space.low, env.action_space.high
    return env, [env.step(rng.uniform(low, high))[4] for _ in range(n)]


@pytest.fixture(scope="module")
def clean():
    env, records = _records(3, noise=False)
    return env, records, LinearTwin().fit(records)


def test_recovers_dc_motor_parameters_on_noise_free_data(clean):
    _, _, twin = clean
    assert twin.param_names_ == ("b0", "a1", "a2")
    np.testing.assert_allclose(twin.params_, TRUE, rtol=1e-3)
    assert twin.delay_ == pytest.approx(0.002, abs=1e-4)
    assert twin.rmse_ < 1e-6
    assert twin.converged_
    np.testing.assert_allclose(twin.rest_levels_[:, 0], 245.0, atol=1e-3)  # y0 = r1
    np.testing.assert_allclose(twin.rest_levels_[:, 1], 245.0 * 4.199 / 9.544, rtol=1e-4)  # u0 = r1 / G(0)
    assert isinstance(twin.plant_, ContinuousPlant)
    np.testing.assert_allclose(twin.plant_.den, (1.0, *TRUE[1:]), rtol=1e-3)


def test_single_experiment_is_enough_without_noise():
    _, records = _records(1, seed=3, noise=False)
    twin = LinearTwin().fit(records[0])  # a single record mapping is accepted
    np.testing.assert_allclose(twin.params_, TRUE, rtol=1e-2)


def test_twin_cost_matches_plant_across_feasible_set(clean):
    env, _, twin = clean
    twin_env = make_twin_env(env, twin)
    assert isinstance(twin_env, TwinEnv) and isinstance(twin_env, ControllerTuningEnv)
    np.testing.assert_array_equal(twin_env.normalizers, env.unwrapped.normalizers)
    np.testing.assert_array_equal(twin_env.weights, env.unwrapped.weights)
    np.testing.assert_array_equal(twin_env.action_space.low, env.action_space.low)
    assert twin_env.loop.effects == () and twin_env.loop.output_noise_std == 0.0
    gains = gain_grid(env, 20)
    _, plant_cost = env.unwrapped.evaluate(gains)
    _, twin_cost = twin_env.evaluate(gains)
    assert twin_cost.shape == (400,)
    assert np.max(np.abs(twin_cost - plant_cost) / plant_cost) < 0.01


def test_twin_env_steps_like_the_plant_env(clean):
    env, records, twin = clean
    twin_env = TwinEnv(env, twin)
    twin_env.reset(seed=0)
    _, reward, _, _, info = twin_env.step(records[0]["gains"])
    assert info["y"].shape == records[0]["y"].shape
    np.testing.assert_allclose(info["y"], records[0]["y"], atol=1e-3)
    assert -reward == pytest.approx(records[0]["true_cost"], rel=1e-3)


def test_delay_is_recovered_within_one_sample():
    _, records = _records(2, seed=1, noise=False, delay=0.007)
    twin = LinearTwin().fit(records)
    assert abs(twin.delay_ - 0.007) < 0.002
    np.testing.assert_allclose(twin.params_, TRUE, rtol=1e-2)


def test_fixed_delay_and_decimated_records(clean):
    _, records, _ = clean
    twin = LinearTwin(IdentifyOptions(delay_search=DelaySearch(delay=0.002), solver=SrivcOptions(n_samples=100)))
    twin.fit(records)
    assert twin.delay_ == 0.002 and twin.n_samples_ == 100
    assert twin.dt_ == pytest.approx(0.05)
    np.testing.assert_allclose(twin.params_, TRUE, rtol=1e-2)
    assert len(twin.predict(records)[0]) == 100


def test_sensor_noise_gives_noise_floor_rmse():
    _, records = _records(5, seed=2, output_noise_std=0.5)
    twin = LinearTwin(IdentifyOptions(delay_search=DelaySearch(max_delay=0.01))).fit(records)
    np.testing.assert_allclose(twin.params_, TRUE, rtol=0.03)
    assert twin.rmse_ == pytest.approx(0.5 / 61.0, rel=0.1)  # white noise of 0.5 rad/s on a 61 rad/s step
    assert twin.rmse_abs_ == pytest.approx(0.5, rel=0.1)


def test_position_loop_with_integrator():
    plant = ContinuousPlant(num=(0.44262 / 0.070983,), den=(1.0, 15.0, 0.0), delay=0.001, output="position")
    loop = ClosedLoop(plant=plant, controller=PDT1Controller(), dt=0.001, duration=0.3, r1=0.03, r2=0.04)
    low, high = np.array([5123.8, 40.1]), np.array([6136.2, 51.0])
    env = ControllerTuningEnv(loop, low, high, cost=CostSpec(weights=(0.10, 0.18, 0.69, 0.04)),
                              reference_gains=np.linspace(low, high, 5))
    env.reset(seed=0)
    records = [env.step(g)[4] for g in np.linspace(low, high, 2)]
    options = IdentifyOptions(n_integrators=1, delay_search=DelaySearch(max_delay=0.005))
    twin = LinearTwin(options, output="position").fit(records)
    np.testing.assert_allclose(twin.params_, (0.44262 / 0.070983, 15.0), rtol=1e-3)
    assert twin.den_[-1] == 0.0 and twin.delay_ == pytest.approx(0.001, abs=1e-4)
    twin_env = TwinEnv(env, twin)
    assert twin_env.plant.output == "position"
    gains = gain_grid(env, 5)
    np.testing.assert_allclose(twin_env.evaluate(gains)[1], env.evaluate(gains)[1], rtol=0.01)


def test_warm_start_refit_and_polish_safeguard(clean):
    _, records, reference = clean
    est = LinearTwin(warm_start=True).fit(records[:1])
    assert est.fit(records) is est and est.n_records_ == 3
    np.testing.assert_allclose(est.params_, TRUE, rtol=1e-3)
    _, noisy = _records(2, seed=4, output_noise_std=0.5)
    options = IdentifyOptions(delay_search=DelaySearch(max_delay=0.006))
    plain = LinearTwin(options).fit(noisy)
    polished = LinearTwin(dataclasses.replace(options, solver=SrivcOptions(polish=True))).fit(noisy)
    assert polished.rmse_ <= plain.rmse_


# -- scikit-learn conventions -----------------------------------------------------------------------
def test_sklearn_conventions(clean):
    _, records, _ = clean
    est = LinearTwin(IdentifyOptions(n_poles=2, delay_search=DelaySearch(max_delay=0.004)))
    assert est.get_params()["options__n_poles"] == 2 and est.get_params()["options__delay_search__max_delay"] == 0.004
    assert set(est.get_params(deep=False)) == {"options", "output", "warm_start"}
    assert not hasattr(est, "params_")
    with pytest.raises(NotFittedError):
        est.predict(records)
    with pytest.raises(NotFittedError):
        est.score(records)
    assert est.fit(records) is est
    assert clone(est).get_params() == est.get_params() and not hasattr(clone(est), "plant_")
    assert est.set_params(options__n_zeros=1) is est
    assert est.options == IdentifyOptions(n_zeros=1, delay_search=DelaySearch(max_delay=0.004))
    with pytest.raises(ValueError, match="options__n_zero: IdentifyOptions has no field 'n_zero'"):
        est.set_params(options__n_zero=1)
    with pytest.raises(ValueError, match="output__x: output is not an option object"):
        est.set_params(output__x=1)
    with pytest.raises(ValueError, match="options: must be an instance of IdentifyOptions"):
        LinearTwin({"n_poles": 2}).fit(records)
    search = GridSearchCV(LinearTwin(IdentifyOptions(delay_search=DelaySearch(max_delay=0.004))),
                          {"options__n_poles": [1, 2]}, cv=2)
    assert search.fit(records + records).best_params_ == {"options__n_poles": 2}  # sklearn's nested parameters
    with pytest.raises(ValueError, match="not fitted"):
        TwinEnv(gym.make("gbo_envs/DCMotor-v0"), LinearTwin())


def test_option_groups_are_nested_sklearn_parameters(clean):
    _, records, _ = clean
    est = LinearTwin(IdentifyOptions(delay_search=DelaySearch(max_delay=0.004)))
    params = est.get_params()
    assert params["options__delay_search"] == DelaySearch(max_delay=0.004)
    assert params["options__solver__n_samples"] is None and params["options__solver__hold"] == "auto"
    est.set_params(options__solver__n_samples=100, options__n_poles=3)
    assert est.options == IdentifyOptions(n_poles=3, delay_search=DelaySearch(max_delay=0.004),
                                          solver=SrivcOptions(n_samples=100))
    est.set_params(options__delay_search=DelaySearch(delay=0.002), options__delay_search__refine_delay=False)
    assert est.options.delay_search == DelaySearch(delay=0.002, refine_delay=False)  # the group, then its field
    assert clone(est).get_params() == est.get_params()
    with pytest.raises(ValueError, match="options__solver__n_sample: SrivcOptions has no field 'n_sample'"):
        est.set_params(options__solver__n_sample=1)
    with pytest.raises(ValueError, match="options__n_poles__x: options__n_poles is not an option object"):
        est.set_params(options__n_poles__x=1)
    with pytest.raises(ValueError, match="solver: must be an instance of SrivcOptions, got {'n_samples': 100}"):
        LinearTwin(IdentifyOptions(solver={"n_samples": 100})).fit(records)  # type: ignore[arg-type]
    search = GridSearchCV(LinearTwin(IdentifyOptions(delay_search=DelaySearch(max_delay=0.004))),
                          {"options__solver__n_samples": [50, 200]}, cv=2).fit(records + records)
    assert list(search.cv_results_["param_options__solver__n_samples"]) == [50, 200]
    assert search.best_estimator_.options.solver.n_samples == search.best_params_["options__solver__n_samples"]


def test_fit_accepts_arrays_and_dataframes(clean):
    _, records, twin = clean
    arrays = [np.column_stack([rec["t"], rec["r"], rec["u"], rec["y"]]) for rec in records]
    np.testing.assert_allclose(LinearTwin(KNOWN_DELAY).fit(arrays).params_, twin.params_, rtol=1e-6)
    pd = pytest.importorskip("pandas")
    frame = pd.concat([pd.DataFrame({"experiment": i, "t": r["t"], "r": r["r"], "u": r["u"], "y": r["y"]})
                       for i, r in enumerate(records)])
    np.testing.assert_allclose(LinearTwin(KNOWN_DELAY).fit(frame).params_, twin.params_, rtol=1e-6)
    assert -1e-6 < LinearTwin(KNOWN_DELAY).fit(frame).score(records) <= 0.0


# -- bad input --------------------------------------------------------------------------------------
def _one(clean) -> dict:
    rec = clean[1][0]
    return {name: np.array(rec[name]) for name in ("t", "r", "u", "y")}


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda rec: rec.update(u=rec["u"][:-1]), "equal lengths"),
        (lambda rec: rec["y"].__setitem__(10, np.nan), "y: must be finite, got nan at sample 10"),
        (lambda rec: rec["t"].__setitem__(5, rec["t"][3]), "t: must increase strictly"),
        (lambda rec: rec.pop("u"), "missing field"),
    ],
)
def test_bad_records_raise_clear_value_errors(clean, mutate, message):
    rec = _one(clean)
    mutate(rec)
    with pytest.raises(ValueError, match=message):
        LinearTwin(KNOWN_DELAY).fit([rec])


def test_empty_and_malformed_input_raise(clean):
    with pytest.raises(ValueError, match="at least one"):
        LinearTwin().fit([])
    with pytest.raises(ValueError, match="shape"):
        LinearTwin().fit([np.zeros((10, 3))])
    with pytest.raises(ValueError, match="n_zeros"):
        LinearTwin(IdentifyOptions(n_zeros=2)).fit(clean[1])
    with pytest.raises(ValueError, match="hold"):
        LinearTwin(IdentifyOptions(solver=SrivcOptions(hold="spline"))).fit(clean[1])



def test_simulation_error_over_several_batches_is_that_of_all_samples():
    from agents.twin import srivc
    from agents.twin.fidelity import rmse
    from agents.twin.identify import check_orders, simulation_error
    from agents.twin.records import Batch
    from tests.support import loop_records

    batch = Batch.from_records(loop_records(None, gains=[[0.3, 1.0], [0.6, 1.5], [0.9, 1.2]], duration=0.5))
    orders, theta = check_orders(2, 0, 0), np.array([4.0, 4.0, 9.5])
    groups = batch.groups(max_samples=260)
    assert [rows.tolist() for rows in groups] == [[0], [1], [2]]  # one record per group
    signals = [srivc.prepare(batch.dt, batch.u[rows], batch.y[rows], batch.r[rows, -1], True, "zoh")
               for rows in groups]
    score, score_abs, levels = simulation_error(orders, theta, 0.002, signals)
    y_sim = [srivc.simulate(orders, theta, 0.002, sig, True) for sig in signals]
    errors = np.concatenate([(sig.y + sig.y_ref[:, None]) - out[0] for sig, out in zip(signals, y_sim)])
    heights = np.concatenate([np.abs(sig.r2 - out[1]) for sig, out in zip(signals, y_sim)])
    assert score == pytest.approx(rmse(errors, height=heights), rel=1e-12)
    assert score_abs == pytest.approx(rmse(errors), rel=1e-12)
    np.testing.assert_array_equal(levels[:, 0], np.concatenate([out[1] for out in y_sim]))


def test_the_noise_free_twin_of_a_speed_loop_with_cogging_is_deterministic():
    """The twin's cogging starts at a random angle per noise draw, as the plant's does; its noise-free
    twin (the one simulation per gain of the prior's grid) starts at one angle and has no noise."""
    from agents.twin import GreyBoxTwin

    env = gym.make("gbo_envs/DCMotor-v0", effects={"cogging": {"amplitude": 10.0}})
    quiet = gym.make("gbo_envs/DCMotor-v0", noise=False, effects={"cogging": {"amplitude": 10.0, "synchronised": True}})
    quiet.reset(seed=0)
    records = [quiet.step(np.array(g))[4] for g in ([0.5, 1.2], [0.9, 1.6])]
    twin = GreyBoxTwin(effects={"cogging": {"amplitude": 10.0, "period": 2 * np.pi, "phase": 0.0}}).fit(records)
    twin_env = TwinEnv(env, twin, measurement_noise_std=0.05)
    assert twin_env.loop.stochastic
    plain = twin_env.noise_free()
    assert not plain.loop.stochastic and plain.loop.output_noise_std == 0.0
    assert plain.noise_free() is plain
    assert [b.params["amplitude"] for b in plain.loop.effects if b.name == "cogging"] == \
           [b.params["amplitude"] for b in twin_env.loop.effects if b.name == "cogging"]
    gains = np.array([[0.5, 1.2], [0.55, 1.21]])
    assert np.array_equal(plain.evaluate(gains)[1], plain.evaluate(gains)[1])


@pytest.mark.parametrize("gains", [(0.5, 1.8), (0.6, 2.0)])  # NaN into svd; into lstsq, which printed DLASCL
def test_a_pole_run_off_to_infinity_is_divergence_not_a_nan_in_lapack(gains, capfd):
    """A flexible coupling (a resonance the 2-pole twin lacks): on one record SRIVC's iterates walked a pole off to
    -infinity (a1 = 1e42); e^{A h} of that iterate overflowed, and its NaN filters reached LAPACK ("SVD did not
    converge", or "On entry to DLASCL parameter number 4 had an illegal value" printed from lstsq). Such an iterate
    is divergence, as a non-finite one: the fit goes on at the other delays and starts."""
    from agents.twin import srivc
    from tests.support import FlexibleCouplingRig

    t, r, u, y = FlexibleCouplingRig(omega=15.0, zeta=0.06, noise_std=0.05, seed=0)(np.array(gains))
    twin = LinearTwin(IdentifyOptions(n_poles=2, solver=SrivcOptions(n_samples=100)), warm_start=True)
    twin.fit([{"t": t, "r": r, "u": u, "y": y}])
    assert np.all(np.isfinite(twin.params_)) and np.isfinite(twin.delay_) and twin.rmse_ < 0.01
    assert "DLASCL" not in "".join(capfd.readouterr())
    with pytest.raises(FloatingPointError, match="too fast to discretise"):
        srivc._Prefilter(np.array([1.0, 1.06e42, 2.09e40]), 0.005, 0.1)
