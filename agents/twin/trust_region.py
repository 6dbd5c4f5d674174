"""Bounded trust-region reflective least squares whose Jacobian is given compressed (``J~, f~``).

This is the iteration of ``scipy.optimize.least_squares(method="trf")`` (Branch, Coleman
and Li's trust-region reflective method), built from scipy's own step functions, with
either of its step solvers: ``tr_solver="exact"`` (the trust-region subproblem solved
exactly from the SVD of the scaled, regularised Jacobian, Moré's iteration) or
``tr_solver="lsmr"`` (steps in the 2-D subspace of the scaled gradient and the
regularised Gauss-Newton direction found by LSMR). The one difference: ``least_squares`` needs the
residual ``f`` with its Jacobian ``J`` (``n_samples`` rows each), while every step of
the iteration only uses ``J^T J``, ``J^T f`` and the cost ``||f||^2 / 2``. Here the
cost comes from ``cost(x)`` and the linear algebra from a compressed system
``(J~, f~)`` with ``J~^T J~ = J^T J`` and ``J~^T f~ = J^T f`` (:class:`agents.twin.jacobian.RecordQR`),
a few rows per record, so that neither the Jacobian nor ``least_squares``' copies of
the residual (its augmented right-hand side, the LSMR work vectors, ``J`` times the
subspace) exist at full size. In exact arithmetic the steps are those of
``least_squares`` on ``(J, f)``: with ``J = Q R`` the SVD of ``[J D; diag]`` is that of
``[R D; diag]`` with the left factor multiplied by ``Q``, so its singular values, right
vectors and ``U^T [f; 0]`` are the same (and the SVD of a few rows per record costs a
fraction of the full one's: on 12 records of 2,501 samples 0.2 ms instead of 12 ms);
LSMR's stopping test sees ``||f~||`` instead of ``||f||`` (the part of ``f`` outside
the columns of ``J`` is left out), so the Gauss-Newton direction may differ within
LSMR's tolerance.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.linalg import norm
from scipy import sparse
from scipy.linalg import qr, svd

# the step functions of least_squares' trf; private modules of scipy, stable since scipy 0.17
from scipy.optimize._lsq.common import (
    CL_scaling_vector,
    build_quadratic_1d,
    check_termination,
    make_strictly_feasible,
    minimize_quadratic_1d,
    regularized_lsq_operator,
    right_multiplied_operator,
    solve_lsq_trust_region,
    solve_trust_region_2d,
    update_tr_radius,
)
from scipy.optimize._lsq.trf import select_step
from scipy.sparse.linalg import lsmr

__all__ = ["trf"]

#: ``least_squares``' ``xtol`` and ``gtol``: the relative step and the scaled gradient below which the iteration stops
XTOL = GTOL = 1e-12


def trf(cost: Callable[[np.ndarray], float], system: Callable[[np.ndarray], tuple], x0: np.ndarray, cost0: float,
        lower: np.ndarray, upper: np.ndarray, x_scale: np.ndarray, *, ftol: float, max_nfev: int,
        tr_solver: str = "lsmr", n_rows: int | None = None,
        resume: dict | None = None) -> tuple[np.ndarray, float, int, dict]:
    """Minimise ``cost(x)`` within bounds by trust-region reflective steps on a compressed Jacobian.

    Parameters
    ----------
    cost : callable
        ``cost(x)``: half the sum of squared residuals at a trial point.
    system : callable
        ``system(x)`` at an accepted point (the last one ``cost`` was called at): ``(J~, f~)``,
        a sparse matrix or ndarray of shape (m, n) and a vector of shape (m,) with the normal
        equations and gradient of the residual and its Jacobian.
    x0 : ndarray of shape (n,)
        Start, strictly inside the bounds; ``cost0`` its cost (``cost`` is not called there).
    lower, upper : ndarray of shape (n,)
        Bounds.
    x_scale : ndarray of shape (n,)
        Characteristic scale of each variable (``least_squares``' ``x_scale``).
    ftol : float
        ``least_squares``' relative cost decrease below which the iteration stops (also at :data:`XTOL`
        and :data:`GTOL`).
    max_nfev : int
        Cost evaluations at most, the start included.
    tr_solver : {"lsmr", "exact"}, default "lsmr"
        ``least_squares``' step solver: the 2-D subspace of LSMR's Gauss-Newton direction, or
        the exact solution of the trust-region subproblem (from the SVD of ``J~``).
    n_rows : int, optional
        Rows of the uncompressed Jacobian ``J`` (default: those of ``J~``); ``"exact"``
        uses it, as ``least_squares`` does, in its rank test ``s_min > eps n_rows s_max``.
    resume : dict, optional
        The ``state`` an earlier call returned, ``x0`` and ``cost0`` its ``x`` and ``cost``: the iteration
        goes on from there up to ``max_nfev`` (counted from its start). With ``"exact"`` steps it takes the
        steps one call with the larger ``max_nfev`` would have taken: the trust radius and the
        Levenberg-Marquardt parameter are carried, and the Jacobian at ``x`` is the same.

    Returns
    -------
    x : ndarray of shape (n,)
    cost : float
    nfev : int
        Cost evaluations, the start included.
    state : dict
        ``{"delta", "alpha", "nfev", "stopped"}``: the trust radius, the Levenberg-Marquardt parameter,
        ``nfev``, and whether a tolerance (not ``max_nfev``) ended the iteration.
    """
    if tr_solver not in ("lsmr", "exact"):
        raise ValueError(f"tr_solver: must be 'lsmr' or 'exact', got {tr_solver!r}")
    exact = tr_solver == "exact"
    x, cost_x, nfev = x0.copy(), float(cost0), 1 if resume is None else int(resume["nfev"])
    if resume is not None and resume["stopped"]:
        return x, cost_x, nfev, dict(resume)
    jac, f = _system(system, x, exact)
    m, n = jac.shape
    n_rows = m if n_rows is None else int(n_rows)
    g = jac.T @ f
    scale, scale_inv = x_scale, 1.0 / x_scale
    if resume is not None:  # the trust radius and Levenberg-Marquardt parameter where the last fit stopped
        delta, alpha = float(resume["delta"]), float(resume["alpha"])
    else:  # least_squares' initial radius; alpha, of the exact steps, is carried from step to step
        v, dv = CL_scaling_vector(x, g, lower, upper)
        v[dv != 0] *= scale_inv[dv != 0]
        delta, alpha = norm(x0 * scale_inv / v**0.5) or 1.0, 0.0
    f_augmented = np.zeros(m + n)
    stopped = False
    while True:
        v, dv = CL_scaling_vector(x, g, lower, upper)
        g_norm = norm(g * v, ord=np.inf)
        if g_norm < GTOL or nfev >= max_nfev:
            stopped = g_norm < GTOL
            break
        v[dv != 0] *= scale_inv[dv != 0]
        d = v**0.5 * scale  # Coleman-Li scaling after x_scale
        diag_h = g * dv * scale
        g_h = d * g  # gradient in the scaled ("hat") variables
        f_augmented[:m] = f
        if exact:  # least_squares' tr_solver="exact": the SVD of the scaled Jacobian over diag(diag_h)^(1/2)
            jac_augmented = np.vstack((jac * d, np.diag(diag_h**0.5)))
            jac_h = jac_augmented[:m]
            u_svd, s_svd, vt_svd = svd(jac_augmented, full_matrices=False)
            v_svd = vt_svd.T
            uf = u_svd.T @ f_augmented
        else:
            jac_h = right_multiplied_operator(jac, d)
            a, b = build_quadratic_1d(jac_h, g_h, -g_h, diag=diag_h)
            reg_term = -minimize_quadratic_1d(a, b, 0, delta / norm(g_h))[1] / delta**2
            gauss_newton = lsmr(regularized_lsq_operator(jac_h, (diag_h + reg_term) ** 0.5), f_augmented)[0]
            basis = qr(np.vstack((g_h, gauss_newton)).T, mode="economic")[0]
            jac_basis = jac_h.dot(basis)
            b_s = jac_basis.T @ jac_basis + (basis.T * diag_h) @ basis
            g_s = basis.T @ g_h
        theta = max(0.995, 1.0 - g_norm)  # how far a step stays from the bounds
        reduction, done = -1.0, False
        while reduction <= 0 and nfev < max_nfev:
            if exact:
                p_h, alpha, _ = solve_lsq_trust_region(n, n_rows, uf, s_svd, v_svd, delta, initial_alpha=alpha)
            else:
                p_h = basis @ solve_trust_region_2d(b_s, g_s, delta)[0]
            step, step_h, predicted = select_step(x, jac_h, diag_h, g_h, d * p_h, p_h, d, delta, lower, upper, theta)
            x_new = make_strictly_feasible(x + step, lower, upper, rstep=0)
            cost_new = float(cost(x_new))
            nfev += 1
            step_h_norm = norm(step_h)
            if not np.isfinite(cost_new):
                delta = 0.25 * step_h_norm
                continue
            reduction = cost_x - cost_new
            delta_new, ratio = update_tr_radius(delta, reduction, predicted, step_h_norm, step_h_norm > 0.95 * delta)
            if check_termination(reduction, cost_x, norm(step), norm(x), ratio, ftol, XTOL) is not None:
                done = True
                break
            alpha *= delta / delta_new
            delta = delta_new
        if reduction > 0:
            x, cost_x = x_new, cost_new
            if done:
                stopped = True
                break
            jac, f = _system(system, x, exact)
            g = jac.T @ f
        elif done:
            stopped = True
            break
    return x, cost_x, nfev, {"delta": delta, "alpha": alpha, "nfev": nfev, "stopped": stopped}


def _system(system: Callable[[np.ndarray], tuple], x: np.ndarray, dense: bool) -> tuple:
    """``system(x)``, its matrix made dense for the exact steps (their SVD)."""
    jac, f = system(x)
    if dense and sparse.issparse(jac):
        jac = jac.toarray()
    return jac, f
