"""PID controller with a first-order derivative filter."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from gbo_envs.controllers.base import grouped, per
from gbo_envs.controllers.state_space import LinearController

__all__ = ["PIDController"]


@dataclass(frozen=True)
class PIDController(LinearController):
    """PID in parallel form with a first-order filter on the derivative term.

    ``C(s) = Kp + Ki / s + Kd s / (Tf s + 1)``

    with ``Kp`` in input units per output unit, ``Ki`` in input units per
    (output unit s), ``Kd`` in input unit s per output unit (see :meth:`units_for`)
    and the filter time constant ``Tf`` in s. The paper's PI ``Kp (1 + Ki / s)``
    (eq. Cv) is this law with ``Kd = 0`` and ``Ki`` (parallel) ``= Kp Ki`` (paper).

    State space (inputs ``[e, r - r1]``; states: the integral of ``e`` and the
    filter state ``x_d``, low-pass of ``e``)::

        x_i' = e,    x_d' = (e - x_d) / Tf,    u = Kp e + Ki x_i + Kd (e - x_d) / Tf,

    run with Tustin at the loop's sample time; the anti-windup acts on ``x_i``.

    Parameters
    ----------
    filter_time : float or None, default 0.01
        ``Tf`` in s, ``> 0``; ``None`` makes it a fourth gain ``Tf``.
    output_limit, anti_windup, tracking_time
        See :class:`~gbo_envs.controllers.state_space.LinearController`.
    """

    filter_time: float | None = 0.01
    gain_names: tuple[str, ...] = ("Kp", "Ki", "Kd")
    gain_units: tuple[str, ...] = ("(input units)/(output units)", "(input units)/((output units) s)",
                                   "(input units) s/(output units)")

    integrator_states: ClassVar[tuple[int, ...]] = (0,)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.filter_time is None:
            object.__setattr__(self, "gain_names", ("Kp", "Ki", "Kd", "Tf"))
            object.__setattr__(self, "gain_units", (*self.gain_units[:3], "s"))
        elif not (np.isfinite(self.filter_time) and self.filter_time > 0.0):
            raise ValueError(f"filter_time: must be a finite number > 0 (s) or None (a gain), got {self.filter_time}")

    def units_for(self, input_unit: str, output_unit: str) -> tuple[str, ...]:
        """``Kp`` in ``input/output``, ``Ki`` in ``input/(output s)``, ``Kd`` in ``input s/output`` (``Tf`` in s)."""
        units = (per(input_unit, output_unit), per(input_unit, f"{grouped(output_unit)} s"),
                 per(f"{grouped(input_unit)} s", output_unit))
        return units if self.filter_time is not None else (*units, "s")

    def continuous(self, gains):
        gains = self._gains(gains)
        kp, ki, kd = gains[:, 0], gains[:, 1], gains[:, 2]
        tf = gains[:, 3] if self.filter_time is None else np.full_like(kp, self.filter_time)
        if np.any(~(tf > 0.0)):
            raise ValueError(f"Tf: the derivative filter time must be > 0 s, got {tf[~(tf > 0.0)][0]}")
        batch = kp.size
        a = np.zeros((batch, 2, 2))
        a[:, 1, 1] = -1.0 / tf
        b = np.zeros((batch, 2, 2))
        b[:, 0, 0] = 1.0
        b[:, 1, 0] = 1.0 / tf
        c = np.stack([ki, -kd / tf], axis=1)
        d = np.zeros((batch, 2))
        d[:, 0] = kp + kd / tf
        return a, b, c, d
