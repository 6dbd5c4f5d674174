"""Expected Improvement for minimisation, and its maximisation (paper, eqs. (LCB), (EI)).

An acquisition function meets the surrogate only through
``model.predict(X) -> (mean, std)``; any object with that method works. The
maximisers meet the acquisition only through ``acquisition(X) -> values``
(BoTorch's separation of model, acquisition and optimizer):
:func:`maximize_on_grid` searches a fixed candidate set (the dense grid of two
gains), :func:`maximize_multistart` works in any dimension (Sobol candidates,
then batched L-BFGS-B from the best of them).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from scipy.optimize import minimize
from scipy.special import ndtr
from scipy.stats import qmc

__all__ = ["Predictor", "expected_improvement", "ExpectedImprovement", "maximize_multistart", "maximize_on_grid"]

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


def maximize_multistart(acquisition, bounds, rng, n_candidates: int = 2048, n_starts: int = 8,
                        max_iter: int = 200, step: float = 1e-6) -> tuple[np.ndarray, float]:
    """``argmax`` of an acquisition over a box in any dimension: Sobol candidates, then multistart L-BFGS-B.

    1. ``n_candidates`` points of a scrambled Sobol sequence (``scipy.stats.qmc.Sobol``
       seeded by ``rng``) in the box, evaluated in one call of ``acquisition``;
    2. the best ``n_starts`` of them start L-BFGS-B inside the box. The starts are
       refined jointly, as BoTorch's ``gen_candidates_scipy`` does: one problem in
       ``n_starts * d`` variables whose objective is the sum of the starts' values
       (they do not interact, so each start follows its own gradient), with the
       gradient by forward differences of step ``step`` (a step back at the upper
       bound), so that each iteration is one call of ``acquisition`` on
       ``n_starts * (d + 1)`` points;
    3. the best point seen (a refined start or a candidate) is returned.

    Parameters
    ----------
    acquisition : callable
        ``acquisition(X)`` of shape (m,) for X of shape (m, d), to be maximised.
    bounds : array_like of shape (d, 2)
        The box, ``low < high`` per row (the unit box for BO).
    rng : numpy.random.Generator or int
        Seeds the Sobol scramble (a fixed seed gives a fixed answer).
    n_candidates : int, default 2048
        Sobol candidates, ``>= 1`` (a power of 2 keeps the sequence balanced).
    n_starts : int, default 8
        Starts of the refinement, ``1 <= n_starts``; at most ``n_candidates`` are used.
    max_iter : int, default 200
        L-BFGS-B iterations of the joint problem.
    step : float, default 1e-6
        Finite-difference step, in the box's units.

    Returns
    -------
    x : ndarray of shape (d,)
        Inside the box.
    value : float
        The acquisition at ``x``.
    """
    box = np.asarray(bounds, dtype=float)
    if box.ndim != 2 or box.shape[1] != 2 or box.shape[0] == 0 or not np.all(box[:, 0] < box[:, 1]):
        raise ValueError(f"bounds: need an array of shape (d, 2) with low < high per row, got {box.tolist()}")
    for name, value in (("n_candidates", n_candidates), ("n_starts", n_starts), ("max_iter", max_iter)):
        if isinstance(value, bool) or int(value) != value or value < 1:
            raise ValueError(f"{name}: must be an integer >= 1, got {value}")
    if not step > 0:
        raise ValueError(f"step: must be > 0, got {step}")
    low, high = box[:, 0], box[:, 1]
    d = box.shape[0]
    candidates = low + qmc.Sobol(d=d, scramble=True, rng=rng).random(int(n_candidates)) * (high - low)
    values = np.asarray(acquisition(candidates), dtype=float)
    order = np.argsort(-values, kind="stable")[: int(n_starts)]
    best_x, best_value = candidates[order[0]].copy(), float(values[order[0]])
    starts = candidates[order]
    k = starts.shape[0]
    # scale the objective so the best start has value ~1: L-BFGS-B's tolerances are absolute
    scale = 1.0 / max(abs(best_value), 1e-300)
    steps = np.eye(d) * step
    seen: list[tuple[np.ndarray, np.ndarray]] = []

    def objective(z: np.ndarray) -> tuple[float, np.ndarray]:
        X = z.reshape(k, d)
        shifted = X[:, None, :] + steps[None, :, :]  # (k, d, d): start i moved along gain j
        backward = shifted > high  # at the upper bound the difference is taken backwards
        shifted = np.where(backward, X[:, None, :] - steps[None, :, :], shifted)
        f = np.asarray(acquisition(np.vstack([X, shifted.reshape(k * d, d)])), dtype=float)
        f0, f1 = f[:k], f[k:].reshape(k, d)
        sign = np.where(backward.any(axis=2), -1.0, 1.0)
        grad = (f1 - f0[:, None]) / step * sign
        seen.append((X.copy(), f0.copy()))
        return -scale * float(np.sum(f0)), -scale * grad.ravel()

    result = minimize(objective, starts.ravel(), jac=True, method="L-BFGS-B",
                      bounds=np.tile(box, (k, 1)), options={"maxiter": int(max_iter)})
    final = np.clip(result.x.reshape(k, d), low, high)
    final_values = np.asarray(acquisition(final), dtype=float)
    for X, f in [*seen, (final, final_values)]:
        finite = np.where(np.isfinite(f), f, -np.inf)
        i = int(np.argmax(finite))
        if finite[i] > best_value:
            best_x, best_value = np.clip(X[i], low, high), float(finite[i])
    return best_x, best_value
