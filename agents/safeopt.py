"""SafeOpt: safe exploration from known-safe gains by GP confidence bounds (registry name ``safeopt``).

Sui, Gotovos, Burdick and Krause, "Safe Exploration for Optimization with Gaussian Processes",
ICML 2015, with several constraints and without a Lipschitz constant as in Berkenkamp, Krause
and Schoellig, "Bayesian optimization with safety constraints: safe and automatic parameter
tuning in robotics", Machine Learning 2023 (the ``safeopt`` package's ``SafeOpt`` with
``lipschitz=None``). On a finite candidate set ``D`` (the dense grid of the feasible set for up
to two gains, a Sobol set above, plus the safe starts), with ``beta`` the confidence scaling:

* confidence bounds ``l(x) = mu(x) - beta sigma(x)``, ``u(x) = mu(x) + beta sigma(x)`` of the
  cost GP and of every constraint GP (the slack ``value - limit``, :mod:`agents.feasibility`);
* **safe set** ``S_n = S_{n-1} u {x in D : u_j(x) <= 0 for every constraint j}``, ``S_0`` the
  safe starts (it only grows, as in the package);
* **maximisers** ``M_n = {x in S_n : l_J(x) <= min_{x' in S_n} u_J(x')}``, the safe gains that
  may still be optimal (the cost is minimised);
* **expanders** ``G_n``: safe gains ``x`` where a measurement at the optimistic bound
  ``l_j(x)`` of every constraint (a fictitious observation, the GPs' hyperparameters fixed)
  would make some gain outside ``S_n`` safe;
* the next experiment is the gain of ``M_n u G_n`` with the largest width ``u - l`` (over the
  cost, in units of the costs' std, and the constraints, in units of their median slack).

Only expander candidates wider than the widest maximiser are checked (they alone can be
chosen), at most ``max_expander_checks`` of them against the ``n_targets`` unsafe candidates
nearest the safe set.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.linalg import solve_triangular
from scipy.spatial import cKDTree
from scipy.stats import qmc

from agents.base import Tuner
from agents.bo import _unit_candidates
from agents.feasibility import ConstraintModel, constraint_set, validated_safe_start
from agents.parameters import Interval, validate_params
from agents.surrogate import GPSurrogate
from agents.thread_limits import single_thread

__all__ = ["SafeOpt"]


class SafeOpt(Tuner):
    """SafeOpt on the env's constraints from ``safe_start`` (module doc).

    Parameters
    ----------
    safe_start : array_like of shape (m, n_gains) or (n_gains,), optional
        Gains known to keep every constraint, in the env's units; the first ``m`` experiments.
        Required on an env with constraints. On an env without, every gain is safe: the safe
        set is the whole candidate set and the first experiment is ``bo``'s Latin hypercube point.
    beta : float, default 2.0
        Confidence scaling of the bounds ``mu +- beta sigma`` (> 0; 2 is the package's default).
    grid_points : int, default 100
        Candidates per gain for up to two gains (``grid_points ** n_gains``, above 65536 a Sobol set).
    n_candidates : int, default 4096
        Sobol candidates from three gains up.
    noise_std : float, optional
        Known cost noise (cost units); ``None`` learns it.
    max_expander_checks : int, default 256
        Expander candidates checked per experiment (the widest).
    n_targets : int, default 2048
        Unsafe candidates, nearest the safe set, against which an expander is checked.

    Raises
    ------
    ValueError
        At :meth:`setup`: an env with constraints but no ``safe_start``, or a ``safe_start`` of
        the wrong number of gains or outside the feasible set.
    """

    name = "safeopt"

    _parameter_constraints: dict[str, list] = {
        "beta": [Interval(float, 0.0, None, closed="neither")],
        "grid_points": [Interval(int, 2, None)],
        "n_candidates": [Interval(int, 1, None)],
        "noise_std": [None, Interval(float, 0.0, None, closed="neither")],
        "max_expander_checks": [Interval(int, 1, None)],
        "n_targets": [Interval(int, 1, None)],
    }

    def __init__(self, *, safe_start=None, beta: float = 2.0, grid_points: int = 100, n_candidates: int = 4096,
                 noise_std: float | None = None, max_expander_checks: int = 256, n_targets: int = 2048) -> None:
        self._params = validate_params(self._parameter_constraints, {
            "beta": beta, "grid_points": grid_points, "n_candidates": n_candidates, "noise_std": noise_std,
            "max_expander_checks": max_expander_checks, "n_targets": n_targets})
        self.safe_start = None if safe_start is None else validated_safe_start(safe_start)
        if self.safe_start is not None:
            self._params["safe_start"] = self.safe_start.tolist()
        for key in ("beta", "grid_points", "n_candidates", "noise_std", "max_expander_checks", "n_targets"):
            setattr(self, key, self._params[key])

    def _setup(self) -> None:
        known = constraint_set(self.env)
        dim = self.space.dim
        if self.safe_start is not None:
            if self.safe_start.shape[1] != dim:
                raise ValueError(f"safe_start: need gains of {dim} values each, got shape {self.safe_start.shape}")
            starts = np.vstack([self.space.to_unit(self.space.check(row, name="safe_start"))
                                for row in self.safe_start])
        elif known is not None:
            raise ValueError("safe_start: SafeOpt on an env with constraints needs gains known to keep every "
                             "constraint, e.g. safe_start=[[0.3, 1.0]]; it explores only from them")
        else:  # no constraints: every gain is safe, start as bo does
            starts = qmc.LatinHypercube(d=dim, rng=self.rng).random(1)
        self._starts = starts
        if dim <= 2:
            grid = _unit_candidates(dim, self.grid_points, self.rng)
        else:
            grid = qmc.Sobol(d=dim, scramble=True, rng=self.rng).random(self.n_candidates)
        self._D = np.vstack([starts, grid])  # the safe starts are candidates 0 .. m-1
        self._safe = np.zeros(self._D.shape[0], dtype=bool) if known is not None else \
            np.ones(self._D.shape[0], dtype=bool)
        self._safe[: starts.shape[0]] = True
        self._fit_seed = int(self.rng.integers(2**31))
        self.cost_gp = GPSurrogate(noise_std=self.noise_std)
        self.constraints = None if known is None else ConstraintModel(*known)
        self._X: list[np.ndarray] = []
        self._y: list[float] = []
        self.last_sets_: dict[str, int] = {}

    def _ask(self) -> np.ndarray:
        n = len(self._y)
        if n < self._starts.shape[0]:
            return self.space.from_unit(self._starts[n])
        with single_thread():
            return self.space.from_unit(self._D[self._next()])

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        x = self.space.to_unit(gains)
        self._X.append(x)
        self._y.append(cost)
        if self.constraints is not None:
            self.constraints.add(x, record)

    def run_summary(self) -> dict[str, Any]:
        return {"safe_share": float(np.mean(self._safe[self._starts.shape[0]:])), **self.last_sets_}

    # -- SafeOpt's sets -----------------------------------------------------------------------------
    def _next(self) -> int:
        """Index in the candidate set of the next experiment (module doc)."""
        seed = int(np.random.default_rng([self._fit_seed, len(self._y)]).integers(2**31))
        X, y = np.vstack(self._X), np.asarray(self._y)
        self.cost_gp.fit(X, y, seed=seed)
        mean, std = self.cost_gp.predict(self._D)
        lower, upper = mean - self.beta * std, mean + self.beta * std
        width = 2 * self.beta * std / self.cost_gp.y_scale_
        if self.constraints is not None and self.constraints.n_observations:
            self.constraints.fit(seed=seed + 1)
            c_mean, c_std = self.constraints.predict(self._D)
            self._safe |= np.all(c_mean + self.beta * c_std <= 0.0, axis=1)
            width = np.maximum(width, 2 * self.beta * c_std.max(axis=1))
        safe = np.flatnonzero(self._safe)
        maximisers = safe[lower[safe] <= np.min(upper[safe])]
        best = maximisers[np.argmax(width[maximisers])]
        expanders = self._expanders(safe, maximisers, width, width[best])
        if expanders.size:
            candidate = expanders[np.argmax(width[expanders])]
            if width[candidate] > width[best]:
                best = candidate
        self.last_sets_ = {"safe_set": int(safe.size), "maximisers": int(maximisers.size),
                           "expanders": int(expanders.size)}
        return int(best)

    def _expanders(self, safe: np.ndarray, maximisers: np.ndarray, width: np.ndarray, floor: float) -> np.ndarray:
        """The expanders among the safe candidates wider than ``floor`` (module doc)."""
        unsafe = np.flatnonzero(~self._safe)
        if self.constraints is None or not self.constraints.n_observations or not unsafe.size:
            return np.empty(0, dtype=int)
        others = np.setdiff1d(safe, maximisers)
        others = others[width[others] > floor]
        if not others.size:
            return np.empty(0, dtype=int)
        others = others[np.argsort(-width[others], kind="stable")[: self.max_expander_checks]]
        distance, _ = cKDTree(self._D[safe]).query(self._D[unsafe])
        targets = unsafe[np.argsort(distance, kind="stable")[: self.n_targets]]
        becomes_safe = np.ones((others.size, targets.size), dtype=bool)
        for model in self.constraints.models:
            becomes_safe &= _optimistic_upper(model, self.constraints.features(self._D[others]),
                                              self.constraints.features(self._D[targets]), self.beta) <= 0.0
        return others[becomes_safe.any(axis=1)]


def _optimistic_upper(gp, A: np.ndarray, B: np.ndarray, beta: float) -> np.ndarray:
    """Upper bound at every B after a fictitious observation at each A at its lower bound, shape (|A|, |B|).

    For a fitted zero-mean scikit-learn GP with hyperparameters fixed: with ``k_n`` the posterior
    covariance and ``s^2 = k_n(a, a) + noise``, the observation ``l(a) = mu(a) - beta sigma(a)``
    moves the posterior at ``b`` to ``mu(b) - k_n(b, a) beta sigma(a) / s^2`` with variance
    ``k_n(b, b) - k_n(b, a)^2 / s^2`` (a rank-one update of the posterior).
    """
    kernel = gp.kernel_
    latent, noise = kernel.k1, float(kernel.k2.noise_level)
    train = gp.X_train_
    v_a = _solve(gp, latent(train, A))
    v_b = _solve(gp, latent(train, B))
    mu_b = latent(B, train) @ gp.alpha_
    var_a = np.maximum(latent.diag(A) - np.sum(v_a**2, axis=0), 0.0)
    var_b = np.maximum(latent.diag(B) - np.sum(v_b**2, axis=0), 0.0)
    cov = latent(A, B) - v_a.T @ v_b  # k_n(a, b), (|A|, |B|)
    s2 = var_a + noise
    sigma_a = np.sqrt(var_a)
    mean = mu_b[None, :] - cov * (beta * sigma_a / s2)[:, None]
    var = np.maximum(var_b[None, :] - cov**2 / s2[:, None], 0.0)
    return mean + beta * np.sqrt(var)


def _solve(gp, K: np.ndarray) -> np.ndarray:
    """``L^-1 K`` with the GP's Cholesky factor ``L`` of ``K(X, X) + alpha I``."""
    return solve_triangular(gp.L_, K, lower=True)
