"""A digital twin's performance metrics as the prior mean of the metric GPs.

Guided BO's default (``GuidedBO(guidance="prior")``) fits the default BO's
metric GPs (:mod:`agents.metric_surrogate`) to the *discrepancy* between plant
and twin: the GP of metric ``i`` models ``T_i(f_i(theta)) - T_i(f~_i(theta))``,
``f~_i`` the twin's metric (:class:`agents.twin.TwinEnv`, simulated with the
plant's controller, step and noise floor). Where the twin is right the
discrepancy is flat and the posterior follows the twin everywhere, also far
from the plant data; where it is wrong, the plant data correct it locally.

The twin is simulated once per candidate point and twin: :class:`TwinMetrics`
keeps every row it has simulated, so the EI grid (10^4 gains) costs one batched
simulation per fitted twin, and every later GP prediction is a look-up.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TwinMetrics", "unstable_metrics"]


def unstable_metrics(env) -> np.ndarray:
    """Metrics of shape (n_metrics,) whose cost is the env's ``unstable_cost``: ``n_i unstable_cost / sum_j w_j``.

    ``J = sum_i w_i f_i / n_i`` (eq. (J_used)) of these metrics is ``unstable_cost``; they
    stand for a diverging experiment (plant or twin) in the metric GPs.
    """
    weights = np.asarray(env.weights, dtype=float)
    return np.asarray(env.normalizers, dtype=float) * float(env.unstable_cost) / float(np.sum(weights))


class TwinMetrics:
    """``prior(X) -> f~`` of a twin env at unit-box gains: the twin's expected raw metrics, cached per row.

    Parameters
    ----------
    twin_env : agents.twin.TwinEnv
        The twin in the plant's closed loop; :meth:`~agents.twin.TwinEnv.evaluate` gives its
        expected metrics (over its measurement noise draws, if any).
    space : agents.GainSpace
        Maps unit-box inputs to physical gains.

    Attributes
    ----------
    simulations_ : int
        Gains simulated so far (each once).

    Notes
    -----
    Where the twin's loop diverges (or a metric is not finite), every metric is set so that
    the twin's cost is the env's ``unstable_cost``: ``f~_i = n_i unstable_cost / sum_j w_j``,
    since ``J = sum_i w_i f_i / n_i`` (eq. (J_used)).
    """

    def __init__(self, twin_env, space) -> None:
        self.twin_env = twin_env
        self.space = space
        self._unstable = unstable_metrics(twin_env)
        self._rows: dict[bytes, np.ndarray] = {}
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self.simulations_ = 0

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """Raw twin metrics of shape (m, n_metrics) at unit-box inputs of shape (m, d)."""
        if self._last is not None and X is self._last[0]:
            return self._last[1]  # the same candidate array as the previous call (one per metric GP)
        X = np.atleast_2d(np.asarray(X, dtype=float))
        keys = [row.tobytes() for row in X]
        missing = [i for i, key in enumerate(keys) if key not in self._rows]
        if missing:
            first: dict[bytes, int] = {}  # each new gain once, at its first row
            for i in missing:
                first.setdefault(keys[i], i)
            unique = list(first)
            rows = X[list(first.values())]
            metrics = self.twin_env.evaluate(self.space.from_unit(rows))[0]
            bad = ~np.all(np.isfinite(metrics), axis=1)
            metrics = np.where(bad[:, None], self._unstable, metrics)
            self.simulations_ += len(unique)
            self._rows.update(zip(unique, metrics))
        values = np.vstack([self._rows[key] for key in keys])
        self._last = (X, values)
        return values
