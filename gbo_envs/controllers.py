"""Digital controllers with their gains as a batch.

Each controller is a continuous-time law ``C(s)`` realised digitally with the
Tustin (bilinear) transform at the loop's sample time, as a real-time target
runs it. All our controllers are first order in ``z``::

    u[k] = b0 e[k] + b1 e[k-1] - a1 u[k-1]

so one recursion, with coefficients of shape (batch,), simulates a whole batch
of gains at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Controller", "PIController", "PDT1Controller", "CONTROLLERS"]


@dataclass(frozen=True)
class Controller:
    """Base class: a controller with named gains and a Tustin first-order realisation."""

    gain_names: tuple[str, ...] = ()
    gain_units: tuple[str, ...] = ()

    def coefficients(self, gains: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return ``(b0, b1, a1)`` of shape (batch,) for gains of shape (batch, n_gains)."""
        raise NotImplementedError

    def units_for(self, input_unit: str, output_unit: str) -> tuple[str, ...]:
        """Units of the gains in a loop whose plant input is in ``input_unit`` and output in ``output_unit``.

        The base class knows no law, so it returns :attr:`gain_units`.

        Parameters
        ----------
        input_unit : str
            Unit of the controller's output, the plant input ``u`` (e.g. ``"A"``).
        output_unit : str
            Unit of the measured output ``y`` and of the control error (e.g. ``"rad/s"``).
        """
        return tuple(self.gain_units)

    def transfer_function(self, gains: np.ndarray) -> tuple[list[float], list[float]]:
        """Continuous ``C(s)`` as ``(num, den)`` for one gain vector (for analysis)."""
        raise NotImplementedError

    @property
    def has_integrator(self) -> bool:
        """Whether ``C(s)`` has a pole at ``s = 0``."""
        return False


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
        return _per(input_unit, output_unit), "1/s"

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
        return _per(input_unit, output_unit), _per(f"{_grouped(input_unit)} s", output_unit)

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


def _grouped(unit: str) -> str:
    """``unit`` in parentheses when it is a quotient or a phrase (``rad/s``, ``input units``), else as given."""
    return f"({unit})" if "/" in unit or " " in unit else unit


def _per(numerator: str, denominator: str) -> str:
    """``numerator/denominator`` with parentheses where a reader needs them: ``(input units)/(rad/s)``, ``A/m``."""
    top = f"({numerator})" if "/" in numerator or numerator.endswith("units") else numerator
    return f"{top}/{_grouped(denominator)}"


CONTROLLERS = {"PI": PIController, "PDT1": PDT1Controller}
