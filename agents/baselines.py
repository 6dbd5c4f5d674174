"""Model-free baselines: uniform random search and a grid sized to the budget."""

from __future__ import annotations

import numpy as np

from agents.base import Tuner
from agents.parameters import Interval, validate_params

__all__ = ["RandomSearch", "GridSearch"]

#: Orders in which :class:`GridSearch` visits its grid.


class RandomSearch(Tuner):
    """Gains drawn independently and uniformly from the feasible set (no learning)."""

    name = "random"

    def __init__(self) -> None:
        self._params: dict = {}

    def _ask(self) -> np.ndarray:
        return self.rng.uniform(self.space.low, self.space.high)

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        pass


class GridSearch(Tuner):
    """A regular grid over the feasible set, sized to the budget, visited once (no learning).

    With ``k`` points per gain the grid is the ``k ** n_gains`` cell centres
    ``low + (i + 1/2) (high - low) / k`` (no point sits on the boundary, where
    controllers are usually poor). ``k`` is the smallest integer with
    ``k ** n_gains >= budget``, so a run of ``budget`` experiments visits all
    but at most a few points (35 experiments on two gains: 6 x 6 = 36 points).

    The points are visited in a permutation drawn from the tuner's seeded rng,
    so a run stopped early still spreads over the set; once every point was
    visited, the sequence starts over.

    Parameters
    ----------
    budget : int, default 35
        Budget that sizes the grid when ``ask``/``tell`` are driven by hand;
        :meth:`run` sizes it to its own ``budget``.
    """

    name = "grid"

    _parameter_constraints = {"budget": [Interval(int, 1, None)]}

    def __init__(self, *, budget: int = 35) -> None:
        self.budget = validate_params(self._parameter_constraints, {"budget": budget})["budget"]
        self._params = {"budget": self.budget}

    def run(self, env, budget: int, seed: int | None = None, **options):
        """As :meth:`Tuner.run` (same ``options``); the grid is sized to this ``budget``."""
        self._run_budget = int(budget)
        try:
            return super().run(env, budget, seed=seed, **options)
        finally:
            del self._run_budget

    def _setup(self) -> None:
        budget = getattr(self, "_run_budget", self.budget)
        dim = self.space.dim
        k = _points_for(budget, dim)
        centres = (np.arange(k) + 0.5) / k
        index = np.array(np.unravel_index(np.arange(k**dim), (k,) * dim)).T
        index = index[self.rng.permutation(len(index))]
        self._points = self.space.from_unit(centres[index])
        self._next = 0

    def _ask(self) -> np.ndarray:
        return self._points[self._next % len(self._points)]

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        self._next += 1

    @property
    def points(self) -> np.ndarray:
        """The grid in visiting order, shape (k ** n_gains, n_gains)."""
        return self._points.copy()


def _points_for(budget: int, dim: int) -> int:
    k = max(1, int(np.floor(budget ** (1.0 / dim))))
    while k**dim < budget:
        k += 1
    return k
