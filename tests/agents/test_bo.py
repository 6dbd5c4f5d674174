"""GP surrogate, acquisition functions and the BO tuner (paper, subsec. BO)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.stats import norm
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor

import agents
from agents.acquisition import ExpectedImprovement, expected_improvement, maximize_on_grid
from agents.surrogate import GPSurrogate
from tests.support import DC_MOTOR_SPACE as SPACE

MINIMUM = np.array([0.4, 1.6])


def bowl(gains) -> float:
    """A smooth cost with its minimum 0.2 at MINIMUM."""
    u = SPACE.to_unit(gains) - SPACE.to_unit(MINIMUM)
    return float(0.2 + 2.0 * u[0] ** 2 + 1.0 * u[1] ** 2)


def test_expected_improvement_closed_form_for_minimisation():
    # z = (J+ - mu) / sigma; EI = sigma (z Phi(z) + phi(z))
    mean, std, best = np.array([0.5, 0.3, 0.7]), np.array([0.1, 0.2, 0.05]), 0.5
    z = (best - mean) / std
    expected = std * (z * norm.cdf(z) + norm.pdf(z))
    np.testing.assert_allclose(expected_improvement(mean, std, best), expected, rtol=1e-12)
    assert expected_improvement([0.0], [1.0], 0.0)[0] == pytest.approx(norm.pdf(0.0))
    # lower mean -> more improvement (the paper's (mu - J+) sign would reverse this)
    assert expected_improvement([0.2], [0.1], 0.5)[0] > expected_improvement([0.8], [0.1], 0.5)[0]
    # zero std: the plain improvement
    np.testing.assert_allclose(expected_improvement([0.2, 0.9], [0.0, 0.0], 0.5), [0.3, 0.0])
    # xi shifts the incumbent
    assert expected_improvement([0.4], [0.1], 0.5, xi=0.1)[0] == pytest.approx(0.1 * norm.pdf(0.0))


def test_surrogate_matches_sklearn_posterior_and_uses_a_constant_mean():
    rng = np.random.default_rng(0)
    X = rng.uniform(size=(15, 2))
    y = 3.0 + np.sin(4 * X[:, 0]) + X[:, 1] ** 2 + 0.01 * rng.standard_normal(15)
    gp = GPSurrogate(min_fit_points=1).fit(X, y, seed=0)
    assert gp.y_mean_ == pytest.approx(y.mean()) and gp.y_scale_ == pytest.approx(y.std())
    grid = rng.uniform(size=(50, 2))
    mean, std = gp.predict(grid)
    y_std = (y - gp.y_mean_) / gp.y_scale_
    reference = GaussianProcessRegressor(gp.kernel_, alpha=1e-8, optimizer=None).fit(X, y_std)
    ref_mean, ref_std = reference.predict(grid, return_std=True)
    white = gp.kernel_.k2.noise_level
    np.testing.assert_allclose(mean, gp.y_mean_ + gp.y_scale_ * ref_mean, rtol=1e-9)
    np.testing.assert_allclose(std, gp.y_scale_ * np.sqrt(np.maximum(ref_std**2 - white, 1e-18)), rtol=1e-6)
    # far from data the posterior returns to the constant mean
    far_mean, far_std = gp.predict(np.array([[60.0, 60.0]]))
    assert far_mean[0] == pytest.approx(y.mean(), abs=1e-6)
    assert np.all(std < far_std[0])
    assert 0.002 < gp.noise_std_ < 0.03  # the data's noise std is 0.01 (cost units)


def test_surrogate_with_known_noise_and_too_few_points():
    gp = GPSurrogate(noise_std=0.05).fit(np.array([[0.5, 0.5]]), np.array([2.0]))
    mean, std = gp.predict(np.array([[0.5, 0.5], [0.0, 1.0]]))
    np.testing.assert_allclose(mean, [2.0, 2.0], atol=0.05)  # one point: its value is the constant mean
    assert std[0] < std[1]
    assert gp.noise_std_ == 0.05
    with pytest.raises(ValueError, match="rows"):
        gp.fit(np.zeros((2, 2)), np.zeros(3))


def test_maximize_on_grid_and_polish():
    def acquisition(X):
        return -((X[:, 0] - 0.333) ** 2) - (X[:, 1] - 0.777) ** 2

    axis = np.linspace(0, 1, 11)
    grid = np.column_stack([m.ravel() for m in np.meshgrid(axis, axis, indexing="ij")])
    x, value = maximize_on_grid(acquisition, grid)
    np.testing.assert_allclose(x, [0.3, 0.8])
    x_fine, value_fine = maximize_on_grid(acquisition, grid, polish=True)
    np.testing.assert_allclose(x_fine, [0.333, 0.777], atol=1e-4)
    assert value_fine >= value


def test_initial_design_is_a_latin_hypercube():
    bo = agents.BayesianOptimization(n_initial=5, grid_points=20)
    bo.setup(SPACE, seed=4)
    points = []
    for _ in range(5):
        gains = bo.ask()
        assert np.isnan(bo.last_ei_)  # initial-design asks have no EI
        points.append(SPACE.to_unit(np.asarray(gains)))
        bo.tell(gains, bowl(gains))
    strata = np.floor(np.asarray(points) * 5).astype(int)
    for column in strata.T:  # one point per stratum in each dimension
        assert sorted(column) == [0, 1, 2, 3, 4]
    assert bo.n_observations == 5


def test_bo_finds_the_minimum_of_a_smooth_bowl():
    bo = agents.BayesianOptimization(grid_points=41)
    bo.setup(SPACE, seed=0)
    costs = []
    for _ in range(15):
        gains = bo.ask()
        costs.append(bowl(gains))
        bo.tell(gains, costs[-1])
    assert min(costs) < 0.2 + 0.01
    # the EI, mean and std exposed after an ask are the posterior's at the asked point
    gains = bo.ask()
    mean, std = bo.posterior([gains])
    assert bo.last_mean_ == pytest.approx(mean[0]) and bo.last_std_ == pytest.approx(std[0])
    assert bo.last_ei_ == pytest.approx(expected_improvement(mean, std, bo.incumbent(), xi=0.0)[0])


def test_propose_has_no_side_effects_and_matches_ask():
    bo = agents.BayesianOptimization(grid_points=25)
    bo.setup(SPACE, seed=1)
    for gains in ([0.2, 1.0], [0.9, 2.0], [0.5, 1.5], [0.3, 1.9], [1.0, 0.9]):
        bo.tell(gains, bowl(gains))
    first, ei, std = bo.propose()
    second, ei2, std2 = bo.propose()
    np.testing.assert_array_equal(first, second)
    assert (ei, std) == (ei2, std2) and ei > 0 and std > 0
    assert bo.n_observations == 5
    np.testing.assert_allclose(bo.ask(), first)
    assert bo.last_ei_ == ei and bo.last_std_ == std


def test_twin_data_enter_the_gp_and_can_be_stripped():
    bo = agents.BayesianOptimization(grid_points=25)
    bo.setup(SPACE, seed=2)
    for gains in ([0.2, 1.0], [0.9, 2.0], [0.5, 1.5], [0.3, 1.9], [1.0, 0.9]):
        bo.tell(gains, bowl(gains))
    plant_X, plant_y = bo.training_set()
    plant_mean = bo.posterior([MINIMUM])[0][0]
    twin_gains = np.array([[0.4, 1.6], [0.45, 1.55], [0.35, 1.65]])
    with bo.extra_data(twin_gains, [0.0, 0.05, 0.05]):
        X, y = bo.training_set()
        assert X.shape == (8, 2) and y[-3] == 0.0
        assert bo.posterior([MINIMUM])[0][0] < plant_mean - 0.05
        assert bo.incumbent() == pytest.approx(0.0)
    X, y = bo.training_set()
    np.testing.assert_array_equal(X, plant_X)
    np.testing.assert_array_equal(y, plant_y)
    bo.add_data([0.5, 1.0], 0.3, source="sim")
    bo.add_data([0.6, 1.0], 0.3)
    assert bo.remove_data("twin") == 1 and bo.remove_data(None) == 1
    assert bo.n_observations == 5
    with pytest.raises(ValueError, match="Ki"):
        bo.add_data([0.5, 9.0], 0.3)
    with pytest.raises(ValueError, match="plant"):
        bo.add_data([0.5, 1.0], 0.3, source="plant")


@pytest.mark.parametrize("kwargs, message", [
    ({"n_initial": 0}, r"n_initial: must be an int in \[1, inf\), got 0"),
    ({"n_initial": 2.5}, r"n_initial: must be an int in \[1, inf\), got 2.5"),
    ({"n_initial": True}, r"n_initial: must be an int"),
    ({"grid_points": 1}, r"grid_points: must be an int in \[2, inf\), got 1"),
    ({"noise_std": 0.0}, r"noise_std: must be None or a float in \(0, inf\), got 0.0"),
    ({"noise_std": float("nan")}, r"noise_std: must be None or a float"),
    ({"model": "metric"}, r"model: must be one of \('cost', 'metrics'\), got 'metric'"),
    ({"settling_model": "envelopes"}, r"settling_model: must be one of \('gp', 'envelope'\)"),
])
def test_bo_argument_validation_names_the_parameter_and_its_range(kwargs, message):
    with pytest.raises(ValueError, match=message):
        agents.BayesianOptimization(**kwargs)


def test_bo_takes_keywords_only_and_none_of_the_removed_knobs():
    with pytest.raises(TypeError):
        agents.BayesianOptimization(1)
    for removed in ("local_every", "output_transform", "prior_mean", "xi", "incumbent", "log_metrics"):
        with pytest.raises(TypeError, match=removed):
            agents.BayesianOptimization(**{removed: None})


def test_validated_params_are_converted_and_stored():
    bo = agents.BayesianOptimization(n_initial=np.int64(3), noise_std=1)
    assert bo.get_params() == {"n_initial": 3, "grid_points": 100, "noise_std": 1.0, "model": "metrics",
                               "settling_model": "gp", "optimizer": "auto", "n_candidates": 2048, "n_starts": 8}
    assert type(bo.n_initial) is int and type(bo.noise_std) is float


def test_parameter_constraints_forms():
    from agents.parameters import HasMethods, Interval, Options, validate_params

    constraints = {"a": [Interval(float, 0.0, 1.0, closed="neither")], "b": [None, Interval(int, None, 5)],
                   "c": [Options(("x", "y"))], "d": [HasMethods(("fit",))], "e": [Interval(float, 0.0, None)]}
    assert validate_params(constraints, {"a": 0.5, "b": None, "c": "x", "e": float("inf")}) == \
        {"a": 0.5, "b": None, "c": "x", "e": float("inf")}
    assert validate_params(constraints, {"b": -7}) == {"b": -7}
    for params, message in (({"a": 0.0}, r"a: must be a float in \(0, 1\), got 0.0"),
                            ({"a": 1.0}, r"a: must be a float in \(0, 1\)"),
                            ({"a": "0.5"}, r"a: must be a float"),
                            ({"b": 6}, r"b: must be None or an int in \(-inf, 5\], got 6"),
                            ({"c": "z"}, r"c: must be one of \('x', 'y'\), got 'z'"),
                            ({"d": object()}, r"d: must be an object with method\(s\) fit"),
                            ({"e": -1e-9}, r"e: must be a float in \[0, inf\)"),
                            ({"f": 1}, r"f: no constraint declared")):
        with pytest.raises(ValueError, match=message):
            validate_params(constraints, params)
    with pytest.raises(ValueError, match="closed"):
        Interval(float, 0.0, 1.0, closed="open")


def test_incumbent_rules():
    for rule in ("observed", "posterior_mean"):
        bo = agents.BayesianOptimization(grid_points=10)
        bo.incumbent_rule = rule  # guided BO switches to "posterior_mean" on the twin
        bo.setup(SPACE, seed=0)
        for gains in ([0.2, 1.0], [0.9, 2.0], [0.5, 1.5], [0.3, 1.9], [1.0, 0.9], [0.4, 1.6]):
            bo.tell(gains, bowl(gains))
        if rule == "observed":
            assert bo.incumbent() == pytest.approx(0.2)
        else:
            X, _ = bo.training_set()
            assert bo.incumbent() == pytest.approx(bo.surrogate.predict(X)[0].min())


def test_expected_improvement_meets_the_model_only_through_predict():
    class Fixed:
        def predict(self, X):
            return X[:, 0], np.full(X.shape[0], 0.1)

    X = np.array([[0.1, 0.0], [0.5, 0.0]])
    np.testing.assert_allclose(ExpectedImprovement(Fixed(), best=0.3)(X),
                               expected_improvement(X[:, 0], [0.1, 0.1], 0.3))


def test_fast_log_marginal_likelihood_equals_sklearn():
    from agents.surrogate import _neg_log_marginal_likelihood, squared_differences

    rng = np.random.default_rng(0)
    X = rng.uniform(size=(20, 2))
    y = np.sin(5 * X[:, 0]) + X[:, 1] + 0.05 * rng.standard_normal(20)
    gp = GPSurrogate(min_fit_points=1).fit(X, y, seed=0)
    y_std = (y - gp.y_mean_) / gp.y_scale_
    pairwise = squared_differences(X)
    reference = GaussianProcessRegressor(gp.kernel_, alpha=1e-8, optimizer=None).fit(X, y_std)
    for theta in (gp.kernel_.theta, gp.kernel_.theta + 0.3, np.log([2.0, 0.1, 0.4, 0.01])):
        ref, ref_grad = reference.log_marginal_likelihood(theta, eval_gradient=True)
        value, grad = _neg_log_marginal_likelihood(theta, pairwise, y_std, 1e-8, True)
        assert -value == pytest.approx(ref, rel=1e-9)
        np.testing.assert_allclose(-grad, ref_grad, rtol=1e-7, atol=1e-9)


def test_likelihood_maximisation_is_as_good_as_sklearns():
    # the multi-start L-BFGS-B of GPSurrogate reaches the log marginal likelihood that
    # scikit-learn's own GaussianProcessRegressor.fit reaches from the same starts
    rng = np.random.default_rng(3)
    X = rng.uniform(size=(30, 2))
    y = np.sin(6 * X[:, 0]) * np.cos(3 * X[:, 1]) + 0.05 * rng.standard_normal(30)
    gp = GPSurrogate(min_fit_points=1, n_restarts=3, warm_start=False).fit(X, y, seed=7)
    y_std = (y - gp.y_mean_) / gp.y_scale_
    reference = GaussianProcessRegressor(gp._prior_kernel(2), alpha=1e-8, n_restarts_optimizer=3,
                                         random_state=np.random.RandomState(7))
    with warnings.catch_warnings():
        # expected: on this data the likelihood's optimum lies on the prior's upper length-scale bound (0.5 of the
        # unit box), which scikit-learn reports as a ConvergenceWarning; the optima are compared below
        warnings.filterwarnings("ignore", message=".*length_scale is close to the specified upper bound",
                                category=ConvergenceWarning)
        reference.fit(X, y_std)
    ours = reference.log_marginal_likelihood(gp.kernel_.theta)
    assert ours >= reference.log_marginal_likelihood_value_ - 1e-6
    np.testing.assert_allclose(gp.kernel_.theta, reference.kernel_.theta, atol=1e-3)


def test_length_scales_grow_with_the_number_of_gains_and_two_gains_keep_theirs():
    # the bounds and the prior length scale times sqrt(d / 2) (Hvarfner et al. 2024): 4 gains may reach 0.71 of the
    # unit box, two gains keep (0.05, 0.5) bit for bit
    rng = np.random.default_rng(5)
    X = rng.uniform(size=(40, 4))
    y = np.sin(5 * X[:, 0]) + 0.1 * X[:, 1] + 0.01 * rng.standard_normal(40)  # inputs 3 and 4 do nothing
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        gp = GPSurrogate(min_fit_points=1, warm_start=False).fit(X, y, seed=0)
    assert gp.length_scales_[2:].min() > 0.5  # at the old bound of 0.5 before
    assert gp.length_scales_.max() <= 0.5 * np.sqrt(2.0) + 1e-9
    two = GPSurrogate(min_fit_points=1, warm_start=False).fit(X[:, :2], y, seed=0)
    assert two.length_scales_.max() <= 0.5 + 1e-12
    from agents.surrogate import dimension_scale

    assert dimension_scale(2) == 1.0 and dimension_scale(4) == pytest.approx(np.sqrt(2.0))


# -- model="metrics": one GP per performance metric (paper, abstract and eq. (J_used)) ---------------------------
class _MetricEnv:
    """Stands in for an env: only ``weights`` and ``normalizers`` of ``J = sum w_i f_i / n_i`` are read."""

    weights = np.array([0.44, 0.22, 0.22, 0.11])
    normalizers = np.array([14.0, 3.5, 1.0, 100.0])


def _metrics(gains) -> dict:
    u = SPACE.to_unit(gains)
    values = (10.0 * u[0] ** 2, 2.0 + 3.0 * (u[1] - 0.6) ** 2, 0.5 + u[0] * u[1], 80.0 + 40.0 * (u[0] - 0.3) ** 2)
    return dict(zip(agents.result.METRIC_COLUMNS, values))


def _cost(metrics: dict) -> float:
    f = np.array([metrics[name] for name in agents.result.METRIC_COLUMNS])
    return float(np.sum(_MetricEnv.weights * f / _MetricEnv.normalizers))


def _metrics_bo(seed: int, **kwargs):
    bo = agents.BayesianOptimization(model="metrics", grid_points=25, **kwargs)
    bo.setup(SPACE, seed=seed, env=_MetricEnv())
    return bo


def test_composite_posterior_is_the_weighted_sum_of_the_metric_gps():
    from agents.metric_surrogate import CompositeSurrogate, MetricSurrogate

    rng = np.random.default_rng(3)
    X = rng.uniform(size=(12, 2))
    F = np.column_stack([10 * X[:, 0], 2 + X[:, 1] ** 2, 0.5 + X[:, 0] * X[:, 1], 80 + 40 * X[:, 0] ** 2])
    noise = 0.01 * rng.standard_normal(12)
    surrogate = MetricSurrogate(_MetricEnv.weights, _MetricEnv.normalizers, min_fit_points=1)
    composite = surrogate.fit(X, F, costs=surrogate.reconstruct(F) + noise, seed=0)
    assert isinstance(composite, CompositeSurrogate)
    grid = rng.uniform(size=(40, 2))
    means, stds = composite.predict_metrics(grid)
    for i, gp in enumerate(surrogate.models):  # each GP is fitted on its normalised metric f_i / n_i
        np.testing.assert_allclose(gp.y_train_, F[:, i] / _MetricEnv.normalizers[i])
        np.testing.assert_array_equal(means[:, i], gp.predict(grid)[0])
    mean, std = composite.predict(grid)
    # J = sum w_i f_i / n_i: mean = sum w_i mu_i, var = sum w_i^2 sigma_i^2 (mu_i, sigma_i of f_i / n_i)
    np.testing.assert_allclose(mean, means @ _MetricEnv.weights, rtol=1e-12)
    np.testing.assert_allclose(std**2, stds**2 @ _MetricEnv.weights**2, rtol=1e-12)
    # the cost-level noise is the RMS residual of J against sum w f / n
    assert composite.cost_noise_std_ == pytest.approx(np.sqrt(np.mean(noise**2)))
    assert composite.noise_std_ >= composite.cost_noise_std_


def test_metrics_mode_proposes_in_bounds_and_is_deterministic_per_seed():
    runs = []
    for _ in range(2):
        bo = _metrics_bo(seed=5)
        asked = []
        for _ in range(8):
            gains = np.asarray(bo.ask())
            if bo.n_observations >= bo.n_initial:  # a model step: its mean is the composite posterior's there
                assert bo.last_mean_ == pytest.approx(bo.posterior(gains[None, :])[0][0])
            metrics = _metrics(gains)
            bo.tell(gains, _cost(metrics) + 0.001, {"metrics": metrics})
            asked.append(gains)
        assert bo.model_in_use == "metrics"
        # the "observed" incumbent is J_hat of the measured metrics (the cost noise is not in them)
        assert bo.incumbent() == pytest.approx(min(_cost(_metrics(g)) for g in asked))
        assert bo.run_summary()["model"] == "metrics"
        runs.append(np.asarray(asked))
    np.testing.assert_array_equal(runs[0], runs[1])
    other = _metrics_bo(seed=6)
    for gains in runs[0][:3]:
        other.tell(gains, _cost(_metrics(gains)), {"metrics": _metrics(gains)})
    assert other.propose()[0].shape == (2,)


def test_default_bo_models_the_metrics_of_the_dc_motor_with_logs():
    import gymnasium as gym

    import gbo_envs  # noqa: F401  (registers the envs)
    from agents.metric_surrogate import CompositeSurrogate

    bo = agents.BayesianOptimization(grid_points=20)
    result = bo.run(gym.make("gbo_envs/DCMotor-v0"), budget=7, seed=0)
    assert bo.model_in_use == "metrics" and isinstance(bo.fit_surrogate(), CompositeSurrogate)
    assert bo.metric_surrogate.log_metrics == (1, 2, 3)  # settling time, rise time, ITAE
    assert result.info["model"] == "metrics"
    # guided BO builds on the same metric GPs; the paper's Algorithm 1 keeps one GP on the cost
    assert agents.GuidedBO().model == "metrics" and agents.GuidedBO(guidance="iterations").model == "cost"


def test_blockwise_prediction_equals_sklearn_on_a_large_grid():
    rng = np.random.default_rng(4)
    X = rng.uniform(size=(40, 2))
    y = np.cos(5 * X[:, 0]) + X[:, 1] ** 2
    gp = GPSurrogate(min_fit_points=1).fit(X, y, seed=0)
    grid = rng.uniform(size=(2500, 2))  # several blocks and a partial one
    y_std = (y - gp.y_mean_) / gp.y_scale_
    reference = GaussianProcessRegressor(gp.kernel_, alpha=1e-8, optimizer=None).fit(X, y_std)
    ref_mean, ref_std = reference.predict(grid, return_std=True)
    mean, std = gp.predict(grid)
    np.testing.assert_allclose(mean, gp.y_mean_ + gp.y_scale_ * ref_mean, rtol=1e-9, atol=1e-12)
    white = gp.kernel_.k2.noise_level
    np.testing.assert_allclose(std, gp.y_scale_ * np.sqrt(np.maximum(ref_std**2 - white, 1e-18)), rtol=1e-5,
                               atol=1e-9)


def test_metrics_mode_falls_back_to_the_cost_gp_without_metrics():
    # no env weights/normalizers: the cost GP, as model="cost"
    bo = agents.BayesianOptimization(model="metrics", grid_points=25)
    bo.setup(SPACE, seed=0)
    for gains in ([0.2, 1.0], [0.9, 2.0], [0.5, 1.5]):
        bo.tell(gains, bowl(gains), {"metrics": _metrics(gains)})
    bo.ask()
    assert bo.model_in_use == "cost"
    # a record without metrics (or an unstable one): the cost GP for that fit
    bo = _metrics_bo(seed=0)
    bo.tell([0.2, 1.0], 0.5, {"metrics": _metrics([0.2, 1.0])})
    bo.tell([0.9, 2.0], 0.7)
    gains = bo.ask()
    assert bo.model_in_use == "cost" and np.all(np.asarray(gains) <= SPACE.high)
    # twin data without metrics: the cost GP while they are in D; with metrics: the metrics model
    bo = _metrics_bo(seed=1)
    for gains in ([0.2, 1.0], [0.9, 2.0], [0.5, 1.5], [0.3, 1.9], [1.0, 0.9]):
        bo.tell(gains, _cost(_metrics(gains)), {"metrics": _metrics(gains)})
    bo.propose()
    assert bo.model_in_use == "metrics"
    with bo.extra_data([0.4, 1.6], 0.1):
        bo.propose()
        assert bo.model_in_use == "cost"
    twin = _metrics([0.4, 1.6])
    with bo.extra_data([0.4, 1.6], _cost(twin), metrics=[twin[name] for name in agents.result.METRIC_COLUMNS]):
        bo.propose()
        assert bo.model_in_use == "metrics"
    bo.propose()
    assert bo.model_in_use == "metrics"
    with pytest.raises(ValueError, match="metrics"):
        bo.add_data([0.4, 1.6], 0.1, metrics=[1.0, 2.0])
    with pytest.raises(ValueError, match="model"):
        agents.BayesianOptimization(model="metric")


def test_a_metric_prior_is_followed_where_the_discrepancy_is_flat():
    from agents.metric_surrogate import MetricSurrogate

    def truth(X):
        X = np.atleast_2d(X)
        return np.column_stack([10 * X[:, 0] ** 2, 2 + np.sin(6 * X[:, 1]), 0.5 + X[:, 0] * X[:, 1],
                                80 + 40 * np.cos(5 * X[:, 0])])

    def prior(X):  # the truth off by a constant in f_0 / n_0 and by constant factors in the logged metrics
        return truth(X) * np.array([1.0, 1.05, 0.9, 1.1]) + np.array([0.5, 0.0, 0.0, 0.0])

    rng = np.random.default_rng(0)
    X = rng.uniform(size=(8, 2))
    surrogate = MetricSurrogate(_MetricEnv.weights, _MetricEnv.normalizers, log_metrics=[1, 2, 3])
    guided = surrogate.fit(X, truth(X), seed=0, prior=prior)
    plain = MetricSurrogate(_MetricEnv.weights, _MetricEnv.normalizers, log_metrics=[1, 2, 3]).fit(
        X, truth(X), seed=0)
    far = rng.uniform(size=(200, 2))
    exact = truth(far) @ (_MetricEnv.weights / _MetricEnv.normalizers)
    error_guided = np.abs(guided.predict(far)[0] - exact).max()
    error_plain = np.abs(plain.predict(far)[0] - exact).max()
    assert error_guided < 1e-3 * np.abs(exact).max()  # the prior's shape, the data's offset
    assert error_plain > 30 * error_guided  # eight points alone cannot know the sine and cosine


def test_a_prior_exact_at_the_points_leaves_the_metrics_own_spread_not_one_normaliser():
    # a twin that reproduces its records (a quantized sensor read the same by twin and plant): every discrepancy
    # is zero at the points. Standardised by 1, its GP put a std of one normaliser (one cost weight) everywhere
    # else, and EI sent guided BO to the corners of LinearMotor-v0 (seed 1: 6 experiments to 1.01 J*, 3 without)
    from agents.metric_surrogate import MetricSurrogate

    def truth(X):
        X = np.atleast_2d(X)
        return np.column_stack([10 * X[:, 0] ** 2, 2 + X[:, 1], 0.5 + X[:, 0], 80 + 40 * X[:, 0]])

    X = np.array([[0.2, 0.3], [0.7, 0.6], [0.4, 0.9]])
    surrogate = MetricSurrogate(_MetricEnv.weights, _MetricEnv.normalizers)
    fitted = surrogate.fit(X, truth(X), seed=0, prior=truth)
    spread = np.std(truth(X) / _MetricEnv.normalizers, axis=0)
    far = np.array([[0.95, 0.05]])
    stds = np.array([model.predict(far)[1][0] for model in fitted.models])
    assert np.all(stds <= 1.01 * spread) and np.all(stds > 0.1 * spread)
    assert np.allclose(fitted.predict(far)[0], truth(far) @ (_MetricEnv.weights / _MetricEnv.normalizers))
    constant = GPSurrogate().fit(X, np.zeros(3), seed=0, scale=0.25)
    assert constant.y_scale_ == 0.25 and GPSurrogate().fit(X, np.zeros(3), seed=0).y_scale_ == 1.0


def test_a_prior_wrong_on_one_metric_guides_only_through_the_others():
    # a twin that replays the response but not its overshoot (stick-slip hunting on LinearMotorCascadeRig-v0):
    # as the prior of every metric it held EI in the basin it predicts
    from agents.metric_surrogate import MetricSurrogate

    def truth(X):
        X = np.atleast_2d(X)
        return np.column_stack([10 * X[:, 0] ** 2, 2 + np.sin(6 * X[:, 1]), 0.5 + X[:, 0] * X[:, 1],
                                80 + 40 * np.cos(5 * X[:, 0])])

    def prior(X):  # exact but for the first metric, which it gets wrong in shape and ten times in size
        wrong = truth(X)
        wrong[:, 0] = 100 * (1 - X[:, 0]) ** 2 + 50 * np.cos(9 * X[:, 1])
        return wrong

    X = np.random.default_rng(0).uniform(size=(12, 2))
    surrogate = MetricSurrogate(_MetricEnv.weights, _MetricEnv.normalizers, log_metrics=[1, 2, 3])
    guided = surrogate.fit(X, truth(X), seed=0, prior=prior)
    assert guided.with_prior == (1, 2, 3)
    assert guided.models[0] is surrogate.plain_models[0]  # the constant-mean GP of that metric
    for i in (1, 2, 3):
        assert surrogate.models[i].log_marginal_likelihood_ > surrogate.plain_models[i].log_marginal_likelihood_
    exact = MetricSurrogate(_MetricEnv.weights, _MetricEnv.normalizers, log_metrics=[1, 2, 3]).fit(
        X, truth(X), seed=0, prior=truth)
    assert exact.with_prior == (0, 1, 2, 3)
    assert MetricSurrogate(_MetricEnv.weights, _MetricEnv.normalizers).fit(X, truth(X), seed=0).with_prior == ()


def test_the_log_marginal_likelihood_is_scikit_learns_in_the_units_of_y():
    from sklearn.gaussian_process import GaussianProcessRegressor

    rng = np.random.default_rng(1)
    X = rng.uniform(size=(9, 3))
    y = 40 + 7 * np.sin(4 * X[:, 0]) + 0.1 * rng.standard_normal(9)
    gp = GPSurrogate().fit(X, y, seed=0)
    reference = GaussianProcessRegressor(kernel=gp.kernel_, optimizer=None, alpha=1e-8).fit(
        X, (y - gp.y_mean_) / gp.y_scale_)
    # the density of y is that of the standardised y times the Jacobian 1 / s_y of each of the 9 points
    assert gp.log_marginal_likelihood_ == pytest.approx(reference.log_marginal_likelihood_value_
                                                        - 9 * np.log(gp.y_scale_), rel=1e-9)


def test_twin_metrics_of_a_noisy_twin_simulate_the_noise_only_near_its_expected_optimum():
    from agents.twin.prior import NOISY_COST_FACTOR, TwinMetrics

    class Twin:  # cost = sum of the metrics; the noise adds 0.5 to the first metric
        weights, normalizers, unstable_cost = np.full(4, 0.25), np.full(4, 0.25), 10.0

        def __init__(self, noisy: bool) -> None:
            self.noisy, self.gains = noisy, []
            self.free = Twin(False) if noisy else self

        def noise_free(self):
            return self.free

        def evaluate(self, gains):
            self.gains.extend(map(tuple, gains))
            metrics = np.zeros((len(gains), 4))
            metrics[:, 1] = 1.0 + 10.0 * np.sum((gains - 0.3) ** 2, axis=1)
            metrics[:, 0] = 0.5 * self.noisy
            return metrics, metrics.sum(axis=1)

    twin = Twin(noisy=True)
    space = agents.GainSpace(low=[0.0, 0.0], high=[1.0, 1.0], names=("Kp", "Ki"))
    X = np.random.default_rng(0).uniform(size=(400, 2))
    values = TwinMetrics(twin, space)(X)
    noise_free_cost = 1.0 + 10.0 * np.sum((X - 0.3) ** 2, axis=1)
    admitted = noise_free_cost <= NOISY_COST_FACTOR * (noise_free_cost.min() + 0.5)
    assert 0 < admitted.sum() < 200 and len(twin.free.gains) == 400  # every gain once without noise
    assert sorted(twin.gains) == sorted(map(tuple, X[admitted]))  # with noise only where it may matter
    np.testing.assert_array_equal(values[:, 0], np.where(admitted, 0.5, 0.0))
    np.testing.assert_array_equal(values[:, 1], noise_free_cost)
    plain = Twin(noisy=False)  # a twin without noise: one simulation per gain, as before
    np.testing.assert_array_equal(TwinMetrics(plain, space)(X)[:, 0], 0.0)
    assert len(plain.gains) == 400


def test_twin_metrics_give_every_admitted_candidate_of_a_multistart_plan_its_expected_metrics():
    """Noise-free metrics are optimistic: none of EI's 2,048 candidates that the bound admits keeps them."""
    from agents.twin.prior import TwinMetrics

    class FlatTwin:  # every gain costs 1 noise-free and 1.5 with noise: all are admitted
        weights, normalizers, unstable_cost = np.full(2, 0.5), np.full(2, 0.5), 10.0

        def __init__(self, noisy: bool) -> None:
            self.noisy, self.free = noisy, FlatTwin(False) if noisy else self

        def noise_free(self):
            return self.free

        def evaluate(self, gains):
            metrics = np.column_stack([np.full(len(gains), 0.5 * self.noisy), np.ones(len(gains))])
            return metrics, metrics.sum(axis=1)

    space = agents.GainSpace(low=[0.0, 0.0, 0.0], high=[1.0, 1.0, 1.0], names=("Kp", "Ki", "Kd"))
    X = np.random.default_rng(1).uniform(size=(2048, 3))
    np.testing.assert_array_equal(TwinMetrics(FlatTwin(noisy=True), space)(X)[:, 0], 0.5)


def test_twin_metrics_simulate_each_gain_once_and_price_divergence_at_the_unstable_cost():
    from agents.twin.prior import TwinMetrics

    class CountingTwin:
        weights, normalizers, unstable_cost = np.array([0.4, 0.2, 0.2, 0.2]), np.array([1.0, 2.0, 4.0, 8.0]), 10.0
        calls = 0

        def evaluate(self, gains):
            self.calls += len(gains)
            metrics = np.tile([1.0, 2.0, 3.0, 4.0], (len(gains), 1))
            metrics[gains[:, 0] > 1.0] = np.nan  # "diverges" for Kp > 1
            return metrics, metrics.sum(axis=1)

    twin = CountingTwin()
    prior = TwinMetrics(twin, SPACE)
    X = np.array([[0.1, 0.2], [0.9, 0.5], [0.1, 0.2]])
    values = prior(X)
    assert twin.calls == 2 and prior.simulations_ == 2  # the repeated row once
    assert prior(X) is values and prior(X[:2].copy()).shape == (2, 4) and twin.calls == 2  # cached
    unstable = SPACE.from_unit(X)[:, 0] > 1.0
    assert unstable.any()
    np.testing.assert_allclose(values[unstable] @ (twin.weights / twin.normalizers), twin.unstable_cost)
    np.testing.assert_array_equal(values[~unstable][0], [1.0, 2.0, 3.0, 4.0])
