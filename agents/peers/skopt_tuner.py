"""scikit-optimize behind the tuner API: ``skopt.Optimizer`` as ``gp_minimize`` sets it up (registry name ``skopt``)."""

from __future__ import annotations

import numpy as np

from agents.peers.base import PeerTuner

__all__ = ["SkoptTuner"]


class SkoptTuner(PeerTuner):
    """scikit-optimize's ``gp_minimize`` through ``skopt.Optimizer``'s ask/tell, after BO's initial design.

    The optimizer is built as ``gp_minimize`` builds it: a GP base estimator
    (``cook_estimator("GP", noise="gaussian")``: constant x Matern 5/2 kernel, normalised
    costs, learned noise), the ``"gp_hedge"`` acquisition (a portfolio of EI, PI and LCB
    with ``xi = 0.01``, ``kappa = 1.96``) maximised by L-BFGS-B from the best of 10,000
    random points with 5 restarts. It works on the unit box and is seeded by the tuner
    rng; it fits its GP once the ``n_initial`` design points are told.

    Parameters
    ----------
    n_initial : int, default 1
        Size ``N0`` of the Latin hypercube initial design (the same points as ``agents.make("bo")``).

    Raises
    ------
    ImportError
        If scikit-optimize is not installed (``pip install "gbo-envs[peers]"``).
    """

    name = "skopt"
    library = ("skopt", "scikit-optimize")

    def _start(self) -> None:
        import skopt
        from skopt.utils import cook_estimator

        dimensions = [skopt.space.Real(0.0, 1.0) for _ in range(self.space.dim)]
        rng = np.random.RandomState(self.library_seed)
        estimator = cook_estimator("GP", space=dimensions, random_state=rng.randint(0, np.iinfo(np.int32).max),
                                   noise="gaussian")
        self._optimizer = skopt.Optimizer(
            dimensions, base_estimator=estimator, n_initial_points=self.n_initial, acq_func="gp_hedge",
            acq_optimizer="lbfgs", random_state=rng,
            acq_func_kwargs={"xi": 0.01, "kappa": 1.96},
            acq_optimizer_kwargs={"n_points": 10000, "n_restarts_optimizer": 5, "n_jobs": 1})

    def _propose(self) -> np.ndarray:
        return np.asarray(self._optimizer.ask(), dtype=float)

    def _observe(self, unit: np.ndarray, cost: float) -> None:
        self._optimizer.tell([float(u) for u in unit], cost)
