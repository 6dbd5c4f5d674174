r"""Simplified refined instrumental variable method for continuous-time models (SRIVC).

The model is the continuous-time transfer function with an input delay

.. math::

    x(t) = \frac{B(p)}{A(p)} u(t - \tau), \qquad y(t_k) = y_0 + x(t_k) + e(t_k),

    A(p) = p^n + a_1 p^{n-1} + \dots + a_n, \qquad B(p) = b_0 p^m + \dots + b_m,

with ``p = d/dt``, ``m < n``, ``e`` the measurement noise, and the record in
deviations from its rest levels: ``u - u_0`` enters the plant, and ``y_0, u_0``
(the pre-step equilibrium) are estimated per record when ``offset=True``.
``k`` known poles at ``s = 0`` are imposed by fixing ``a_{n-k+1} = ... = a_n = 0``.

SRIVC (Young & Jakeman 1980; Garnier, Wang & Young 2008) iterates, from an
initial estimate ``theta^0`` (here the least-squares state-variable filter fit,
:func:`lssvf`), for ``j = 1, 2, ...``:

(a) prefilter with ``F(p) = 1 / A^{j-1}(p)``::

        y_f^{(i)} = p^i / A^{j-1}(p) y,   u_f^{(i)} = p^i / A^{j-1}(p) u(t - tau)          (S1)

    (``i = 0..n``; ``y_f^{(n)} = y - sum_i a_i^{j-1} y_f^{(n-i)}``);
(b) simulate the noise-free auxiliary model and filter it::

        x_hat = B^{j-1}(p) / A^{j-1}(p) u(t - tau),   x_f^{(i)} = p^i / A^{j-1}(p) x_hat     (S2)

(c) regressor, instrument and target::

        phi_f  = [-y_f^{(n-1)}, ..., -y_f^{(0)}, u_f^{(m)}, ..., u_f^{(0)}]^T
        zeta_f = [-x_f^{(n-1)}, ..., -x_f^{(0)}, u_f^{(m)}, ..., u_f^{(0)}]^T                 (S3)

(d) solve the IV normal equations over all samples of all records::

        theta^j = [ sum_k zeta_f(t_k) phi_f(t_k)^T ]^{-1} sum_k zeta_f(t_k) y_f^{(n)}(t_k)   (S4)

until ``||theta^j - theta^{j-1}|| <= tol ||theta^j||``. The rest levels enter
(S4) as two nuisance regressors per record, ``1`` (for ``y_0``) and the
auxiliary model's step response ``B^{j-1}/A^{j-1} 1(t - tau)`` (for ``u_0``),
projected out of ``phi_f``, ``zeta_f`` and ``y_f^{(n)}`` (they are noise-free,
so they are their own instruments).

Filters are simulated exactly on the sample grid: the prefilter ``1/A`` in
controllable canonical form, whose states are ``p^{n-1}/A, ..., 1/A``, is
discretised with a zero-order hold and the fractional input delay by
:meth:`gbo_envs.ContinuousPlant.discretize`, turned into one ``z``-transfer
function per state and run as ``scipy.signal.lfilter`` runs it, compiled, over all
states and records at once (:func:`gbo_envs.physics.kernels.lfilter_rows`). For
decimated records (``hold="foh"``) the signals are first interpolated linearly onto
a grid ``oversample`` times finer (value at the middle of each fine interval) and
filtered there, which approximates a first-order hold.

Closed loop: ``u`` depends on the noise through the feedback. The instrument
``zeta_f`` is built from ``u`` and the noise-free model output ``x_hat``, never
from ``y``, and at convergence (``A^{j-1} = A``) the equation error of (S4) at
``t_k`` is ``y(t_k) - x(t_k) = e(t_k)`` (white). With a sampled controller,
``u(t_k)`` depends on ``e`` up to ``t_k``, but the strictly proper filters make
``zeta_f(t_k)`` depend on ``u`` before ``t_k`` only, so ``zeta_f(t_k)`` is
uncorrelated with ``e(t_k)`` and the estimate stays consistent under feedback,
whereas least squares (``zeta_f = phi_f``) is biased. For coloured noise or a
controller output that reacts within the same sample, prefer the closed-loop
variant of Gilson et al. (2008), which simulates the instrument from ``r``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from gbo_envs import ContinuousPlant

__all__ = ["Orders", "Signals", "SrivcResult", "lssvf", "prepare", "simulate", "srivc", "stabilised"]


@dataclass(frozen=True)
class Orders:
    """Model structure: ``n`` poles (``k`` of them at ``s = 0``), ``m`` zeros."""

    n: int
    m: int
    k: int = 0

    @property
    def n_params(self) -> int:
        """Free parameters ``a_1..a_{n-k}, b_0..b_m``."""
        return self.n - self.k + self.m + 1

    def den(self, theta: np.ndarray) -> np.ndarray:
        """Monic ``A`` of shape (n + 1,), highest power first."""
        return np.concatenate([[1.0], theta[: self.n - self.k], np.zeros(self.k)])

    def num(self, theta: np.ndarray) -> np.ndarray:
        """``B`` of shape (m + 1,), highest power first."""
        return np.asarray(theta[self.n - self.k :], dtype=float)


@dataclass(frozen=True, eq=False)
class Signals:
    """One batch of records in deviations, ready for filtering.

    Attributes
    ----------
    h : float
        Filter step in s (the sample time divided by ``oversample``).
    u_fine, y_fine : ndarray of shape (n_records, n_fine)
        Input ``u - u_ref`` and output ``y - y_ref`` as staircases on the filter grid.
    rows : ndarray of int, shape (n_steps,)
        Filter-grid index of each measured sample.
    y : ndarray of shape (n_records, n_steps)
        Measured ``y - y_ref``.
    y_ref, u_ref, r2 : ndarray of shape (n_records,)
        Reference levels subtracted, and the post-step reference.
    free : ndarray of bool, shape (n_records,)
        Records whose rest levels ``(y0, u0)`` are estimated (with ``offset=True``); the others are
        pinned at ``(y_ref, u_ref)``, the rest their data show (:mod:`agents.twin.initial`).
    """

    h: float
    u_fine: np.ndarray
    y_fine: np.ndarray
    rows: np.ndarray
    y: np.ndarray
    y_ref: np.ndarray
    u_ref: np.ndarray
    r2: np.ndarray
    free: np.ndarray

    def at_samples(self, x: np.ndarray) -> np.ndarray:
        """``x[..., rows]``: the measured samples of signals on the filter grid (``x`` itself where the grid is
        the samples' own, ``hold="zoh"``: no copy)."""
        return x if self.rows.size == x.shape[-1] else x[..., self.rows]


@dataclass(frozen=True)
class SrivcResult:
    """Outcome of :func:`srivc`: parameters, iterations and convergence flag."""

    theta: np.ndarray
    n_iter: int
    converged: bool


def prepare(dt: float, u: np.ndarray, y: np.ndarray, r2: np.ndarray, offset: bool, hold: str,
            oversample: int = 10, rest: np.ndarray | None = None) -> Signals:
    """Subtract reference levels and lay the signals on the filter grid.

    ``y_ref = y[0]``; ``u_ref = u[0]`` when the rest input is estimated
    (``offset=True``), else ``0`` (the record is already a deviation). ``rest`` of shape
    (n_records, 2) pins the rest levels ``(y0, u0)`` of the records whose row is finite
    (``NaN`` rows are estimated).
    """
    y_ref = y[:, 0].copy()
    u_ref = u[:, 0].copy() if offset else np.zeros(u.shape[0])
    free = np.full(u.shape[0], bool(offset))
    if rest is not None:
        pinned = np.all(np.isfinite(rest), axis=1)
        y_ref[pinned], u_ref[pinned] = rest[pinned, 0], rest[pinned, 1]
        free &= ~pinned
    du, dy = u - u_ref[:, None], y - y_ref[:, None]
    n = u.shape[1]
    if hold == "zoh":
        return Signals(dt, du, dy, np.arange(n), dy, y_ref, u_ref, r2, free)
    fine_t = np.minimum((np.arange((n - 1) * oversample + 1) + 0.5) / oversample, n - 1)  # mid-interval
    grid = np.arange(n)
    u_fine = np.stack([np.interp(fine_t, grid, row) for row in du])
    y_fine = np.stack([np.interp(fine_t, grid, row) for row in dy])
    return Signals(dt / oversample, u_fine, y_fine, np.arange(n) * oversample, dy, y_ref, u_ref, r2, free)


class _Prefilter:
    """``p^i / A(p)``, ``i = n-1 .. 0``, sampled exactly with step ``h`` and input delay.

    The delay's whole samples ``d`` are a shift of the filtered signal, not ``d`` leading zeros of the
    numerators: ``lfilter``'s work per sample grows with the numerator's length.
    """

    def __init__(self, den: np.ndarray, h: float, delay: float) -> None:
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is caught below, and said there
            plant = ContinuousPlant(num=(1.0,), den=tuple(den), delay=delay).discretize(h)
            den_z = _sampled_denominator(np.asarray(den, dtype=float).tobytes(), float(h))
            num0 = _state_numerators(plant.phi, plant.gamma0, den_z)
            num1 = _state_numerators(plant.phi, plant.gamma1, den_z)
        n = plant.order
        if not (np.all(np.isfinite(num0)) and np.all(np.isfinite(num1)) and np.all(np.isfinite(den_z))):
            # e^{A h} overflows: a pole of A(p) beyond about 1e35 / h (an iterate whose pole ran off to
            # -infinity), which no sample can show; its NaN filters would reach LAPACK
            raise FloatingPointError(f"A(p) = {den.tolist()}: poles too fast to discretise at h = {h:g} s")
        nums = np.zeros((n, n + 2))
        nums[:, : n + 1] += num0  # x[k+1] = Phi x[k] + Gamma0 u[k-d] + Gamma1 u[k-d-1]
        nums[:, 1:] += num1
        self.nums, self.den = nums, den_z
        self.order, self.shift = n, plant.delay_steps

    def states(self, x: np.ndarray) -> np.ndarray:
        """Filter ``x`` of shape (batch, n_fine); return states of shape (n, batch, n_fine).

        Every state of every row in one compiled pass (:func:`gbo_envs.physics.kernels.lfilter_rows`, the
        numbers of ``scipy.signal.lfilter``), zero until the input arrives (the shift).
        """
        # heavy dependency: numba (kept off the diagnose start-up path)
        from gbo_envs.physics import kernels

        flat = x.reshape(-1, x.shape[-1])
        signals = flat.shape[0]
        out = kernels.lfilter_rows(np.repeat(self.nums, signals, axis=0), self.den, flat,
                                   source=np.tile(np.arange(signals), self.order), shift=self.shift)
        return out.reshape(self.order, *x.shape)


def _prefilter(den: np.ndarray, h: float, delay: float) -> _Prefilter:
    """``_Prefilter(den, h, delay)``, remembered: an iteration builds the same filters for ``y`` and ``u`` (at a
    delay of zero), and its last iterate's again to simulate it (read-only, so shared)."""
    return _prefilter_of(np.asarray(den, dtype=float).tobytes(), float(h), float(delay))


@functools.lru_cache(maxsize=64)
def _prefilter_of(den: bytes, h: float, delay: float) -> _Prefilter:
    made = _Prefilter(np.frombuffer(den), h, delay)
    made.nums.setflags(write=False)
    made.den.setflags(write=False)
    return made


@functools.lru_cache(maxsize=64)
def _sampled_denominator(den: bytes, h: float) -> np.ndarray:
    """The denominator in ``z^-1`` of ``1 / A(p)`` sampled every ``h`` s: the polynomial of the eigenvalues
    ``e^{p_i h}`` of ``Phi = e^{A h}`` (``A``'s coefficients given by their bytes), the same for any delay."""
    out = np.real(np.poly(np.exp(np.roots(np.frombuffer(den)) * h)))
    out.setflags(write=False)
    return out


def _state_numerators(phi: np.ndarray, gamma: np.ndarray, den_z: np.ndarray) -> np.ndarray:
    """Numerators in ``z^-1`` of ``(zI - Phi)^{-1} gamma``, shape (n, n + 1), over ``den_z``.

    Leverrier: ``adj(zI - Phi) = sum_k z^{n-1-k} M_k`` with ``M_0 = I``, ``M_k = Phi M_{k-1} + c_k I``.
    """
    n = phi.shape[0]
    nums = np.zeros((n, n + 1))
    vec = gamma.copy()
    for k in range(n):
        nums[:, k + 1] = vec
        vec = phi @ vec + den_z[k + 1] * gamma
    return nums


def _output(orders: Orders, theta: np.ndarray, states: np.ndarray) -> np.ndarray:
    """``B(p)/A(p) u`` from the prefilter states ``p^{n-1}/A u .. 1/A u`` (state ``n-1-i`` is ``p^i/A``)."""
    b = orders.num(theta)
    first = orders.n - 1 - orders.m  # state of p^m / A
    return np.tensordot(b, states[first : first + orders.m + 1], axes=1)


def _projector(nuisance: np.ndarray) -> np.ndarray:
    """Orthonormal basis of shape (n_steps, q) of the columns of ``nuisance``."""
    basis, sing, _ = np.linalg.svd(nuisance, full_matrices=False)
    return basis[:, sing > sing[0] * 1e-10] if sing[0] > 0 else basis[:, :0]


def _project(q: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """Remove from ``columns`` of shape (..., n_steps) their components along ``q`` of shape (n_steps, r).

    Two matrix products (BLAS) over all the regressors of all records at once.
    """
    flat = columns.reshape(-1, columns.shape[-1])
    return (flat - (flat @ q) @ q.T).reshape(columns.shape)


def _least_squares_instruments(phi: np.ndarray) -> np.ndarray:
    """``zeta = phi`` of least squares, projected once, as its own array: numpy computes ``A @ A.T`` of one
    buffer by a symmetric rank-k update, whose rounding differs from the general product's (it moved the
    ranking of ``benchmarks/bench_diagnose.py``'s backlash case below its best)."""
    return phi.copy()


def _solve(gram: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    scale = 1.0 / np.sqrt(np.maximum(np.abs(np.diag(gram)), 1e-300))
    sol = np.linalg.lstsq(gram * scale[:, None] * scale[None, :], rhs * scale, rcond=None)[0]
    return sol * scale


def _equations(orders: Orders, batches: list[Signals], den: np.ndarray, delay: float, theta_aux, offset: bool,
               free_offsets: bool = False):
    """Accumulate ``sum zeta phi^T`` and ``sum zeta y_f^(n)`` of (S4) over all batches.

    ``theta_aux`` gives the auxiliary model of (S2); ``None`` means least squares (``zeta = phi``).
    """
    n, m, k = orders.n, orders.m, orders.k
    p = orders.n_params
    gram, rhs = np.zeros((p, p)), np.zeros(p)
    for sig in batches:
        fy = _prefilter(den, sig.h, 0.0)
        fu = _prefilter(den, sig.h, delay)
        ys = sig.at_samples(fy.states(sig.y_fine))  # (S1) y_f^{(n-1)} .. y_f^{(0)}
        us_fine = fu.states(sig.u_fine)
        us = sig.at_samples(us_fine)  # (S1) u_f^{(n-1)} .. u_f^{(0)}
        target = sig.y - np.tensordot(den[1:], ys, axes=1)  # y_f^{(n)}
        u_cols = us[n - 1 - m :]  # u_f^{(m)} .. u_f^{(0)}
        phi = np.concatenate([-ys[: n - k], u_cols])  # (S3): one regressor per row, shape (p, n_records, n_steps)
        if theta_aux is None:
            zeta = phi
        else:
            x_hat = _output(orders, theta_aux, us_fine)  # (S2)
            xs = sig.at_samples(fy.states(x_hat))
            zeta = np.concatenate([-xs[: n - k], u_cols])  # (S3)
        if offset and sig.free.any():
            ones = np.ones((1, sig.u_fine.shape[1]))
            if free_offsets:  # any y_0 A(p)/A_f(p) 1 - u_0 B(p)/A_f(p) 1(t - tau)
                s_y = sig.at_samples(fy.states(ones)[:, 0])
                s_u = sig.at_samples(fu.states(ones)[:, 0])
                nuisance = np.column_stack([np.ones(sig.rows.size), *s_y, *s_u[n - 1 - m :]])
            else:  # y_0 and u_0 through the auxiliary model's step response
                step = sig.at_samples(_output(orders, theta_aux, fu.states(ones))[0])
                nuisance = np.column_stack([np.ones(sig.rows.size), step])
            q = _projector(nuisance)
            if sig.free.all():
                phi, target = _project(q, phi), _project(q, target)
                zeta = _least_squares_instruments(phi) if theta_aux is None else _project(q, zeta)
            else:  # the pinned records keep their rest levels: nothing to project out of their rows
                free = sig.free
                phi, target = phi.copy(), target.copy()
                phi[:, free], target[free] = _project(q, phi[:, free]), _project(q, target[free])
                if theta_aux is None:
                    zeta = _least_squares_instruments(phi)
                else:
                    zeta = zeta.copy()
                    zeta[:, free] = _project(q, zeta[:, free])
        zeta_rows = zeta.reshape(p, -1)  # each regressor over the samples of all records
        gram += zeta_rows @ phi.reshape(p, -1).T
        rhs += zeta_rows @ target.ravel()
    return gram, rhs


def stabilised(orders: Orders, theta: np.ndarray) -> np.ndarray:
    """Mirror unstable roots of the free part of ``A`` into the left half plane.

    Parameters
    ----------
    orders : Orders
    theta : ndarray of shape (orders.n_params,)
        ``[a_1 .. a_{n-k}, b_0 .. b_m]``.

    Returns
    -------
    ndarray of shape (orders.n_params,)
        ``theta`` itself when ``A`` is already stable, else a copy whose ``A`` has the
        roots with ``Re >= 0`` mirrored to ``-|Re| - 1e-9``.
    """
    free = np.concatenate([[1.0], theta[: orders.n - orders.k]])
    if free.size == 1:
        return theta
    roots = np.roots(free)
    if np.all(roots.real < 0.0):
        return theta
    roots = np.where(roots.real >= 0.0, -np.abs(roots.real) - 1e-9 + 1j * roots.imag, roots)
    out = theta.copy()
    out[: orders.n - orders.k] = np.real(np.poly(roots))[1:]
    return out


def lssvf(orders: Orders, batches: list[Signals], delay: float, bandwidth: float, offset: bool) -> np.ndarray:
    """Least-squares state-variable-filter estimate, the SRIVC initialisation.

    Solves (S4) with ``zeta_f = phi_f`` and the fixed prefilter ``1 / (p + bandwidth)^n``
    (``bandwidth`` in rad/s); the rest levels enter through free step-response regressors.
    """
    den = np.real(np.poly(np.full(orders.n, -float(bandwidth))))
    gram, rhs = _equations(orders, batches, den, delay, None, offset, free_offsets=True)
    return stabilised(orders, _solve(gram, rhs))


def srivc(orders: Orders, batches: list[Signals], delay: float, theta0: np.ndarray, max_iter: int = 50,
          tol: float = 1e-8, offset: bool = True) -> SrivcResult:
    """Iterate (S1)-(S4) from ``theta0`` at a fixed input delay ``delay`` (s).

    An iterate that is not finite, or whose pole ran off to -infinity so far that its
    prefilter cannot be discretised (the data want fewer poles than the model has), is
    divergence: the result is ``theta0``, not converged.
    """
    theta = stabilised(orders, np.asarray(theta0, dtype=float))
    for it in range(1, max_iter + 1):
        try:
            gram, rhs = _equations(orders, batches, orders.den(theta), delay, theta, offset)
        except FloatingPointError:  # a pole too fast to discretise (_Prefilter)
            return SrivcResult(theta0, it, False)
        new = stabilised(orders, _solve(gram, rhs))
        change = np.linalg.norm(new - theta) / max(np.linalg.norm(new), 1e-300)
        theta = new
        if not np.all(np.isfinite(theta)):
            return SrivcResult(theta0, it, False)
        if change <= tol:
            return _simulatable(SrivcResult(theta, it, True), orders, batches, delay, theta0)
    return _simulatable(SrivcResult(theta, max_iter, False), orders, batches, delay, theta0)


def _simulatable(result: SrivcResult, orders: Orders, batches: list[Signals], delay: float,
                 theta0: np.ndarray) -> SrivcResult:
    """``result``, or divergence (``theta0``) if its last iterate cannot be discretised (see :func:`srivc`)."""
    try:
        for h in {sig.h for sig in batches}:
            _prefilter(orders.den(result.theta), h, delay)
    except FloatingPointError:
        return SrivcResult(theta0, result.n_iter, False)
    return result


def simulate(orders: Orders, theta: np.ndarray, delay: float, sig: Signals, offset: bool):
    """Simulated output ``y0 + B/A u(t - tau) - u0 B/A 1(t - tau)`` at the measured samples.

    With ``offset=True`` the rest levels ``(y0, u0)`` of each record are the
    least-squares fit of the simulation error, except where :attr:`Signals.free` pins them;
    else ``y0 = y[0]``, ``u0 = 0``.

    Returns
    -------
    y_sim : ndarray of shape (n_records, n_steps)
        Simulated output in the units of ``y``.
    y0, u0 : ndarray of shape (n_records,)
        Rest levels used.
    """
    den = orders.den(theta)
    fu = _prefilter(den, sig.h, delay)
    x = sig.at_samples(_output(orders, theta, fu.states(sig.u_fine)))
    if not offset or not sig.free.any():
        return sig.y_ref[:, None] + x, sig.y_ref.copy(), sig.u_ref.copy()
    step = sig.at_samples(_output(orders, theta, fu.states(np.ones((1, sig.u_fine.shape[1]))))[0])
    basis = np.column_stack([np.ones(sig.rows.size), step])
    coef = np.linalg.lstsq(basis, (sig.y - x).T, rcond=None)[0]  # (2, n_records)
    coef[:, ~sig.free] = 0.0  # pinned rest levels
    y_sim = sig.y_ref[:, None] + x + (basis @ coef).T
    return y_sim, sig.y_ref + coef[0], sig.u_ref - coef[1]
