"""Bayesian optimization of controller gains (paper, subsec. BO).

GP surrogate (:class:`agents.surrogate.GPSurrogate`) + Expected Improvement
(:mod:`agents.acquisition`) maximised by exhaustive search over a dense grid of
the feasible set, after a Latin hypercube initial set of ``N0`` experiments.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np
from scipy.stats import qmc

from agents.acquisition import ExpectedImprovement, maximize_on_grid
from agents.base import Tuner
from agents.surrogate import GPSurrogate

__all__ = ["BayesianOptimization", "INCUMBENTS"]

#: Choices of the incumbent ``J+`` of EI.
INCUMBENTS = ("observed", "posterior_mean")

#: Candidate sets larger than this (``grid_points ** n_gains``) are replaced by a Sobol set of this size.
_MAX_GRID = 2**16


class BayesianOptimization(Tuner):
    """GP-EI Bayesian optimization (paper, subsec. BO, Algorithm 1 without the twin).

    1. ``n_initial`` (``N0``) gains from a Latin hypercube of the feasible set
       (``scipy.stats.qmc.LatinHypercube`` seeded by the tuner's rng).
    2. Then, every experiment: fit the GP (Matern 5/2 ARD, constant mean by
       standardising the costs, noise learned or given, hyperparameters by log
       marginal likelihood; inputs scaled to the unit box) on the training set
       ``D`` of eq. (D); query the maximiser of Expected Improvement (eq. (LCB))
       over a ``grid_points``-per-gain grid of the feasible set (eq. (EI)).

    Parameters
    ----------
    n_initial : int, default 1
        Size ``N0`` of the Latin hypercube initial set (the paper uses 1).
    grid_points : int, default 100
        Grid points per gain for maximising EI (100 x 100 for two gains, the
        paper's dense grid). Above 65536 candidates a scrambled Sobol set of
        65536 points is used instead.
    polish : bool, default False
        Refine the best grid point with L-BFGS-B within the bounds.
    incumbent : {"observed", "posterior_mean"}, default "observed"
        ``J+`` of EI: the lowest measured cost in the training set (the
        paper's "best-observed performance") or the lowest posterior mean at
        the training points (robust to a lucky noisy measurement). On
        DCMotor-v0 "observed" reached ratio 1.1 in fewer experiments (see
        benchmarks/data_efficiency.py), so it is the default.
    xi : float, default 0.0
        EI exploration margin, cost units.
    noise_std : float, optional
        Known cost noise ``sigma_eps`` (e.g. from :func:`agents.noise.estimate_noise`);
        ``None`` learns it by marginal likelihood.
    n_restarts : int, default 2
        Random restarts of the likelihood optimiser per fit (seeded by the tuner).
    length_scale_bounds : (float, float), default (0.05, 0.5)
        ARD length-scale bounds in unit-box units. The upper bound keeps the
        GP from explaining a narrow cost valley with one smooth bowl (which
        makes EI stop exploring); 0.5 was best of 0.2-20 on DCMotor-v0.
    noise_bounds : (float, float), default (1e-6, 0.5)
        Bounds of the learned noise variance, in units of the standardised costs.
    warm_start : bool, default True
        Start each hyperparameter fit from the previous one.
    restart_every : int, default 5
        Random restarts only on every ``restart_every``-th fit (warm start in between).

    Attributes
    ----------
    surrogate : GPSurrogate
        The GP; :meth:`fit_surrogate` returns it fitted on the current training set.
    last_ei_, last_std_, last_mean_ : float
        EI (cost units), posterior std and mean of ``J_hat`` at the gains of the
        last :meth:`ask` (``nan`` for initial-design gains).

    Notes
    -----
    Extension points for guided BO: :meth:`add_data` / :meth:`remove_data` /
    :meth:`extra_data` put twin evaluations in the GP's training set and take
    them out again; :meth:`propose` returns ``(gains, ei, std)`` without
    changing the tuner; :meth:`posterior` gives the GP at any gains;
    :meth:`training_set` may be overridden to change what the GP is fitted on.
    """

    name = "bo"

    def __init__(self, *, n_initial: int = 1, grid_points: int = 100, polish: bool = False,
                 incumbent: str = "observed", xi: float = 0.0, noise_std: float | None = None,
                 n_restarts: int = 2, length_scale_bounds: tuple[float, float] = (0.05, 0.5),
                 noise_bounds: tuple[float, float] = (1e-6, 0.5), warm_start: bool = True,
                 restart_every: int = 5) -> None:
        if int(n_initial) < 1:
            raise ValueError(f"n_initial: must be >= 1, got {n_initial}")
        if int(grid_points) < 2:
            raise ValueError(f"grid_points: must be >= 2, got {grid_points}")
        if incumbent not in INCUMBENTS:
            raise ValueError(f"incumbent: must be one of {INCUMBENTS}, got {incumbent!r}")
        if not np.isfinite(xi) or xi < 0:
            raise ValueError(f"xi: must be a finite number >= 0, got {xi}")
        if noise_std is not None and not (np.isfinite(noise_std) and noise_std > 0):
            raise ValueError(f"noise_std: must be None or a finite number > 0, got {noise_std}")
        self.n_initial = int(n_initial)
        self.grid_points = int(grid_points)
        self.polish = bool(polish)
        self.incumbent_rule = incumbent
        self.xi = float(xi)
        self.noise_std = noise_std
        self.n_restarts = int(n_restarts)
        self.length_scale_bounds = tuple(length_scale_bounds)
        self.noise_bounds = tuple(noise_bounds)
        self.warm_start = bool(warm_start)
        self.restart_every = int(restart_every)
        self._params = {"n_initial": self.n_initial, "grid_points": self.grid_points, "polish": self.polish,
                        "incumbent": incumbent, "xi": self.xi, "noise_std": noise_std,
                        "n_restarts": self.n_restarts, "length_scale_bounds": self.length_scale_bounds,
                        "noise_bounds": self.noise_bounds, "warm_start": self.warm_start,
                        "restart_every": self.restart_every}

    # -- Tuner hooks ---------------------------------------------------------------------------------
    def _setup(self) -> None:
        dim = self.space.dim
        # Latin hypercube initial set Theta_init of size N0 (paper, subsec. BO), unit box.
        self._initial = qmc.LatinHypercube(d=dim, rng=self.rng).random(self.n_initial)
        self._unit_grid = _unit_candidates(dim, self.grid_points, self.rng)
        self._fit_seed = int(self.rng.integers(2**31))
        self.surrogate = GPSurrogate(n_restarts=self.n_restarts, length_scale_bounds=self.length_scale_bounds,
                                     noise_std=self.noise_std, noise_bounds=self.noise_bounds,
                                     warm_start=self.warm_start,
                                     restart_every=self.restart_every)
        self._plant_X: list[np.ndarray] = []  # unit box
        self._plant_y: list[float] = []
        self._extra_X: list[np.ndarray] = []
        self._extra_y: list[float] = []
        self._extra_source: list[str] = []
        self._version = 0
        self._fitted_version = -1
        self._optimize_hyperparameters = True  # guided BO holds them fixed during twin iterations
        self.last_ei_ = self.last_std_ = self.last_mean_ = float("nan")

    def _ask(self) -> np.ndarray:
        n = len(self._plant_y)
        if n < self.n_initial:
            self.last_ei_ = self.last_std_ = self.last_mean_ = float("nan")
            return self.space.from_unit(self._initial[n])
        gains, ei, std = self.propose()
        self.last_ei_, self.last_std_ = ei, std
        self.last_mean_ = float(self.posterior(gains[None, :])[0][0])
        return gains

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        # D <- D u {(theta+, J(theta+))}, eq. (D_training)
        self._plant_X.append(self.space.to_unit(gains))
        self._plant_y.append(cost)
        self._version += 1

    def run_summary(self) -> dict[str, Any]:
        if not hasattr(self.surrogate, "kernel_"):
            return {}
        return {"gp_noise_std": self.surrogate.noise_std_,
                "gp_length_scales": [float(v) for v in self.surrogate.length_scales_]}

    # -- what guided BO builds on -------------------------------------------------------------------
    @property
    def n_observations(self) -> int:
        """Number of plant experiments told so far."""
        return len(self._plant_y)

    def training_set(self) -> tuple[np.ndarray, np.ndarray]:
        """The GP's training set ``D`` (eq. (D)): plant data, then extra (twin) data.

        Returns
        -------
        X : ndarray of shape (n, n_gains)
            Unit-box inputs.
        y : ndarray of shape (n,)
            Costs.
        """
        X = self._plant_X + self._extra_X
        y = self._plant_y + self._extra_y
        return np.reshape(np.asarray(X, dtype=float), (len(y), self.space.dim)), np.asarray(y, dtype=float)

    def fit_surrogate(self) -> GPSurrogate:
        """The GP fitted on :meth:`training_set` (refitted only when the data changed)."""
        if self._fitted_version != self._version:
            X, y = self.training_set()
            if y.size == 0:
                raise RuntimeError(f"{type(self).__name__}: no data to fit the GP; tell() an experiment first")
            seed = int(np.random.default_rng([self._fit_seed, self._version]).integers(2**31))
            self.surrogate.fit(X, y, seed=seed, optimize=self._optimize_hyperparameters)
            self._fitted_version = self._version
        return self.surrogate

    def incumbent(self) -> float:
        """``J+`` of EI over the current training set (see ``incumbent`` in the class doc)."""
        model = self.fit_surrogate()
        X, y = self.training_set()
        if self.incumbent_rule == "observed":
            return float(np.min(y))  # J+_n, best observed cost (paper, eq. (LCB))
        return float(np.min(model.predict(X)[0]))

    def propose(self) -> tuple[np.ndarray, float, float]:
        """Next query ``theta_{n+1} = argmax_theta a_EI(theta)`` (eq. (EI)), without side effects.

        Does not count as an ask: the initial design, the data and the rng are
        unchanged (the GP is fitted, or reused if the data did not change).

        Returns
        -------
        gains : ndarray of shape (n_gains,)
            Physical units, inside the feasible set.
        ei : float
            EI at ``gains``, cost units.
        std : float
            Posterior std of ``J_hat`` at ``gains``, cost units.
        """
        model = self.fit_surrogate()
        acquisition = ExpectedImprovement(model, self.incumbent(), self.xi)
        unit_box = np.column_stack([np.zeros(self.space.dim), np.ones(self.space.dim)])
        x, ei = maximize_on_grid(acquisition, self._unit_grid, polish=self.polish, bounds=unit_box)
        std = float(model.predict(x[None, :])[1][0])
        return self.space.from_unit(x), float(ei), std

    def posterior(self, gains) -> tuple[np.ndarray, np.ndarray]:
        """GP mean and std of ``J_hat`` at gains of shape (m, n_gains) (physical units); each (m,)."""
        gains = np.atleast_2d(np.asarray(gains, dtype=float))
        return self.fit_surrogate().predict(self.space.to_unit(gains))

    def add_data(self, gains, costs, source: str = "twin") -> None:
        """Add extra points (e.g. twin evaluations) to the GP's training set (Algorithm 1, line D_in_DT).

        Parameters
        ----------
        gains : array_like of shape (m, n_gains) or (n_gains,)
            Inside the feasible set.
        costs : array_like of shape (m,) or float
            Finite costs.
        source : str, default "twin"
            Label used by :meth:`remove_data`; ``"plant"`` is reserved.
        """
        if source == "plant":
            raise ValueError("source: 'plant' is reserved for tell(); use another label")
        gains = np.atleast_2d(np.asarray(gains, dtype=float))
        costs = np.atleast_1d(np.asarray(costs, dtype=float))
        if gains.shape[0] != costs.shape[0]:
            raise ValueError(f"gains, costs: {gains.shape[0]} gains but {costs.shape[0]} costs")
        for row, cost in zip(gains, costs):
            checked = self.space.check(row, name="add_data(gains)")
            if not np.isfinite(cost):
                raise ValueError(f"add_data(costs): must be finite, got {cost}")
            self._extra_X.append(self.space.to_unit(checked))
            self._extra_y.append(float(cost))
            self._extra_source.append(source)
        self._version += 1

    def remove_data(self, source: str | None = "twin") -> int:
        """Remove extra points with label ``source`` (``None``: all extra points); returns how many.

        Plant experiments are never removed (Algorithm 1, line remove_DT_data).
        """
        keep = [i for i, s in enumerate(self._extra_source) if source is not None and s != source]
        removed = len(self._extra_source) - len(keep)
        self._extra_X = [self._extra_X[i] for i in keep]
        self._extra_y = [self._extra_y[i] for i in keep]
        self._extra_source = [self._extra_source[i] for i in keep]
        if removed:
            self._version += 1
        return removed

    @contextlib.contextmanager
    def extra_data(self, gains, costs, source: str = "twin") -> Iterator[BayesianOptimization]:
        """``with bo.extra_data(gains, costs): bo.propose()`` -- the points are removed on exit."""
        self.add_data(gains, costs, source=source)
        try:
            yield self
        finally:
            self.remove_data(source)


def _unit_candidates(dim: int, points_per_gain: int, rng: np.random.Generator) -> np.ndarray:
    """The dense grid of the unit box, shape (points_per_gain ** dim, dim), or a Sobol set if too large."""
    if points_per_gain**dim <= _MAX_GRID:
        axes = [np.linspace(0.0, 1.0, points_per_gain)] * dim
        return np.column_stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")])
    return qmc.Sobol(d=dim, scramble=True, rng=rng).random(_MAX_GRID)
