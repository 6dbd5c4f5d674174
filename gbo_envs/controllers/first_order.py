"""The first-order controllers, PI and PDT1, with their gains as a batch.

Each is a continuous-time law ``C(s)`` realised digitally with the Tustin
(bilinear) transform at the loop's sample time, first order in ``z``::

    u[k] = b0 e[k] + b1 e[k-1] - a1 u[k-1]

so one recursion, with coefficients of shape (batch,), simulates a whole batch
of gains at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gbo_envs.controllers.base import Controller, grouped, per

__all__ = ["PDT1Controller", "PIController"]


@dataclass(frozen=True)
class PIController(Controller):
    """PI speed controller of the paper, eq. (Cv): ``C(s) = Kp (1 + Ki / s)``.

    ``Kp`` is in input units per output unit (``(input units)/(rad/s)`` on the
    DC motor, see :meth:`units_for`) and ``Ki`` in 1/s.
    Tustin: ``u[k] = u[k-1] + (Kp + Kp Ki dt/2) e[k] + (-Kp + Kp Ki dt/2) e[k-1]``.
    """

    gain_names: tuple[str, ...] = ("Kp", "Ki")
    gain_units: tuple[str, ...] = ("(input units)/(output units)", "1/s")

    def units_for(self, input_unit: str, output_unit: str) -> tuple[str, ...]:
        """``Kp`` in ``input_unit/output_unit``, ``Ki`` in 1/s."""
        return per(input_unit, output_unit), "1/s"

    def coefficients(self, gains, dt):
        kp, ki = gains[:, 0], gains[:, 1]
        half = kp * ki * dt / 2.0
        return kp + half, -kp + half, -np.ones_like(kp)

    def transfer_function(self, gains):
        kp, ki = float(gains[0]), float(gains[1])
        return [kp, kp * ki], [1.0, 0.0]

    @property
    def has_integrator(self) -> bool:
        return True


@dataclass(frozen=True)
class PDT1Controller(Controller):
    """Industrial PDT1 position controller, paper eq. (LM_Controller).

    ``C(s) = Kp + Kd s / (tf s + 1)`` with ``Kp`` in A/m, ``Kd`` in A s/m and the
    derivative filter time constant ``tf`` in s (0.001 s on the LinMot drive).
    """

    filter_time: float = 0.001
    gain_names: tuple[str, ...] = ("Kp", "Kd")
    gain_units: tuple[str, ...] = ("A/m", "A s/m")

    def units_for(self, input_unit: str, output_unit: str) -> tuple[str, ...]:
        """``Kp`` in ``input_unit/output_unit``, ``Kd`` in ``input_unit s/output_unit`` (A/m, A s/m on the LinMot)."""
        return per(input_unit, output_unit), per(f"{grouped(input_unit)} s", output_unit)

    def coefficients(self, gains, dt):
        kp, kd = gains[:, 0], gains[:, 1]
        tf = self.filter_time
        a1 = (dt - 2.0 * tf) / (2.0 * tf + dt)
        dgain = 2.0 * kd / (2.0 * tf + dt)
        return kp + dgain, kp * a1 - dgain, np.full_like(kp, a1)

    def transfer_function(self, gains):
        kp, kd = float(gains[0]), float(gains[1])
        tf = self.filter_time
        return [kp * tf + kd, kp], [tf, 1.0]


