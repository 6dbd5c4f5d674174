"""Bounded trust-region reflective least squares whose Jacobian is given compressed (``J~, f~``).

This is the iteration of ``scipy.optimize.least_squares(method="trf", tr_solver="lsmr")``
(Branch, Coleman and Li's trust-region reflective method, steps in the 2-D subspace of
the scaled gradient and the regularised Gauss-Newton direction found by LSMR), built
from scipy's own step functions. The one difference: ``least_squares`` needs the
residual ``f`` with its Jacobian ``J`` (``n_samples`` rows each), while every step of
the iteration only uses ``J^T J``, ``J^T f`` and the cost ``||f||^2 / 2``. Here the
cost comes from ``cost(x)`` and the linear algebra from a compressed system
``(J~, f~)`` with ``J~^T J~ = J^T J`` and ``J~^T f~ = J^T f`` (:class:`agents.twin.jacobian.RecordQR`),
a few rows per record, so that neither the Jacobian nor ``least_squares``' copies of
the residual (its augmented right-hand side, the LSMR work vectors, ``J`` times the
subspace) exist at full size. In exact arithmetic the steps are those of
``least_squares`` on ``(J, f)``; LSMR's stopping test sees ``||f~||`` instead of
``||f||`` (the part of ``f`` outside the columns of ``J`` is left out), so the
Gauss-Newton direction may differ within LSMR's tolerance.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.linalg import norm
from scipy.linalg import qr

# the step functions of least_squares' trf; private modules of scipy, stable since scipy 0.17
from scipy.optimize._lsq.common import (
    CL_scaling_vector,
    build_quadratic_1d,
    check_termination,
    make_strictly_feasible,
    minimize_quadratic_1d,
    regularized_lsq_operator,
    right_multiplied_operator,
    solve_trust_region_2d,
    update_tr_radius,
)
from scipy.optimize._lsq.trf import select_step
from scipy.sparse.linalg import lsmr

__all__ = ["trf"]


def trf(cost: Callable[[np.ndarray], float], system: Callable[[np.ndarray], tuple], x0: np.ndarray, cost0: float,
        lower: np.ndarray, upper: np.ndarray, x_scale: np.ndarray, *, ftol: float, xtol: float = 1e-12,
        gtol: float = 1e-12, max_nfev: int) -> tuple[np.ndarray, float, int]:
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
    ftol, xtol, gtol : float
        ``least_squares``' tolerances: relative cost decrease, relative step, scaled gradient.
    max_nfev : int
        Cost evaluations at most, the start included.

    Returns
    -------
    x : ndarray of shape (n,)
    cost : float
    nfev : int
        Cost evaluations, the start included.
    """
    x, cost_x, nfev = x0.copy(), float(cost0), 1
    jac, f = system(x)
    m, n = jac.shape
    g = jac.T @ f
    scale, scale_inv = x_scale, 1.0 / x_scale
    v, dv = CL_scaling_vector(x, g, lower, upper)
    v[dv != 0] *= scale_inv[dv != 0]
    delta = norm(x0 * scale_inv / v**0.5) or 1.0
    f_augmented = np.zeros(m + n)
    while True:
        v, dv = CL_scaling_vector(x, g, lower, upper)
        g_norm = norm(g * v, ord=np.inf)
        if g_norm < gtol or nfev >= max_nfev:
            break
        v[dv != 0] *= scale_inv[dv != 0]
        d = v**0.5 * scale  # Coleman-Li scaling after x_scale
        diag_h = g * dv * scale
        g_h = d * g  # gradient in the scaled ("hat") variables
        f_augmented[:m] = f
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
            if check_termination(reduction, cost_x, norm(step), norm(x), ratio, ftol, xtol) is not None:
                done = True
                break
            delta = delta_new
        if reduction > 0:
            x, cost_x = x_new, cost_new
            if done:
                break
            jac, f = system(x)
            g = jac.T @ f
        elif done:
            break
    return x, cost_x, nfev
