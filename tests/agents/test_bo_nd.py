"""BO beyond two gains: EI maximised by Sobol candidates and multistart L-BFGS-B (agents.acquisition)."""

from __future__ import annotations

import numpy as np
import pytest

import agents
from agents.acquisition import maximize_multistart, maximize_on_grid
from agents.space import GainSpace
from tests.support import DC_MOTOR_SPACE


def space(dim: int) -> GainSpace:
    return GainSpace(names=tuple(f"K{i}" for i in range(dim)), low=np.linspace(0.1, 1.0, dim),
                     high=np.linspace(2.0, 40.0, dim), units=("V/rad",) * dim)


def bowl(gains, s: GainSpace) -> float:
    """A smooth cost, minimum 0.1 at the unit point (0.3, 0.6, 0.45, ...), elongated along the first gain."""
    u = s.to_unit(gains)
    centre = np.resize([0.3, 0.6, 0.45], s.dim)
    return float(0.1 + np.sum(np.arange(1, s.dim + 1) * (u - centre) ** 2))


def test_multistart_finds_an_interior_maximum_and_one_on_the_bound_in_4_dimensions():
    box = np.array([[0.0, 1.0], [-2.0, 2.0], [0.0, 1.0], [5.0, 6.0]])
    peak = np.array([0.37, 0.5, 0.81, 5.2])
    x, value = maximize_multistart(lambda X: -np.sum(((X - peak) / [1, 4, 1, 1]) ** 2, axis=1), box, rng=0)
    np.testing.assert_allclose(x, peak, atol=1e-3)
    assert value == pytest.approx(0.0, abs=1e-6)
    outside = np.array([1.5, 0.5, 0.2, 5.5])  # beyond the upper bound of the first gain
    x, _ = maximize_multistart(lambda X: -np.sum((X - outside) ** 2, axis=1), box, rng=0)
    assert x[0] == 1.0 and np.all((box[:, 0] <= x) & (x <= box[:, 1]))
    np.testing.assert_allclose(x[1:], outside[1:], atol=1e-3)


def test_multistart_is_as_good_as_its_best_candidate_and_seeded():
    box = np.array([[0.0, 1.0]] * 3)
    rough = lambda X: np.sin(40 * X[:, 0]) * np.cos(30 * X[:, 1]) + X[:, 2]  # noqa: E731
    x1, v1 = maximize_multistart(rough, box, rng=3, n_candidates=64, n_starts=2)
    x2, v2 = maximize_multistart(rough, box, rng=3, n_candidates=64, n_starts=2)
    np.testing.assert_array_equal(x1, x2)
    assert v1 == v2 == pytest.approx(float(rough(x1[None, :])[0]))
    from scipy.stats import qmc
    candidates = qmc.Sobol(d=3, scramble=True, rng=3).random(64)
    assert v1 >= rough(candidates).max()
    with pytest.raises(ValueError, match="bounds: need an array of shape"):
        maximize_multistart(rough, np.array([[1.0, 0.0]]), rng=0)
    with pytest.raises(ValueError, match="n_starts: must be an integer >= 1"):
        maximize_multistart(rough, box, rng=0, n_starts=0)


@pytest.mark.parametrize("dim", [3, 4])
def test_bo_proposes_in_bounds_and_improves_over_its_start_in_3_and_4_gains(dim):
    s = space(dim)
    bo = agents.BayesianOptimization(model="cost")
    bo.setup(s, seed=0)
    assert bo.optimizer_in_use == "multistart" and bo._unit_grid is None
    costs = []
    for _ in range(20):
        gains = np.asarray(bo.ask())
        assert gains.shape == (dim,) and np.all((s.low <= gains) & (gains <= s.high))
        costs.append(bowl(gains, s))
        bo.tell(gains, costs[-1])
    assert min(costs[1:]) < 0.5 * costs[0]  # far better than the Latin hypercube start
    assert min(costs) < 0.1 + 0.05 * dim  # near the minimum 0.1
    assert np.isfinite(bo.last_ei_) and bo.last_ei_ >= 0


def test_a_4_gain_proposal_has_no_side_effects_and_is_reproducible():
    s = space(4)
    runs = []
    for _ in range(2):
        bo = agents.BayesianOptimization(model="cost")
        bo.setup(s, seed=5)
        for _ in range(7):
            gains = np.asarray(bo.ask())
            bo.tell(gains, bowl(gains, s))
        proposed = bo.propose()
        again = bo.propose()
        np.testing.assert_array_equal(proposed[0], again[0])
        np.testing.assert_array_equal(np.asarray(bo.ask()), proposed[0])
        runs.append(proposed[0])
    np.testing.assert_array_equal(runs[0], runs[1])


def test_two_gains_keep_the_grid_by_default_and_either_optimizer_may_be_chosen():
    bo = agents.BayesianOptimization(model="cost")
    bo.setup(DC_MOTOR_SPACE, seed=0)
    assert bo.optimizer_in_use == "grid" and bo._unit_grid.shape == (100 * 100, 2)
    bo.tell(np.array([0.5, 1.0]), 0.4)
    bo.tell(np.array([1.0, 1.5]), 0.3)
    gains, ei, _ = bo.propose()
    grid_x, grid_ei = maximize_on_grid(bo_ei(bo), bo._unit_grid)
    np.testing.assert_array_equal(gains, DC_MOTOR_SPACE.from_unit(grid_x))  # the grid's maximiser, exactly
    assert ei == grid_ei
    chosen = agents.BayesianOptimization(model="cost", optimizer="multistart")
    chosen.setup(DC_MOTOR_SPACE, seed=0)
    assert chosen.optimizer_in_use == "multistart"
    grid_3d = agents.BayesianOptimization(optimizer="grid", grid_points=10)
    grid_3d.setup(space(3), seed=0)
    assert grid_3d.optimizer_in_use == "grid" and grid_3d._unit_grid.shape == (1000, 3)
    for kwargs, message in (({"optimizer": "sobol"}, r"optimizer: must be one of \('auto', 'grid', 'multistart'\)"),
                            ({"n_candidates": 0}, r"n_candidates: must be an int in \[1, inf\)"),
                            ({"n_starts": 1.5}, r"n_starts: must be an int in \[1, inf\)")):
        with pytest.raises(ValueError, match=message):
            agents.BayesianOptimization(**kwargs)


def bo_ei(bo):
    from agents.acquisition import ExpectedImprovement

    return ExpectedImprovement(bo.fit_surrogate(), bo.incumbent())


def test_the_initial_design_is_a_latin_hypercube_in_4_gains():
    s = space(4)
    bo = agents.BayesianOptimization(n_initial=6, model="cost")
    bo.setup(s, seed=2)
    design = []
    for _ in range(6):
        gains = np.asarray(bo.ask())
        design.append(s.to_unit(gains))
        bo.tell(gains, bowl(gains, s))
    strata = np.floor(np.asarray(design) * 6).astype(int)
    for column in strata.T:  # one point in each sixth of every gain's range
        assert sorted(column) == list(range(6))
    assert np.isnan(bo.last_ei_)
