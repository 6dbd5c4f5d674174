"""Linear controllers of any order: a continuous state space, Tustin at the loop's rate, anti-windup.

A :class:`LinearController` defines its law as a continuous state space with the
inputs ``w = [e, r - r1]`` (the control error and the reference's deviation from
its level at rest) and the output ``u``, for a batch of gains::

    x' = A x + B w,    u = C x + D w.

The loop runs it digitally: the bilinear (Tustin) transform at the sample time
``dt`` (:func:`tustin`, the ``"bilinear"`` method of ``scipy.signal.cont2discrete``)
gives the discrete state space of :class:`~gbo_envs.controllers.base.DiscreteStateSpace`
whose transfer function is ``C(s)`` at ``s = (2 / dt) (z - 1) / (z + 1)``. A
controller may clip its output to ``+-output_limit`` (a drive's current limit);
its integrator states then do not wind up against it (``anti_windup``):

* ``"clamping"`` (conditional integration): an integrator state holds while the
  output is clipped and its update would drive the command further out;
* ``"back-calculation"``: the clipped excess feeds back into the integrator,
  ``I' = ... + (u - v) / T_t`` with the tracking time ``T_t`` in s (Astrom and
  Hagglund, *Advanced PID Control*, Sec. 3.5);
* ``"none"``: the integrator winds up.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from gbo_envs.controllers.base import Controller, DiscreteStateSpace

__all__ = ["ANTI_WINDUP", "LinearController", "tustin"]

#: Values of :attr:`LinearController.anti_windup`.
ANTI_WINDUP = ("clamping", "back-calculation", "none")


def tustin(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, dt: float):
    """Bilinear (Tustin) transform of a batch of continuous state spaces.

    ``Ad = (I - A dt/2)^-1 (I + A dt/2)``, ``Bd = (I - A dt/2)^-1 B dt``,
    ``Cd = C (I - A dt/2)^-1``, ``Dd = D + C Bd / 2`` (``scipy.signal.cont2discrete``,
    ``method="bilinear"``, row by row).

    Parameters
    ----------
    a : ndarray of shape (batch, n, n)
    b : ndarray of shape (batch, n, m)
    c : ndarray of shape (batch, n)
    d : ndarray of shape (batch, m)
    dt : float
        Sample time in s.

    Returns
    -------
    ad, bd, cd, dd : ndarray
        Shapes as the inputs.
    """
    eye = np.eye(a.shape[1])
    ima = eye - a * (dt / 2.0)
    ad = np.linalg.solve(ima, eye + a * (dt / 2.0))
    bd = np.linalg.solve(ima, b * dt)
    cd = np.linalg.solve(np.swapaxes(ima, 1, 2), c[:, :, None])[:, :, 0]
    dd = d + 0.5 * np.einsum("rn,rnm->rm", c, bd)
    return ad, bd, cd, dd


def characteristic_polynomials(m: np.ndarray) -> np.ndarray:
    """``det(z I - M)`` of a batch of square matrices, coefficients of ``z^n .. z^0``, shape (batch, n + 1)."""
    batch, n = m.shape[0], m.shape[1]
    roots = np.linalg.eigvals(m)
    coef = np.zeros((batch, n + 1), dtype=complex)
    coef[:, 0] = 1.0
    for j in range(n):  # times (z - root_j)
        coef[:, 1 : j + 2] = coef[:, 1 : j + 2] - roots[:, j : j + 1] * coef[:, : j + 1]
    return coef.real


@dataclass(frozen=True)
class LinearController(Controller):
    """Base class of a linear controller of any order, given as a continuous state space.

    Subclasses implement :meth:`continuous` and name their integrator states in
    :attr:`integrator_states`.

    Parameters
    ----------
    output_limit : float, optional
        The output is clipped to ``[-output_limit, output_limit]`` in input units
        (``None``: unlimited; the loop is then linear).
    anti_windup : {"clamping", "back-calculation", "none"}, default "clamping"
        How the integrator states behave while the output is clipped (module docstring).
    tracking_time : float, optional
        ``T_t`` of back-calculation in s, ``> 0``; required with ``anti_windup="back-calculation"``.
    """

    output_limit: float | None = None
    anti_windup: str = "clamping"
    tracking_time: float | None = None

    #: Indices of the states that integrate (the anti-windup acts on them).
    integrator_states: ClassVar[tuple[int, ...]] = ()

    def __post_init__(self) -> None:
        if self.output_limit is not None and not (np.isfinite(self.output_limit) and self.output_limit > 0.0):
            raise ValueError(f"output_limit: must be a finite number > 0 (input units) or None, "
                             f"got {self.output_limit}")
        if self.anti_windup not in ANTI_WINDUP:
            raise ValueError(f"anti_windup: must be one of {ANTI_WINDUP}, got {self.anti_windup!r}")
        if self.anti_windup == "back-calculation":
            if self.tracking_time is None or not (np.isfinite(self.tracking_time) and self.tracking_time > 0.0):
                raise ValueError("tracking_time: back-calculation needs a finite tracking time > 0 (s), "
                                 f"got {self.tracking_time}")

    # -- to be defined by a subclass --------------------------------------------------------------------------------
    def continuous(self, gains: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Continuous state space ``(A, B, C, D)`` of shapes (batch, n, n), (batch, n, 2), (batch, n), (batch, 2)
        for gains of shape (batch, n_gains); the inputs are ``[e, r - r1]``."""
        raise NotImplementedError

    # -- derived -----------------------------------------------------------------------------------------------------
    def _gains(self, gains) -> np.ndarray:
        gains = np.atleast_2d(np.asarray(gains, dtype=float))
        if gains.ndim != 2 or gains.shape[1] != len(self.gain_names):
            raise ValueError(f"gains: expected shape (batch, {len(self.gain_names)}) for {self.gain_names}, "
                             f"got {gains.shape}")
        return gains

    def state_space(self, gains: np.ndarray, dt: float) -> DiscreteStateSpace:
        """The Tustin realisation at ``dt`` with the output limit and the anti-windup (see the module docstring)."""
        ad, bd, cd, dd = tustin(*self.continuous(self._gains(gains)), dt)
        n = ad.shape[1]
        injection = np.zeros_like(cd)
        clamp = np.zeros(n, dtype=bool)
        if self.output_limit is not None and self.integrator_states:
            index = list(self.integrator_states)
            if self.anti_windup == "clamping":
                clamp[index] = True
            elif self.anti_windup == "back-calculation":
                # the integral's share of the command, Cd_i x_i, moves by dt / T_t of the clipped excess per sample
                weight = cd[:, index]
                injection[:, index] = np.where(weight != 0.0, dt / (self.tracking_time * np.where(weight != 0.0,
                                                                                                   weight, 1.0)), 0.0)
        limit = np.inf if self.output_limit is None else float(self.output_limit)
        return DiscreteStateSpace(a=ad, b=bd, c=cd, d=dd, injection=injection, clamp=clamp, limit=limit)

    def z_transfer(self, gains: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """:meth:`~gbo_envs.controllers.base.Controller.z_transfer` of the Tustin realisation (its limit aside).

        ``D(z) = det(I - Ad z^-1)`` and ``N_j(z) = det(I - (Ad - Bd_j Cd) z^-1) + (Dd_j - 1) D(z)``
        for the inputs ``j = e, r - r1`` (the determinant identity of a rank-one update).
        """
        law = self.state_space(gains, dt)
        den = characteristic_polynomials(law.a)
        nums = [characteristic_polynomials(law.a - law.b[:, :, j, None] * law.c[:, None, :])
                + (law.d[:, j, None] - 1.0) * den for j in (0, 1)]
        two_dof = bool(np.any(law.b[:, :, 1] != 0.0) or np.any(law.d[:, 1] != 0.0))
        return nums[0], (nums[1] if two_dof else None), den

    def transfer_function(self, gains: np.ndarray) -> tuple[list[float], list[float]]:
        """Continuous feedback law ``C(s) = U(s) / E(s)`` (reference fixed) as ``(num, den)`` for one gain vector."""
        return self._continuous_tf(gains, np.array([1.0, 0.0]))

    def reference_transfer_function(self, gains: np.ndarray) -> tuple[list[float], list[float]]:
        """Continuous law from the reference, ``U(s) / R(s)`` with the output fixed (``e`` and ``r - r1`` both
        move with ``r``), as ``(num, den)`` for one gain vector; equal to :meth:`transfer_function` for a
        one-degree-of-freedom law."""
        return self._continuous_tf(gains, np.array([1.0, 1.0]))

    def _continuous_tf(self, gains, mix: np.ndarray) -> tuple[list[float], list[float]]:
        from scipy.signal import ss2tf  # imported here: scipy.signal takes 0.3 s to import

        a, b, c, d = (part[0] for part in self.continuous(self._gains(gains)[:1]))
        num, den = ss2tf(a, (b @ mix)[:, None], c[None, :], np.atleast_2d(d @ mix))
        return [float(v) for v in np.ravel(num)], [float(v) for v in den]

    @property
    def has_integrator(self) -> bool:
        return bool(self.integrator_states)

    @property
    def has_state_space(self) -> bool:
        return True
