"""Certified minimum of a batched cost over a box, in any dimension: Sobol points, then multistart local search.

A grid of ``r`` points per gain costs ``r ** d`` simulations, which is out of reach
from three gains up. :func:`certified_minimum` instead runs two independent
searches on the noise-free cost and reports how far apart their minima are:

1. **search A**: ``n_points`` scrambled Sobol points (``scipy.stats.qmc.Sobol``,
   seed ``seeds[0]``), evaluated in batches; L-BFGS-B from the best ``n_starts``,
   its gradient by forward differences, each gradient one batch of ``d + 1`` gains;
2. **search B**: another ``n_points`` Sobol points (seed ``seeds[1]``) and
   bounded Nelder-Mead from the best ``n_starts``, which needs no gradient;
3. in both searches every start then ends with Nelder-Mead restarted from its
   best point with a fresh simplex until a restart gains less than
   :data:`RESTART_GAIN` (at most :data:`RESTARTS` restarts): the settling time is
   read on the sample grid and the overshoot of a quantised sensor comes in
   steps, so the cost has steps that a gradient does not see and that stall a
   single Nelder-Mead run, most often where the optimum lies on a bound;
4. the result is the lower of the two minima; their relative difference
   ``|J_A - J_B| / min(J_A, J_B)`` is the *disagreement*, to be within
   ``tolerance`` (a :class:`SearchDisagreement` warning says when it is not).

Both searches work on the unit box (each gain scaled by its range), so their
steps and tolerances are fractions of the feasible set.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from tqdm.auto import tqdm

__all__ = ["SearchDisagreement", "SearchResult", "certified_minimum", "default_points"]

#: Finite-difference step of search A, a fraction of each gain's range.
GRADIENT_STEP = 1e-5
#: Size of Nelder-Mead's initial simplex, a fraction of each gain's range.
SIMPLEX_STEP = 0.05
#: Nelder-Mead restarts per start at most, and the relative gain below which they stop.
RESTARTS, RESTART_GAIN = 10, 1e-7


class SearchDisagreement(RuntimeWarning):
    """The two searches of :func:`certified_minimum` found minima further apart than its tolerance."""


@dataclass(frozen=True)
class SearchResult:
    """The minimum of one search of :func:`certified_minimum`.

    Attributes
    ----------
    gains : ndarray of shape (d,)
        The minimiser, in the box's units.
    cost : float
        The cost there.
    method : str
        The local method (``"L-BFGS-B"`` or ``"Nelder-Mead"``).
    seed : int
        The Sobol seed.
    evaluations : int
        Cost evaluations (Sobol points and local search).
    """

    gains: np.ndarray
    cost: float
    method: str
    seed: int
    evaluations: int


def default_points(dim: int) -> int:
    """Sobol points per search for ``dim`` gains: ``2 ** (10 + dim)``, at most ``2 ** 16``."""
    return 2 ** min(10 + int(dim), 16)


def certified_minimum(cost: Callable[[np.ndarray], np.ndarray], low, high, *, n_points: int | None = None,
                      n_starts: int = 16, seeds: tuple[int, int] = (0, 1), tolerance: float = 1e-3,
                      chunk: int = 1024, max_evaluations: int | None = None,
                      progress: bool = False) -> tuple[SearchResult, SearchResult, float]:
    """Minimise ``cost`` over the box ``[low, high]`` twice, independently, and compare the two minima.

    Parameters
    ----------
    cost : callable
        ``cost(gains)`` of shape (n,) for gains of shape (n, d): deterministic
        (the noise-free or expected cost), finite or ``inf``.
    low, high : array_like of shape (d,)
        The box, ``low < high``, in gain units.
    n_points : int, optional
        Sobol points per search, ``>= n_starts`` (default :func:`default_points`).
    n_starts : int, default 16
        Local searches per search, from its best Sobol points, ``>= 1``.
    seeds : (int, int), default (0, 1)
        Sobol seeds of searches A and B; must differ.
    tolerance : float, default 1e-3
        Largest admitted relative difference of the two minima, ``> 0``.
    chunk : int, default 1024
        Gains per batch of Sobol points.
    max_evaluations : int, optional
        Cost evaluations per local run (default ``200 * d``; each Nelder-Mead restart is a run).
    progress : bool, default False
        A tqdm progress bar over the batches and the local searches.

    Returns
    -------
    best : SearchResult
        The lower of the two minima.
    other : SearchResult
        The other one.
    disagreement : float
        ``|J_A - J_B| / min(J_A, J_B)`` (0 when both are 0).

    Warns
    -----
    SearchDisagreement
        When ``disagreement > tolerance``.
    """
    low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    if low.ndim != 1 or low.shape != high.shape or low.size == 0 or not np.all(np.isfinite(low)) \
            or not np.all(np.isfinite(high)) or not np.all(low < high):
        raise ValueError(f"low, high: need finite 1-D bounds of one length with low < high, got {low}, {high}")
    dim = low.size
    n_points = default_points(dim) if n_points is None else n_points
    for name, value, least in (("n_starts", n_starts, 1), ("n_points", n_points, n_starts), ("chunk", chunk, 1)):
        if isinstance(value, bool) or int(value) != value or value < least:
            raise ValueError(f"{name}: must be an integer >= {least}, got {value}")
    if len(seeds) != 2 or int(seeds[0]) == int(seeds[1]):
        raise ValueError(f"seeds: need two different integers, got {seeds}")
    if not tolerance > 0:
        raise ValueError(f"tolerance: must be > 0, got {tolerance}")
    max_evaluations = 200 * dim if max_evaluations is None else int(max_evaluations)
    span = high - low

    def unit_cost(points: np.ndarray) -> np.ndarray:
        return np.asarray(cost(low + np.clip(points, 0.0, 1.0) * span), dtype=float)

    total = 2 * (-(-int(n_points) // int(chunk)) + int(n_starts))
    with tqdm(total=total, desc="ground truth search", unit="step", disable=not progress) as bar:
        found = [_search(unit_cost, dim, int(n_points), int(n_starts), int(seed), method, int(chunk),
                         max_evaluations, bar)
                 for seed, method in zip(seeds, ("L-BFGS-B", "Nelder-Mead"))]
    results = [SearchResult(gains=low + x * span, cost=value, method=method, seed=int(seed), evaluations=count)
               for (x, value, count), seed, method in zip(found, seeds, ("L-BFGS-B", "Nelder-Mead"))]
    best, other = sorted(results, key=lambda r: r.cost)
    gap = other.cost - best.cost
    disagreement = 0.0 if gap == 0 else float(gap / abs(best.cost)) if best.cost != 0 else float("inf")
    if not disagreement <= tolerance:
        warnings.warn(f"certified_minimum: the two searches disagree by {disagreement:.3g} (relative cost), "
                      f"above the tolerance {tolerance:g}: {results[0].method} found {results[0].cost:.6g} at "
                      f"{results[0].gains}, {results[1].method} {results[1].cost:.6g} at {results[1].gains}",
                      SearchDisagreement, stacklevel=2)
    return best, other, disagreement


def _search(cost, dim: int, n_points: int, n_starts: int, seed: int, method: str, chunk: int,
            max_evaluations: int, bar) -> tuple[np.ndarray, float, int]:
    """One search on the unit box: Sobol points, then ``method`` from the best ``n_starts``; (x, J, evaluations)."""
    from scipy.stats import qmc  # heavy dependency: scipy.stats (0.9 s), loaded by a search, not by `import gbo_envs`

    points = qmc.Sobol(d=dim, scramble=True, rng=np.random.default_rng(seed)).random(n_points)
    values = []
    for start in range(0, n_points, chunk):
        values.append(cost(points[start:start + chunk]))
        bar.update()
    values = np.concatenate(values)
    ranked = np.where(np.isfinite(values), values, np.inf)
    order = np.argsort(ranked, kind="stable")
    best_x, best_value, evaluations = points[order[0]].copy(), float(ranked[order[0]]), n_points
    box = [(0.0, 1.0)] * dim
    for index in order[:n_starts]:
        x, value, count = _local(cost, points[index], float(ranked[index]), method, box, max_evaluations)
        evaluations += count
        for _ in range(RESTARTS):
            restart, restart_value, count = _local(cost, x, value, "Nelder-Mead", box, max_evaluations)
            evaluations += count
            gained = restart_value < value * (1 - RESTART_GAIN) if value > 0 else restart_value < value
            if restart_value < value:
                x, value = restart, restart_value
            if not gained:
                break
        if value < best_value:
            best_x, best_value = x, value
        bar.update()
    return best_x, best_value, evaluations


def _local(cost, x0: np.ndarray, f0: float, method: str, box, max_evaluations: int) -> tuple[np.ndarray, float, int]:
    """One local search from ``x0`` (unit box); the best point it evaluated, its cost and the evaluations."""
    from scipy.optimize import minimize  # heavy dependency: scipy.optimize, loaded by a search, not at import

    dim = x0.size
    best = [x0.copy(), f0]
    count = [0]

    def keep(X: np.ndarray, f: np.ndarray) -> None:
        count[0] += X.shape[0]
        i = int(np.argmin(np.where(np.isfinite(f), f, np.inf)))
        if f[i] < best[1]:
            best[0], best[1] = X[i].copy(), float(f[i])

    scale = 1.0 / max(abs(f0), 1e-12) if np.isfinite(f0) else 1.0  # L-BFGS-B's tolerances are absolute
    if method == "L-BFGS-B":
        steps = np.eye(dim) * GRADIENT_STEP

        def objective(x: np.ndarray) -> tuple[float, np.ndarray]:
            forward = x + steps
            backward = forward > 1.0  # at the upper bound the difference is taken backwards
            forward[backward] = (x - steps)[backward]
            X = np.vstack([x, forward])
            f = cost(X)
            keep(X, f)
            if not np.all(np.isfinite(f)):
                return float("inf"), np.zeros(dim)
            sign = np.where(backward.any(axis=1), -1.0, 1.0)
            return scale * float(f[0]), scale * sign * (f[1:] - f[0]) / GRADIENT_STEP

        minimize(objective, x0, jac=True, method="L-BFGS-B", bounds=box,
                 options={"maxfun": max(1, max_evaluations // (dim + 1)), "ftol": 1e-12, "gtol": 1e-10})
    else:
        simplex = np.vstack([x0, x0 + np.diag(np.where(x0 + SIMPLEX_STEP <= 1.0, SIMPLEX_STEP, -SIMPLEX_STEP))])

        def scalar(x: np.ndarray) -> float:
            f = cost(x[None, :])
            keep(x[None, :], f)
            return scale * float(f[0]) if np.isfinite(f[0]) else float("inf")

        minimize(scalar, x0, method="Nelder-Mead", bounds=box,
                 options={"initial_simplex": simplex, "maxfev": max_evaluations, "xatol": 1e-6, "fatol": 1e-10})
    return best[0], best[1], count[0]
