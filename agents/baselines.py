"""Model-free baselines: uniform random search and a grid sized to the budget."""

from __future__ import annotations

import numpy as np

from agents.base import Tuner

__all__ = ["RandomSearch", "GridSearch", "GRID_ORDERS"]

#: Orders in which :class:`GridSearch` visits its grid.
GRID_ORDERS = ("shuffled", "serpentine")


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

    Parameters
    ----------
    points_per_gain : int, optional
        Fixes ``k`` instead of deriving it from the budget. Required when
        driving ``ask``/``tell`` by hand without :meth:`run` (else ``k`` is
        derived from ``budget``).
    budget : int, default 35
        Budget used to size the grid when not set by :meth:`run`.
    order : {"shuffled", "serpentine"}, default "shuffled"
        ``"shuffled"``: a permutation drawn from the tuner's seeded rng, so a
        run stopped early still spreads over the set. ``"serpentine"``:
        boustrophedon order, last gain fastest, reversing on every other row.

    Once every grid point was visited, the sequence starts over.
    """

    name = "grid"

    def __init__(self, *, points_per_gain: int | None = None, budget: int = 35, order: str = "shuffled") -> None:
        if points_per_gain is not None and int(points_per_gain) < 1:
            raise ValueError(f"points_per_gain: must be >= 1, got {points_per_gain}")
        if int(budget) < 1:
            raise ValueError(f"budget: must be >= 1, got {budget}")
        if order not in GRID_ORDERS:
            raise ValueError(f"order: must be one of {GRID_ORDERS}, got {order!r}")
        self.points_per_gain = None if points_per_gain is None else int(points_per_gain)
        self.budget = int(budget)
        self.order = order
        self._params = {"points_per_gain": self.points_per_gain, "budget": self.budget, "order": order}

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
        k = self.points_per_gain or _points_for(budget, dim)
        centres = (np.arange(k) + 0.5) / k
        index = np.array(np.unravel_index(np.arange(k**dim), (k,) * dim)).T  # last gain fastest
        if self.order == "serpentine":
            linear = np.arange(k**dim)
            for axis in range(1, dim):
                # reverse axis `axis` on every other sweep of it, so neighbours in time are neighbours in space
                flip = (linear // k ** (dim - axis)) % 2 == 1
                index[flip, axis] = k - 1 - index[flip, axis]
        else:
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
