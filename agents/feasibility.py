"""GP models of an env's constraints and the probability that gains keep them (Gardner et al. 2014).

An env with constraints (:mod:`gbo_envs.constraints`) reports for every experiment
``record["constraints"]``: name -> ``c_j = value_j - limit_j`` (``<= 0`` kept) and
``record["feasible"]``. :class:`ConstraintModel` fits one GP per constraint on its slack
``c_j`` in units of the limit, ``c_j / |limit_j|`` (``c_j`` when the limit is 0), where an
unstable experiment enters with at least ``UNSTABLE_SLACK`` (a violation of the size of the
limit: its metrics are those of a diverged response), then divided by the median ``|c_j|`` of
the experiments so far (a slack of typical size is 1, whatever the margin of the limit: a
command limit of 140 over a steady command of 135 has slacks of a few percent of the limit)
and clipped to ``[-CLIP, CLIP]``, so that a diverged experiment does not dominate the fit.
With the GPs independent, the probability of feasibility is

    PF(theta) = prod_j Phi(-mu_j(theta) / sigma_j(theta))

(mu_j, sigma_j: the posterior mean and std of s_j; Gardner et al., "Bayesian Optimization
with Inequality Constraints", ICML 2014, eq. (5)).

The GP of a constraint has a **zero prior mean** (a gain far from every experiment is taken
to sit on the limit, ``PF = 1/2`` per constraint, never in a safe set) and a kernel
amplitude of at least :data:`MIN_AMPLITUDE` (in median slacks): unlike the cost GP it is not
standardised, because a standardised GP fitted on a few equal slacks (a safe start measured
again) becomes certain everywhere and calls the whole box safe. Kernel: ``s^2 Matern_5/2``
(ARD length scales in ``[0.05, 0.5]`` of the unit box for any number of gains: unlike the cost GPs'
(:func:`agents.surrogate.dimension_scale`) they do not grow with it, since a longer length scale makes a
safety model confident farther from its data) plus a linear term ``s_l^2 (x . x' +
0.01)`` on the gains centred on the box (a slack that grows with a gain, as the peak command
with ``Kp``, is extrapolated along its trend: a stationary zero-mean GP alone reverts to the
limit slowly and called gains beyond the trend safe) plus white noise; hyperparameters by
marginal likelihood from :data:`MIN_FIT_POINTS` experiments on (scikit-learn's
``GaussianProcessRegressor``, warm-started, :data:`RESTARTS` restarts on every
:data:`RESTART_EVERY`-th fit), the prior kernel (amplitude 1, length scales 0.2,
noise variance 1e-4) below.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy.optimize import minimize
from scipy.special import ndtr
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, DotProduct, Matern, WhiteKernel

from gbo_envs.constraints import keeps

__all__ = ["CLIP", "ConstrainedAcquisition", "ConstraintModel", "UNSTABLE_SLACK", "constraint_set",
           "reported_slacks", "run_risk", "validated_safe_start"]

#: Scaled slacks are clipped to ``[-CLIP, CLIP]`` (median slacks).
CLIP = 5.0
#: Smallest scaled slack of an unstable experiment.
UNSTABLE_SLACK = 1.0
#: Least kernel std of a constraint GP, in median slacks.
MIN_AMPLITUDE = 0.5
#: Experiments from which the constraint GPs' hyperparameters are fitted.
MIN_FIT_POINTS = 5
#: Random restarts of the likelihood optimiser on the first and every :data:`RESTART_EVERY`-th fit
#: (the others start from the previous fit alone, as :class:`agents.surrogate.GPSurrogate` does).
RESTARTS, RESTART_EVERY = 2, 5
#: L-BFGS-B iterations per start.
MAX_ITER = 60


def constraint_set(env) -> tuple[tuple[str, ...], np.ndarray] | None:
    """``(names, limits)`` of the env's constraints (``env.unwrapped.constraints``), or ``None`` without."""
    plant = getattr(env, "unwrapped", env)
    limits = getattr(plant, "constraints", None)
    if not limits:
        return None
    return tuple(limits.names), np.asarray(limits.limits, dtype=float)


def reported_slacks(record: dict | None, names, limits) -> list[float]:
    """The ``value - limit`` of every constraint of an experiment, finite, for a peer library's constraint model.

    As the env reports them (``<= 0`` kept), except where they would mislead or break a model:
    a failed experiment (no record) and an unstable one count each constraint as broken by at
    least its limit (``|limit|``, 1 for a zero limit), and a non-finite value as broken by 10 limits.

    Parameters
    ----------
    record : dict or None
        The experiment's ``info`` (``record["constraints"]``, ``record["unstable"]``).
    names : sequence of str
    limits : array_like of shape (len(names),)
    """
    scale = np.where(np.abs(np.asarray(limits, dtype=float)) > 0, np.abs(np.asarray(limits, dtype=float)), 1.0)
    slacks = (record or {}).get("constraints") or {}
    values = np.array([float(slacks.get(name, np.nan)) for name in names])
    if record is None or record.get("unstable", False) or record.get("failed", False):
        values = np.where(np.isnan(values), scale, np.maximum(values, scale))
    values = np.where(np.isnan(values), scale, values)
    return np.where(np.isfinite(values), values, 10.0 * scale).tolist()


def run_risk(delta: float, experiment: int) -> float:
    """The risk ``delta_t`` admitted for the ``t``-th experiment of a run so that the whole run keeps ``delta``.

    A safe tuner that admits the same risk ``delta`` at every proposal breaks a limit in a run of
    ``T`` experiments with probability up to ``1 - (1 - delta)^T`` (35 experiments at
    ``delta = 0.05``: 83 %), and since each proposal maximises the acquisition on the edge of the
    safe set, it sits where ``PF`` is just ``1 - delta``. SafeOpt's guarantee (Sui et al. 2015,
    Lemma 1, after Srinivas et al. 2010, Lemma 5.1) is for the run: it splits ``delta`` over the
    experiments as ``delta_t = 6 delta / (pi^2 t^2)`` (``sum_{t >= 1} delta_t = delta``), so that by
    the union bound every proposal of the run keeps the limits with probability ``>= 1 - delta``
    (without SafeOpt's union over the candidate set, which the grid makes arbitrary).

    Parameters
    ----------
    delta : float
        The admitted probability that the run breaks a limit at all, in ``(0, 1)``.
    experiment : int
        ``t``, the number of the experiment in the run (1 for the first), ``>= 1``.

    Returns
    -------
    float
        ``delta_t = 6 delta / (pi^2 t^2)``; a proposal is safe when ``PF >= 1 - delta_t``.
    """
    if not 0.0 < delta < 1.0:
        raise ValueError(f"delta: must be in (0, 1), got {delta}")
    if experiment < 1:
        raise ValueError(f"experiment: must be >= 1, got {experiment}")
    return 6.0 * delta / (math.pi**2 * experiment**2)


def validated_safe_start(values) -> np.ndarray:
    """``safe_start`` (gains known to keep every constraint) as finite gains of shape (m, n_gains).

    Raises
    ------
    ValueError
        Not numbers, empty, or not finite.
    """
    try:
        start = np.atleast_2d(np.asarray(values, dtype=float))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"safe_start: expected gains of shape (m, n_gains), got {values!r}") from exc
    if start.ndim != 2 or start.size == 0 or not np.all(np.isfinite(start)):
        raise ValueError(f"safe_start: expected finite gains of shape (m, n_gains), got {values!r}")
    return start


class ConstraintModel:
    """One GP per constraint on its scaled slack, and the probability of feasibility of gains.

    Parameters
    ----------
    names : sequence of str
        The constraints, in the order of ``record["constraints"]``.
    limits : array_like of shape (n_constraints,)
        Their limits (to scale the slacks).
    """

    def __init__(self, names, limits) -> None:
        self.names = tuple(names)
        limits = np.asarray(limits, dtype=float).ravel()
        if limits.size != len(self.names):
            raise ValueError(f"limits: need one per constraint {self.names}, got {limits.size}")
        self.limits = limits
        self.scales = np.where(np.abs(limits) > 0, np.abs(limits), 1.0)
        self.models: list[GaussianProcessRegressor] = []
        self._X: list[np.ndarray] = []
        self._S: list[np.ndarray] = []
        self._feasible: list[bool] = []
        self._version = 0
        self._fitted = -1
        self._kernels: dict = {}
        self._n_fits = 0

    # -- data ---------------------------------------------------------------------------------------
    def add(self, x: np.ndarray, record: dict | None) -> bool | None:
        """Learn the constraints of one experiment at unit-box ``x``; returns its feasibility (``None``: unknown).

        A record without ``constraints`` (a failed experiment) is not learned.
        """
        slacks = None if not record else record.get("constraints")
        if not slacks or any(name not in slacks for name in self.names):
            return None
        raw = np.array([float(slacks[name]) for name in self.names])
        scaled = np.where(np.isnan(raw), UNSTABLE_SLACK, raw / self.scales)
        if record.get("unstable", False):
            scaled = np.maximum(scaled, UNSTABLE_SLACK)
        scaled = np.where(np.isfinite(scaled), scaled, UNSTABLE_SLACK)
        kept = bool(np.all(keeps(raw, self.limits))) and not record.get("unstable", False)
        feasible = bool(record.get("feasible", kept))
        self._X.append(np.asarray(x, dtype=float).copy())
        self._S.append(scaled)
        self._feasible.append(feasible)
        self._version += 1
        return feasible

    @property
    def n_observations(self) -> int:
        """Experiments learned."""
        return len(self._S)

    @property
    def observed_feasible(self) -> np.ndarray:
        """Feasibility of every learned experiment, shape (n,)."""
        return np.asarray(self._feasible, dtype=bool)

    # -- posterior ----------------------------------------------------------------------------------
    def fit(self, seed: int | None = None) -> ConstraintModel:
        """Fit every constraint GP (only when new data came in); constraint ``j`` gets ``seed + j``."""
        if not self._S:
            raise RuntimeError("ConstraintModel: no experiment with constraints learned yet")
        if self._fitted != self._version:
            X, S = np.vstack(self._X), np.vstack(self._S)
            self.unit_ = np.maximum(np.median(np.abs(S), axis=0), 1e-9)
            S = np.clip(S / self.unit_, -CLIP, CLIP)
            restarts = RESTARTS if self._n_fits % RESTART_EVERY == 0 else 0
            self.models = [_fit_gp(self.features(X), S[:, j], None if seed is None else int(seed) + j,
                                   self._kernels.get(j), restarts) for j in range(S.shape[1])]
            if X.shape[0] >= MIN_FIT_POINTS:  # warm starts from fitted hyperparameters only
                self._kernels = {j: model.kernel_ for j, model in enumerate(self.models)}
                self._n_fits += 1
            self._fitted = self._version
        return self

    @staticmethod
    def features(X: np.ndarray) -> np.ndarray:
        """The GPs' inputs: unit-box gains centred on the box (the linear term's origin), shape (m, d)."""
        return np.atleast_2d(np.asarray(X, dtype=float)) - 0.5

    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Posterior mean and std of every scaled slack at unit-box X (m, d), each (m, n_constraints)."""
        Z = self.features(X)
        parts = [model.predict(Z, return_std=True) for model in self.models]
        return np.column_stack([p[0] for p in parts]), np.column_stack([p[1] for p in parts])

    def probability(self, X: np.ndarray) -> np.ndarray:
        """``PF(theta) = prod_j Phi(-mu_j / sigma_j)`` at unit-box X (m, d), shape (m,) (module doc)."""
        mean, std = self.predict(X)
        z = np.where(std > 1e-12, -mean / np.maximum(std, 1e-12), np.where(mean <= 0.0, math.inf, -math.inf))
        return np.prod(ndtr(z), axis=1)


class ConstrainedAcquisition:
    """``EI(theta) x PF(theta)`` (Gardner et al. 2014, eq. (6)), or ``PF`` alone before any feasible experiment.

    In a safe set (``safe_level``) the value is ``-1`` wherever ``PF < safe_level``, below any EI
    (``>= 0``), so that a maximiser proposes outside it only if nothing inside is a candidate.

    Parameters
    ----------
    ei : callable or None
        ``ei(X) -> values`` (the Expected Improvement over the best feasible cost); ``None``: no
        feasible experiment yet, maximise ``PF``.
    constraints : ConstraintModel
        Fitted.
    safe_level : float, optional
        ``1 - delta``: the least ``PF`` of a proposal (safe mode); ``None``: no restriction.
    """

    def __init__(self, ei, constraints: ConstraintModel, safe_level: float | None = None) -> None:
        self.ei, self.constraints, self.safe_level = ei, constraints, safe_level

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(X)
        pf = self.constraints.probability(X)
        value = pf if self.ei is None else np.asarray(self.ei(X), dtype=float) * pf
        if self.safe_level is not None:
            value = np.where(pf >= self.safe_level, value, -1.0)
        return value


def _fit_gp(X: np.ndarray, s: np.ndarray, seed: int | None, previous=None,
            restarts: int = 0) -> GaussianProcessRegressor:
    """A zero-mean GP on one constraint's scaled slacks (module doc), warm-started from ``previous``."""
    dim = X.shape[1]
    few = X.shape[0] < MIN_FIT_POINTS
    kernel = ConstantKernel(1.0, (MIN_AMPLITUDE**2, 1e2)) * Matern(np.full(dim, 0.2), (0.05, 0.5), nu=2.5) \
        + ConstantKernel(1.0, (1e-4, 1e2)) * DotProduct(0.1, "fixed") + WhiteKernel(1e-4, (1e-6, 1e-1))
    if previous is not None and not few:
        kernel = previous
    gp = GaussianProcessRegressor(kernel, alpha=1e-8, normalize_y=False, optimizer=None if few else _lbfgsb,
                                  n_restarts_optimizer=0 if few else restarts,
                                  random_state=None if seed is None else int(seed) % (2**32))
    with warnings.catch_warnings():  # a hyperparameter at its bound is expected with few points
        warnings.simplefilter("ignore", ConvergenceWarning)
        return gp.fit(X, s)


def _lbfgsb(objective, theta, bounds):
    """scikit-learn's GP optimizer, L-BFGS-B, limited to :data:`MAX_ITER` iterations."""
    result = minimize(objective, theta, method="L-BFGS-B", jac=True, bounds=bounds, options={"maxiter": MAX_ITER})
    return result.x, result.fun
