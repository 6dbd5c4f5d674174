"""Friction effects: Coulomb, viscous and static friction (stiction).

Friction is a torque (force) on the mechanics. The plants here are identified
from input (controller units) to output, so each friction is expressed as an
*equivalent input* that opposes the mechanical speed: ``u_applied = u - f``
with ``f`` in input units. The speed is the plant's mechanical speed passed by
the simulator (``y`` for a speed loop, ``dy/dt`` for a position loop), the true
(unmeasured) one at the start of the sample interval; ``f`` is held over the
interval like the input.

What is modelled, and what is not: the friction level switches with the sign
of the sampled speed. At zero speed (exactly, or within ``threshold`` for
stiction) friction balances the drive up to its level (Karnopp's rule), so a
body at rest with a small drive receives no input. Because friction is an
input-equivalent, the plant's own internal dynamics (e.g. a current still
decaying in a second-order motor model) are not stopped by it.
"""

from __future__ import annotations

import numpy as np

from gbo_envs.physics.block import MAGNITUDE_LIMIT, EffectBlock, EffectParameter

__all__ = ["CoulombFriction", "Stiction", "ViscousFriction"]

_MAX = MAGNITUDE_LIMIT


class CoulombFriction(EffectBlock):
    """Coulomb (dry, kinetic) friction of constant level opposing the motion, possibly unequal in the two directions.

    The level is ``torque (1 + asymmetry)`` for positive speed and ``torque (1 - asymmetry)``
    for negative speed. ``f = level * sign(speed)`` for ``speed != 0``; at ``speed == 0``
    ``f = clip(u, -torque (1 - asymmetry), torque (1 + asymmetry))`` (friction balances a
    drive below the level, so a body at rest stays at rest: Karnopp). With
    ``smoothing > 0`` the sign is replaced by the ramp ``clip(speed / smoothing, -1, 1)``
    times the level of the speed's sign (no chattering around zero speed, but a body at
    rest creeps under any drive). Real drives often break away at different levels in the
    two directions (seals, preload, a load on an inclined axis); ``asymmetry = 0`` is the
    textbook symmetric friction.

    Parameters
    ----------
    torque : float
        Friction level as an equivalent input, in input units, ``>= 0`` (0: none).
    smoothing : float, default 0.0
        Speed below which friction ramps linearly, in speed units, ``>= 0``.
    asymmetry : float, default 0.0
        Relative difference of the levels in the two directions, in ``[-1, 1]`` (0: equal;
        0.2: 1.2 torque forwards, 0.8 torque backwards).
    """

    name = "coulomb_friction"
    side = "actuator"
    parameters = (
        EffectParameter("torque", "input units", 0.0, _MAX, None, 0.0,
                        "friction level as an equivalent input opposing the speed"),
        EffectParameter("smoothing", "speed units", 0.0, _MAX, 0.0, float("nan"),
                        "speed below which the friction ramps linearly (0: sign)"),
        EffectParameter("asymmetry", "1", -1.0, 1.0, 0.0, float("nan"),
                        "relative difference of the levels: torque (1 + a) forwards, torque (1 - a) backwards"),
    )
    magnitude_param = "torque"

    def __init__(self, torque: float, smoothing: float = 0.0, asymmetry: float = 0.0) -> None:
        self._set_params(torque=torque, smoothing=smoothing, asymmetry=asymmetry)

    def _levels(self) -> tuple:
        """Friction levels for positive and for negative speed, in input units."""
        return self.torque * (1.0 + self.asymmetry), self.torque * (1.0 - self.asymmetry)

    def friction(self, u: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Friction ``f`` of shape (batch,) in input units for drive ``u`` at ``speed``."""
        forwards, backwards = self._levels()
        level = np.where(speed > 0.0, forwards, backwards)
        if self.smoothing > 0.0:
            # the ramp clip(speed / smoothing, -1, 1), clipped before the division: the same values, and no
            # overflow (a RuntimeWarning) where a tiny smoothing puts |speed| / smoothing beyond double range
            return level * (np.clip(speed, -self.smoothing, self.smoothing) / self.smoothing)
        moving = level * np.sign(speed)
        held = np.minimum(np.maximum(u, -backwards), forwards)
        return np.where(speed == 0.0, held, moving)

    def command_for(self, u_applied, speed):
        if self.smoothing > 0.0:
            return u_applied + self.friction(u_applied, speed)
        forwards, backwards = self._levels()
        direction = np.where(speed == 0.0, np.sign(u_applied), np.sign(speed))  # of the motion the drive holds
        return u_applied + np.where(direction > 0.0, forwards, backwards) * direction

    def actuate(self, u, speed):
        return u - self.friction(u, speed)


class ViscousFriction(EffectBlock):
    """Viscous friction proportional to the speed (bearing drag, damping).

    ``f = coefficient * speed``.

    Parameters
    ----------
    coefficient : float
        Input units per speed unit, ``>= 0`` (0: none). For a position loop in
        m and A, e.g. A per (m/s).
    """

    name = "viscous_friction"
    side = "actuator"
    parameters = (EffectParameter("coefficient", "input units per speed unit", 0.0, _MAX, None, 0.0,
                                  "equivalent input per unit of speed"),)
    magnitude_param = "coefficient"

    def __init__(self, coefficient: float) -> None:
        self._set_params(coefficient=coefficient)
        if not np.isfinite(self.coefficient):
            raise ValueError(f"viscous_friction: parameter 'coefficient' must be finite, got {self.coefficient}")

    def command_for(self, u_applied, speed):
        return u_applied + self.coefficient * speed

    def actuate(self, u, speed):
        return u - self.coefficient * speed


class Stiction(EffectBlock):
    """Static friction: holds the body at rest until the drive exceeds the breakaway level.

    At rest (``|speed| <= threshold``) ``f = clip(u, -breakaway, breakaway)``,
    so a drive below breakaway applies nothing and one above it applies only
    its excess; once moving, this block adds no friction (combine it with
    ``coulomb_friction`` for the sliding level; at rest the two then add, so
    the total breakaway is ``breakaway + torque``). The drop from the static
    level to the sliding level on breakaway gives stick-slip.

    Parameters
    ----------
    breakaway : float
        Static friction level as an equivalent input, in input units, ``>= 0`` (0: none).
    threshold : float, default 0.0
        Speed at or below which the body counts as at rest, in speed units,
        ``>= 0``; 0 means exactly at rest (the sampled speed rarely returns to
        exactly 0, so raise it for sticking on speed reversals).
    """

    name = "stiction"
    side = "actuator"
    parameters = (
        EffectParameter("breakaway", "input units", 0.0, _MAX, None, 0.0,
                        "static friction level as an equivalent input"),
        EffectParameter("threshold", "speed units", 0.0, _MAX, 0.0, float("nan"),
                        "speed at or below which the body counts as at rest"),
    )
    magnitude_param = "breakaway"

    def __init__(self, breakaway: float, threshold: float = 0.0) -> None:
        self._set_params(breakaway=breakaway, threshold=threshold)

    def command_for(self, u_applied, speed):
        at_rest = np.abs(speed) <= self.threshold
        return u_applied + np.where(at_rest, self.breakaway * np.sign(u_applied), 0.0)

    def actuate(self, u, speed):
        at_rest = np.abs(speed) <= self.threshold
        return u - np.where(at_rest, np.clip(u, -self.breakaway, self.breakaway), 0.0)
