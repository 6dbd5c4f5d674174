"""GP surrogate, acquisition functions and the BO tuner (paper, subsec. BO)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

import agents
from agents.acquisition import (
    ExpectedImprovement,
    expected_improvement,
    lower_confidence_bound,
    maximize_on_grid,
    probability_of_improvement,
)
from agents.space import GainSpace
from agents.surrogate import GPSurrogate

SPACE = GainSpace(names=("Kp", "Ki"), low=np.array([0.11, 0.87]), high=np.array([1.10, 2.08]))
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


def test_other_acquisitions():
    assert probability_of_improvement([0.5], [0.2], 0.5)[0] == pytest.approx(0.5)
    np.testing.assert_allclose(lower_confidence_bound([1.0], [0.5], beta=2.0), [0.0])


def test_surrogate_matches_sklearn_posterior_and_uses_a_constant_mean():
    rng = np.random.default_rng(0)
    X = rng.uniform(size=(15, 2))
    y = 3.0 + np.sin(4 * X[:, 0]) + X[:, 1] ** 2 + 0.01 * rng.standard_normal(15)
    gp = GPSurrogate(min_fit_points=1).fit(X, y, seed=0)
    assert gp.y_mean_ == pytest.approx(y.mean()) and gp.y_scale_ == pytest.approx(y.std())
    grid = rng.uniform(size=(50, 2))
    mean, std = gp.predict(grid)
    ref_mean, ref_std = gp.gp_.predict(grid, return_std=True)
    white = gp.kernel_.k2.noise_level
    np.testing.assert_allclose(mean, gp.y_mean_ + gp.y_scale_ * ref_mean, rtol=1e-9)
    np.testing.assert_allclose(std, gp.y_scale_ * np.sqrt(np.maximum(ref_std**2 - white, 1e-18)), rtol=1e-6)
    # far from data the posterior returns to the constant mean
    far_mean, far_std = gp.predict(np.array([[60.0, 60.0]]))
    assert far_mean[0] == pytest.approx(y.mean(), abs=1e-6)
    assert np.all(std < far_std[0])
    assert np.all(gp.length_scales_ >= 0.05) and np.all(gp.length_scales_ <= 0.5)
    assert 0 < gp.noise_std_ < 0.5


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
    # EI and std at the asked point are exposed, finite and non-negative
    assert bo.last_ei_ >= 0.0 and bo.last_std_ >= 0.0 and np.isfinite(bo.last_mean_)


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


def test_bo_argument_validation():
    with pytest.raises(ValueError, match="incumbent"):
        agents.BayesianOptimization(incumbent="best")
    with pytest.raises(ValueError, match="n_initial"):
        agents.BayesianOptimization(n_initial=0)
    with pytest.raises(TypeError):
        agents.BayesianOptimization(1)


def test_incumbent_rules():
    for rule in ("observed", "posterior_mean"):
        bo = agents.BayesianOptimization(grid_points=10, incumbent=rule)
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
    from agents.surrogate import _neg_log_marginal_likelihood

    rng = np.random.default_rng(0)
    X = rng.uniform(size=(20, 2))
    y = np.sin(5 * X[:, 0]) + X[:, 1] + 0.05 * rng.standard_normal(20)
    gp = GPSurrogate(min_fit_points=1).fit(X, y, seed=0)
    y_std = (y - gp.y_mean_) / gp.y_scale_
    pairwise = (X[:, None, :] - X[None, :, :]) ** 2
    for theta in (gp.kernel_.theta, gp.kernel_.theta + 0.3, np.log([2.0, 0.1, 0.4, 0.01])):
        ref, ref_grad = gp.gp_.log_marginal_likelihood(theta, eval_gradient=True)
        value, grad = _neg_log_marginal_likelihood(theta, pairwise, y_std, 1e-8, True)
        assert -value == pytest.approx(ref, rel=1e-9)
        np.testing.assert_allclose(-grad, ref_grad, rtol=1e-7, atol=1e-9)
