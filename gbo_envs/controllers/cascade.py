"""Cascaded position -> speed controller, as servo drives run it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from gbo_envs.controllers.base import per
from gbo_envs.controllers.state_space import LinearController

__all__ = ["CascadeController"]


@dataclass(frozen=True)
class CascadeController(LinearController):
    """Position P loop around a speed PI loop, with velocity feed-forward; the speed estimated from the position.

    The drive measures only the position ``y``. Its speed estimate is the
    filtered difference of the position samples, the Tustin form of
    ``s / (Tv s + 1)``::

        v_hat[k] = a v_hat[k-1] + (1 - a) (y[k] - y[k-1]) / dt,    a = (2 Tv - dt) / (2 Tv + dt)

    (:meth:`speed_estimate`), a first-order low-pass of time constant ``Tv`` on
    the difference quotient. The same filter of the reference gives the
    reference speed ``v_r``. Then::

        v_ref = Kv (r - y) + Kff v_r              position P with velocity feed-forward
        e_v   = v_ref - v_hat                     speed error
        u     = Kp (e_v + Ki int e_v dt)          speed PI, the paper's form of eq. (Cv)

    with ``Kv`` in 1/s, ``Kp`` in input units per (output unit/s) (A/(m/s) on a
    linear motor), ``Ki`` in 1/s and ``Kff`` dimensionless (0: none, 1: the whole
    reference speed). ``u`` (the current command) is clipped to
    ``+-output_limit`` and the speed integrator does not wind up against it
    (``anti_windup``). The feedback law, from the position error with the
    reference held, is ``C(s) = Kp (1 + Ki / s) (Kv + s / (Tv s + 1))``; ``Kff``
    shapes only the response to the reference, not the stability margins.

    State space: with the inputs ``[e, r - r1]`` the position deviation is
    ``(r - r1) - e``; the states are its low-pass ``x_f``, the low-pass of the
    reference ``x_r`` and the speed integral ``x_i``::

        x_f' = ((r - r1) - e - x_f) / Tv,    x_r' = ((r - r1) - x_r) / Tv,    x_i' = e_v,
        v_hat = ((r - r1) - e - x_f) / Tv,   v_r = ((r - r1) - x_r) / Tv.

    Parameters
    ----------
    speed_filter_time : float, default 0.001
        ``Tv`` in s, ``> 0``.
    feedforward : bool, default True
        Whether ``Kff`` is a gain; ``False``: three gains ``(Kv, Kp, Ki)`` and no feed-forward.
    output_limit, anti_windup, tracking_time
        See :class:`~gbo_envs.controllers.state_space.LinearController`.
    """

    speed_filter_time: float = 0.001
    reference_filter_time: float | None = 0.01
    feedforward: bool = True
    gain_names: tuple[str, ...] = ("Kv", "Kp", "Ki", "Kff")
    gain_units: tuple[str, ...] = ("1/s", "(input units)/((output units)/s)", "1/s", "1")

    integrator_states: ClassVar[tuple[int, ...]] = (2,)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (np.isfinite(self.speed_filter_time) and self.speed_filter_time > 0.0):
            raise ValueError(f"speed_filter_time: must be a finite number > 0 (s), got {self.speed_filter_time}")
        shaping = self.reference_filter_time
        if shaping is not None and not (np.isfinite(shaping) and shaping > 0.0):
            raise ValueError(f"reference_filter_time: must be a finite number > 0 (s) or None, got {shaping}")
        if not self.feedforward:
            object.__setattr__(self, "gain_names", self.gain_names[:3])
            object.__setattr__(self, "gain_units", self.gain_units[:3])

    def units_for(self, input_unit: str, output_unit: str) -> tuple[str, ...]:
        """``Kv`` in 1/s, ``Kp`` in ``input/(output/s)`` (A/(m/s)), ``Ki`` in 1/s, ``Kff`` dimensionless."""
        units = ("1/s", per(input_unit, f"{output_unit}/s"), "1/s", "1")
        return units if self.feedforward else units[:3]

    def continuous(self, gains):
        gains = self._gains(gains)
        kv, kp, ki = gains[:, 0], gains[:, 1], gains[:, 2]
        kff = gains[:, 3] if self.feedforward else np.zeros_like(kv)
        rate = 1.0 / self.speed_filter_time
        shaped = self.reference_filter_time is not None
        # the second state: the setpoint filter (r_f = x_2), or the reference's speed filter (r_f = r)
        rate2 = 1.0 / self.reference_filter_time if shaped else rate
        pf = 1.0 if shaped else 0.0
        # e_v = Kv (r_f - y) + Kff r_f' - v_hat
        #     = (Kv + 1/Tv) e + (Kff rate2 - pf Kv - 1/Tv) (r - r1) + (pf Kv - Kff rate2) x_2 + x_f / Tv
        on_e, on_r, on_x2 = kv + rate, kff * rate2 - pf * kv - rate, pf * kv - kff * rate2
        batch = kv.size
        a = np.zeros((batch, 3, 3))
        a[:, 0, 0] = -rate
        a[:, 1, 1] = -rate2
        a[:, 2, 0] = rate
        a[:, 2, 1] = on_x2
        b = np.zeros((batch, 3, 2))
        b[:, 0] = [-rate, rate]
        b[:, 1, 1] = rate2
        b[:, 2, 0] = on_e
        b[:, 2, 1] = on_r
        c = np.stack([kp * rate, kp * on_x2, kp * ki], axis=1)
        d = np.stack([kp * on_e, kp * on_r], axis=1)
        return a, b, c, d

    def speed_estimate(self, y, dt: float) -> np.ndarray:
        """The drive's speed estimate from recorded positions ``y`` (output units), in output units/s.

        Parameters
        ----------
        y : array_like of shape (..., n_steps)
            Measured positions, the loop at rest before the first sample.
        dt : float
            Sample time in s.
        """
        from scipy.signal import lfilter

        y = np.asarray(y, dtype=float)
        a = (2.0 * self.speed_filter_time - dt) / (2.0 * self.speed_filter_time + dt)
        step = np.diff(y, axis=-1, prepend=y[..., :1]) / dt
        return lfilter([1.0 - a], [1.0, -a], step, axis=-1)
