"""Confidence intervals of fitted grey-box parameters, from the least-squares Jacobian at the fit."""

from __future__ import annotations

import numpy as np
from scipy.special import stdtrit

from agents.thread_limits import single_thread
from agents.twin.least_squares import jacobian, make_problem
from agents.twin.model import GreyFit
from agents.twin.records import Batch

__all__ = ["parameter_intervals"]


@single_thread()
def parameter_intervals(data: Batch, fit: GreyFit, level: float = 0.95) -> dict[str, dict]:
    """Standard error and confidence interval of each global parameter the fit moved.

    The covariance is the Gauss-Newton one, ``s^2 (J^T J)^{-1}`` with ``J`` the
    Jacobian of the simulation error (:func:`agents.twin.least_squares.jacobian`) with
    respect to every parameter the least-squares fit moves (global parameters,
    per-record rest levels and biases) and ``s^2 = RSS / (n - p)`` the residual
    variance; the interval is ``value +- t_{(1+level)/2, n-p} * std``. It assumes
    white residuals: a residual that is not white (see :func:`agents.twin.residuals.residuals`)
    makes it too narrow. Parameters chosen on a grid (the quantization step) get none.

    Parameters
    ----------
    data : Batch
        The data ``fit`` was fitted to.
    fit : GreyFit
    level : float, default 0.95
        Confidence level, in (0, 1).

    Returns
    -------
    dict
        ``{global name: {"value", "std", "low", "high"}}`` (``spec.global_names()``), in the
        parameter's units; ``std`` is ``nan`` (and the bounds too) where the data do not
        determine the parameter (a singular ``J^T J``).
    """
    if not 0.0 < float(level) < 1.0:
        raise ValueError(f"level: must be in (0, 1), got {level}")
    rows = np.arange(data.n_records)
    problem = make_problem(data, fit.spec, fit.theta, fit.y0, fit.bias, rows, start=fit.start)
    free = np.flatnonzero(problem.free & (problem.lower < problem.upper))
    jac = jacobian(data, problem, problem.theta)[data.mask.ravel()]
    dof = max(data.n_samples - free.size, 1)
    s2 = fit.rmse**2 * data.n_samples / dof
    norms = np.linalg.norm(jac, axis=0)
    norms[norms == 0] = 1.0
    scaled = jac / norms
    _, sv, vt = np.linalg.svd(scaled, full_matrices=False)
    keep = sv > sv[0] * 1e-10
    inv = (vt[keep].T / sv[keep] ** 2) @ vt[keep]  # pseudo-inverse of the scaled J^T J
    with np.errstate(invalid="ignore"):  # inf * 0 where the fit diverged: a NaN variance, an undetermined parameter
        var = s2 * np.diag(inv) / norms**2
    # a direction the data do not see (a dropped singular value) leaves its parameters undetermined
    blind = np.abs(vt[~keep]).max(axis=0) > 1e-3 if (~keep).any() else np.zeros(free.size, bool)
    quantile = float(stdtrit(dof, 0.5 + float(level) / 2.0))  # Student's t quantile (scipy.stats.t.ppf's own)
    names = fit.spec.global_names()
    out = {}
    for col, j in enumerate(free):
        if j >= fit.theta.size:
            break
        value = float(fit.theta[j])
        std = float(np.sqrt(var[col])) if not blind[col] and np.isfinite(var[col]) else float("nan")
        out[names[j]] = {"value": value, "std": std, "low": value - quantile * std, "high": value + quantile * std}
    return out
