"""Expected Improvement for minimisation, and its maximisation over a grid (paper, eqs. (LCB), (EI)).

An acquisition function meets the surrogate only through
``model.predict(X) -> (mean, std)``; any object with that method works.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from scipy.optimize import minimize
from scipy.special import ndtr

__all__ = ["Predictor", "expected_improvement", "ExpectedImprovement", "maximize_on_grid"]

_SQRT_2PI = np.sqrt(2.0 * np.pi)


class Predictor(Protocol):
    """Anything with a posterior ``predict(X) -> (mean, std)``, X of shape (m, d)."""

    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


def expected_improvement(mean, std, best: float, xi: float = 0.0) -> np.ndarray:
    """Expected Improvement of a minimisation problem (paper, eq. (LCB)).

    ``a_EI(theta) = sigma (z Phi(z) + phi(z))``, ``z = (J+ - mu - xi) / sigma``,

    with ``mu, sigma`` the posterior mean and std, ``J+`` the incumbent (best)
    cost, ``Phi``/``phi`` the standard normal cdf/pdf and ``xi >= 0`` an
    optional exploration margin. The paper typesets ``z = (mu - J+) / sigma``,
    which is the improvement of a *maximisation*; since the controller cost is
    minimised (eq. (opt_prob)) the improvement is ``J+ - J`` and the sign of
    ``z`` flips. Where ``sigma = 0`` EI is ``max(J+ - mu - xi, 0)``.

    Parameters
    ----------
    mean, std : array_like of shape (m,)
        Posterior mean and standard deviation (cost units).
    best : float
        Incumbent ``J+`` (cost units).
    xi : float, default 0
        Exploration margin (cost units).

    Returns
    -------
    ndarray of shape (m,)
        EI, in cost units, ``>= 0``.
    """
    mean = np.asarray(mean, dtype=float)
    std = np.asarray(std, dtype=float)
    improvement = best - mean - xi
    positive = std > 1e-12
    z = np.where(positive, improvement / np.where(positive, std, 1.0), 0.0)
    ei = std * (z * ndtr(z) + np.exp(-0.5 * z**2) / _SQRT_2PI)
    return np.where(positive, np.maximum(ei, 0.0), np.maximum(improvement, 0.0))


class ExpectedImprovement:
    """EI of eq. (LCB) bound to a model and an incumbent: ``acq(X) -> values``.

    Parameters
    ----------
    model : Predictor
        The surrogate; only ``model.predict(X)`` is called.
    best : float
        Incumbent ``J+`` (cost units).
    xi : float, default 0
        Exploration margin (cost units).
    """

    def __init__(self, model: Predictor, best: float, xi: float = 0.0) -> None:
        self.model = model
        self.best = float(best)
        self.xi = float(xi)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """EI at inputs of shape (m, d), shape (m,)."""
        mean, std = self.model.predict(np.atleast_2d(X))
        return expected_improvement(mean, std, self.best, self.xi)


def maximize_on_grid(acquisition, grid: np.ndarray, polish: bool = False,
                     bounds: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """``argmax`` of an acquisition over a grid of candidates (paper, eq. (EI)).

    Parameters
    ----------
    acquisition : callable
        ``acquisition(X)`` of shape (m,) for X of shape (m, d); evaluated once
        on the whole grid (one vectorised ``predict``).
    grid : ndarray of shape (m, d)
        Candidate points (the dense grid of the feasible set).
    polish : bool, default False
        Refine the best grid point with L-BFGS-B (numerical gradients) inside
        ``bounds``; the refined point is kept only if its value is higher.
    bounds : ndarray of shape (d, 2), optional
        Box for the polish (default: the grid's bounding box).

    Returns
    -------
    x : ndarray of shape (d,)
    value : float
        The acquisition at ``x``.
    """
    values = np.asarray(acquisition(grid), dtype=float)
    index = int(np.argmax(values))  # first maximiser: deterministic ties
    x, value = grid[index].copy(), float(values[index])
    if polish:
        box = np.column_stack([grid.min(axis=0), grid.max(axis=0)]) if bounds is None else np.asarray(bounds)
        result = minimize(lambda p: -float(acquisition(p[None, :])[0]), x, method="L-BFGS-B", bounds=box,
                          options={"maxiter": 50})
        if np.all(np.isfinite(result.x)) and -result.fun > value:
            x, value = np.clip(result.x, box[:, 0], box[:, 1]), float(-result.fun)
    return x, value
