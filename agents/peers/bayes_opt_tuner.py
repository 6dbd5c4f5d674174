"""bayesian-optimization behind the tuner API: register/suggest (registry name ``bayes-opt``)."""

from __future__ import annotations

import numpy as np

from agents.peers.base import PeerTuner

__all__ = ["BayesOptTuner"]


class BayesOptTuner(PeerTuner):
    """bayesian-optimization's ``BayesianOptimization(f=None)`` with ``register`` / ``suggest``, after BO's design.

    The library's defaults: a GP (Matern 5/2, ``alpha = 1e-6``, normalised targets, 5
    optimizer restarts) and its default acquisition (upper confidence bound in 3.x),
    maximised by random sampling and L-BFGS-B. It maximises, so it is told the negated
    cost. It works on the unit box (one bound ``(0, 1)`` per gain name), is seeded by the
    tuner rng, and accepts repeated points (``allow_duplicate_points=True``).

    Parameters
    ----------
    n_initial : int, default 1
        Size ``N0`` of the Latin hypercube initial design (the same points as ``agents.make("bo")``).

    Raises
    ------
    ImportError
        If bayesian-optimization is not installed (``pip install "gbo-envs[peers]"``).
    """

    name = "bayes-opt"
    library = ("bayes_opt", "bayesian-optimization")

    def _start(self) -> None:
        from bayes_opt import BayesianOptimization

        self._keys = [f"x{i}" for i in range(self.space.dim)]  # gain names may not be identifiers
        self._optimizer = BayesianOptimization(f=None, pbounds={key: (0.0, 1.0) for key in self._keys},
                                               random_state=self.library_seed, verbose=0,
                                               allow_duplicate_points=True)

    def _propose(self) -> np.ndarray:
        point = self._optimizer.suggest()
        return np.array([float(point[key]) for key in self._keys])

    def _observe(self, unit: np.ndarray, cost: float) -> None:
        self._optimizer.register(params={key: float(u) for key, u in zip(self._keys, unit)}, target=-cost)
