"""Continuous-time LTI plants and their exact zero-order-hold discretisation.

A plant is a strictly proper SISO transfer function with an input delay,
``G(s) = num(s) / den(s) * exp(-s * delay)``. It is sampled *exactly*: the
input is held constant between samples (zero-order hold, as a DAC does) and the
delay, integer and fractional part, is folded into the discrete model, so no
integration error enters the closed-loop simulation.
"""

from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm

__all__ = ["ContinuousPlant", "DiscretePlant"]


def _floats(values) -> tuple[float, ...]:
    """``values`` as a tuple of floats (at least one); a tuple of floats as it is (a plant is built for
    every parameter set a fit simulates, so the common case skips numpy)."""
    if isinstance(values, tuple) and values and all(type(c) is float for c in values):
        return values
    return tuple(float(c) for c in np.atleast_1d(values))


@dataclass(frozen=True)
class ContinuousPlant:
    """Strictly proper SISO transfer function with an input delay.

    Parameters
    ----------
    num : sequence of float
        Numerator coefficients of ``G(s)``, highest power first.
    den : sequence of float
        Denominator coefficients of ``G(s)``, highest power first; its degree
        must exceed the numerator's.
    delay : float, default 0.0
        Input (dead-time) delay in s, ``>= 0``.
    output : {"speed", "position"}, default "speed"
        What the output measures; friction-like effects act against the
        mechanical speed, which is ``y`` for a speed loop and ``dy/dt`` for a
        position loop.

    Examples
    --------
    The paper's identified DC motor, Table I: ``G(s) = 9.544 / (s^2 + 4.145 s
    + 4.199) e^{-0.002 s}`` (output rad/s, input controller units)

    >>> ContinuousPlant(num=(9.544,), den=(1.0, 4.145, 4.199), delay=0.002)
    ContinuousPlant(num=(9.544,), den=(1.0, 4.145, 4.199), delay=0.002, output='speed')
    """

    num: tuple[float, ...]
    den: tuple[float, ...]
    delay: float = 0.0
    output: str = "speed"

    def __post_init__(self) -> None:
        if self.output not in ("speed", "position"):
            raise ValueError(f"output: must be 'speed' or 'position', got {self.output!r}")
        num, den = _floats(self.num), _floats(self.den)
        n_leading_zeros = next((i for i, c in enumerate(num) if c != 0.0), len(num))
        if len(den) == 0 or den[0] == 0.0:
            raise ValueError(f"den: leading coefficient must be non-zero, got {den}")
        if not all(map(math.isfinite, num)) or not all(map(math.isfinite, den)):
            raise ValueError(f"num/den must be finite, got num={num}, den={den}")
        if len(num) - n_leading_zeros >= len(den):
            raise ValueError(
                f"num/den: the plant must be strictly proper (deg num < deg den), "
                f"got deg num = {len(num) - n_leading_zeros - 1}, deg den = {len(den) - 1}"
            )
        if not np.isfinite(self.delay) or self.delay < 0.0:
            raise ValueError(f"delay: must be a finite number of seconds >= 0, got {self.delay}")
        object.__setattr__(self, "num", num)
        object.__setattr__(self, "den", den)
        object.__setattr__(self, "delay", float(self.delay))

    @property
    def order(self) -> int:
        """Number of poles."""
        return len(self.den) - 1

    @property
    def dc_gain(self) -> float:
        """Static gain ``G(0)``; ``inf`` for an integrating plant."""
        return self.num[-1] / self.den[-1] if self.den[-1] != 0.0 else np.inf

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Controllable-canonical ``(A, B, C)`` with ``A`` of shape (n, n), ``B`` and ``C`` of shape (n,).

        ``scipy.signal.tf2ss``'s realisation, its arithmetic done directly (5x faster: it is
        built for every plant a fit simulates); a numerator whose leading coefficient
        ``tf2ss`` would trim (``<= 1e-14`` after normalising) goes to ``tf2ss`` itself.
        """
        den = np.array(self.den) / self.den[0]
        num = np.array(self.num) / self.den[0]
        if num.size == 0 or abs(num[0]) <= 1e-14:
            # tf2ss trims the (near-)zero leading coefficient, as wanted, and says so with BadCoefficients; a
            # model of zero gain is one (a twin fitted to records whose drive saturated throughout: no input
            # reached the plant), and the warning reached guided BO's user
            from scipy.signal import BadCoefficients, tf2ss  # rare: scipy.signal takes 0.3 s to import

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", BadCoefficients)
                a, b, c, _ = tf2ss(self.num, self.den)
            return a, b[:, 0], c[0]
        k = den.size
        padded = np.zeros(k)
        padded[k - num.size :] = num
        a = np.zeros((k - 1, k - 1))
        a[0] = -den[1:]
        a[1:, :-1] = np.eye(k - 2)
        b = np.zeros(k - 1)
        b[0] = 1.0
        return a, b, padded[1:] - padded[0] * den[1:]

    def discretize(self, dt: float) -> DiscretePlant:
        """Exact zero-order-hold discretisation with the delay folded in.

        Writing the delay as ``d * dt + f`` with ``0 <= f < dt``, the input is
        ``u[k-d-1]`` on ``[t_k, t_k + f)`` and ``u[k-d]`` on ``[t_k + f, t_{k+1})``,
        so that ``x[k+1] = Phi x[k] + Gamma0 u[k-d] + Gamma1 u[k-d-1]`` with
        ``Phi = e^{A dt}``, ``Gamma0 = int_0^{dt-f} e^{As} ds B`` and
        ``Gamma1 = e^{A (dt-f)} int_0^f e^{As} ds B``.

        Parameters
        ----------
        dt : float
            Sample time in s, ``> 0``.
        """
        if not np.isfinite(dt) or dt <= 0.0:
            raise ValueError(f"dt: sample time must be > 0 s, got {dt}")
        a, b, c = self.state_space()
        whole = int(np.floor(self.delay / dt + 1e-9))
        frac = self.delay - whole * dt
        if frac < 1e-12 * max(dt, 1.0):
            frac = 0.0
        phi, int_full = _zoh_blocks(a, b, dt - frac)
        gamma0 = int_full
        if frac > 0.0:
            phi_frac, int_frac = _zoh_blocks(a, b, frac)
            gamma1 = phi @ int_frac
            phi = phi @ phi_frac
        else:
            gamma1 = np.zeros_like(gamma0)
        return DiscretePlant(phi=phi, gamma0=gamma0, gamma1=gamma1, c=c, delay_steps=whole, dt=dt,
                             a=a, b=b)


def _zoh_blocks(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(e^{A h}, int_0^h e^{As} ds B)`` from one augmented matrix exponential.

    Remembered by value (:func:`_zoh_blocks_of`): the exponential depends on the denominator and the delay
    only, and a fit asks for it again with every numerator it tries (a Jacobian's numerator columns, each
    experiment of a drifting gain), the same numbers each time.
    """
    return _zoh_blocks_of(a.tobytes(), b.tobytes(), a.shape[0], float(h))


@functools.lru_cache(maxsize=4096)
def _zoh_blocks_of(a: bytes, b: bytes, n: int, h: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_zoh_blocks` of ``A`` and ``B`` given by their bytes (``n`` states); the arrays are read-only."""
    aug = np.zeros((n + 1, n + 1))
    aug[:n, :n] = np.frombuffer(a).reshape(n, n) * h
    aug[:n, n] = np.frombuffer(b) * h
    e = expm(aug)
    phi, integral = e[:n, :n], e[:n, n]
    phi.setflags(write=False)
    integral.setflags(write=False)
    return phi, integral


@dataclass(frozen=True, eq=False)
class DiscretePlant:
    """Exact sampled model ``x[k+1] = phi x[k] + gamma0 u[k-d] + gamma1 u[k-d-1]``, ``y[k] = c x[k]``.

    Built by :meth:`ContinuousPlant.discretize`; ``a`` and ``b`` keep the
    continuous model for equilibrium computations.
    """

    phi: np.ndarray
    gamma0: np.ndarray
    gamma1: np.ndarray
    c: np.ndarray
    delay_steps: int
    dt: float
    a: np.ndarray = field(repr=False)
    b: np.ndarray = field(repr=False)

    @property
    def order(self) -> int:
        """Number of states."""
        return self.phi.shape[0]

    def equilibrium(self, y_level: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """State and constant input that hold the output at ``y_level``.

        Solves ``A x + B u = 0``, ``C x = y`` (minimum-norm solution, so that an
        integrating plant rests with zero input).

        Returns
        -------
        x : ndarray of shape (n, batch)
        u : ndarray of shape (batch,)
        """
        y_level = np.atleast_1d(np.asarray(y_level, dtype=float))
        n = self.order
        m = np.zeros((n + 1, n + 1))
        m[:n, :n] = self.a
        m[:n, n] = self.b
        m[n, :n] = self.c
        rhs = np.zeros((n + 1, y_level.size))
        rhs[n] = y_level
        sol = np.linalg.lstsq(m, rhs, rcond=None)[0]
        return sol[:n], sol[n]

    def transfer_function(self) -> tuple[np.ndarray, np.ndarray]:
        """Sampled plant ``P(z) = z^-d c (zI - Phi)^-1 (Gamma0 + Gamma1 z^-1)`` as ``(num, den)`` in ``z^-1``.

        Returns
        -------
        num : ndarray
            Numerator coefficients of ``z^0, z^-1, ...`` (the delay shows as leading zeros).
        den : ndarray of shape (order + 1,)
            Denominator coefficients of ``z^0, z^-1, ...``.
        """
        from scipy.signal import BadCoefficients, ss2tf  # imported here: scipy.signal takes 0.3 s to import

        with warnings.catch_warnings():  # a zero leading numerator coefficient is expected (strictly proper)
            warnings.simplefilter("ignore", BadCoefficients)
            n0, den = ss2tf(self.phi, self.gamma0[:, None], self.c[None, :], np.zeros((1, 1)))
            n1, _ = ss2tf(self.phi, self.gamma1[:, None], self.c[None, :], np.zeros((1, 1)))
        d = self.delay_steps
        num = np.zeros(d + 2 + n0.shape[1])
        num[d : d + n0.shape[1]] += n0[0]
        num[d + 1 : d + 1 + n1.shape[1]] += n1[0]
        return np.trim_zeros(num, "b"), np.ravel(den)

    def velocity_row(self) -> np.ndarray:
        """Row ``c A`` such that ``dy/dt = (c A) x`` (valid for relative degree >= 2)."""
        return self.c @ self.a
