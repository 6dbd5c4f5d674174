"""Actuator-path effects: saturation, dead zone, backlash, offset and cogging.

All act on the commanded plant input ``u`` (in the plant's input units, the
controller output) after the loop's input delay, once per sample; the plant
holds their output for the sample interval (zero-order hold).
"""

from __future__ import annotations

import numpy as np

from gbo_envs.physics.block import MAGNITUDE_LIMIT, EffectBlock, EffectParameter, RowNoise

__all__ = ["Backlash", "Cogging", "DeadZone", "Offset", "Saturation"]

_INF = float("inf")
_MAX = MAGNITUDE_LIMIT


class Saturation(EffectBlock):
    """Symmetric input limit (drive current or voltage limit).

    ``u_applied = clip(u, -limit, limit)``.

    Parameters
    ----------
    limit : float
        Largest input magnitude the actuator delivers, in input units, in
        ``[0, inf]``; ``inf`` (zero magnitude) means no limit.

    Notes
    -----
    The experiment starts at rest, so the input that holds the plant at ``r1``
    must lie within the limit; otherwise :meth:`command_for` raises
    ``ValueError``.
    """

    name = "saturation"
    side = "actuator"
    parameters = (EffectParameter("limit", "input units", 0.0, _MAX, None, _INF,
                                  "largest input magnitude the actuator delivers"),)
    magnitude_param = "limit"

    def __init__(self, limit: float) -> None:
        self._set_params(limit=limit)

    def command_for(self, u_applied, speed):
        if np.any(np.abs(u_applied) > self.limit):
            worst = float(np.max(np.abs(u_applied)))
            raise ValueError(f"saturation: parameter 'limit' = {self.limit:g} input units is below the input "
                             f"{worst:g} that holds the plant at rest at r1; allowed: limit >= {worst:g}")
        return u_applied

    def actuate(self, u, speed):
        return np.minimum(np.maximum(u, -self.limit), self.limit)  # np.clip, at half the call overhead


class DeadZone(EffectBlock):
    """Symmetric dead band around zero input (amplifier or valve dead zone).

    ``u_applied = 0`` for ``|u| <= width / 2``, else ``u - sign(u) width / 2``.

    Parameters
    ----------
    width : float
        Total width of the band in input units, ``>= 0`` (0: no dead zone).
    """

    name = "dead_zone"
    side = "actuator"
    parameters = (EffectParameter("width", "input units", 0.0, _MAX, None, 0.0,
                                  "total width of the band of inputs that produce nothing"),)
    magnitude_param = "width"

    def __init__(self, width: float) -> None:
        self._set_params(width=width)

    def command_for(self, u_applied, speed):
        return u_applied + np.sign(u_applied) * (self.width / 2.0)

    def actuate(self, u, speed):
        half = self.width / 2.0
        return u - np.clip(u, -half, half)


class Backlash(EffectBlock):
    """Backlash (play) between the drive and the load, as a hysteresis on the input path.

    The play operator: the transmitted input ``v`` follows ``u`` only once
    the gap is taken up, ``v[k] = clip(v[k-1], u[k] - width/2, u[k] + width/2)``;
    reversing ``u`` leaves ``v`` unchanged until ``u`` has travelled ``width``.

    Parameters
    ----------
    width : float
        Total play in input units, ``>= 0`` (0: rigid transmission).

    Notes
    -----
    At rest the drive pushes the load (the gap is closed on the side of the
    holding input), so the commanded input at rest is
    ``u_applied + sign(u_applied) width / 2``.
    """

    name = "backlash"
    side = "actuator"
    parameters = (EffectParameter("width", "input units", 0.0, _MAX, None, 0.0,
                                  "total play the input travels on reversal before the load follows"),)
    magnitude_param = "width"

    def __init__(self, width: float) -> None:
        self._set_params(width=width)
        self._state = np.zeros(0)

    def reset(self, batch, rng, dt, draws=None):
        self._state = np.zeros(batch)

    @property
    def transmitted(self) -> np.ndarray:
        """Shape (batch,): the transmitted input ``v`` of each row now (the play operator's state), in input units."""
        return self._state

    def command_for(self, u_applied, speed):
        self._state = np.array(u_applied, dtype=float, copy=True)
        return u_applied + np.sign(u_applied) * (self.width / 2.0)

    def actuate(self, u, speed):
        half = self.width / 2.0
        self._state = np.minimum(np.maximum(self._state, u - half), u + half)  # np.clip, at half the call overhead
        return self._state


class Offset(EffectBlock):
    """Constant bias on the actuator (default) or on the sensor.

    ``on = "actuator"``: ``u_applied = u + value`` (amplifier/DAC offset, or a
    constant load expressed as an input); the integrating controller absorbs
    it, so it shows in the recorded command ``u`` (shifted by ``-value`` at
    rest) and through any nonlinearity downstream.
    ``on = "sensor"``: ``y_measured = y + value`` (sensor bias); the loop
    regulates the *measured* output, so the true output rests ``value`` below it.

    Parameters
    ----------
    value : float
        The bias in input units (actuator) or output units (sensor); 0: none.
    on : {"actuator", "sensor"}, default "actuator"
        Where the bias acts.
    """

    name = "offset"
    parameters = (EffectParameter("value", "input units (on='actuator') or output units (on='sensor')",
                                  -_MAX, _MAX, None, 0.0, "constant bias"),)
    options = {"on": ("actuator", "sensor")}
    magnitude_param = "value"

    def __init__(self, value: float, on: str = "actuator") -> None:
        self._set_params(value=value)
        self.on = self._check_option("on", on)
        self.side = on
        if not np.isfinite(self.value):
            raise ValueError(f"offset: parameter 'value' must be finite, got {self.value}")

    def command_for(self, u_applied, speed):
        return u_applied - self.value

    def actuate(self, u, speed):
        return u + self.value

    def level_for(self, y_measured):
        return y_measured - self.value

    def measure(self, y):
        return y + self.value


class Cogging(EffectBlock):
    """Cogging (detent) ripple: an input disturbance periodic in the rotor or slider position.

    ``u_applied = u + amplitude sin(2 pi theta / period + phase)``, averaged
    over the sample interval: with the position ``theta[k]`` at the start of
    the interval and ``d = speed[k] dt`` travelled during it, the plant gets
    ``amplitude sin(a + b / 2) sinc(b / (2 pi))`` with ``a = 2 pi theta[k] / period + phase``,
    ``b = 2 pi d / period`` and ``sinc(x) = sin(pi x) / (pi x)`` (the plain sine at ``d = 0``).
    This is the mean ripple the plant integrates under the zero-order hold,
    so a fast motor whose ripple is faster than the sampling sees it
    attenuated, not aliased.

    The position is the integral of the mechanical speed (rectangle rule,
    ``theta[k+1] = theta[k] + speed[k] dt``): for a speed loop it is the rotor
    angle (rad when the speed is in rad/s), for a position loop the travel
    since the start. Where it starts:

    * the mechanism rests at the start (a position loop, a speed loop from
      standstill): ``theta = 0``, the same rest position in every experiment;
    * it moves at the start (a speed loop at ``r1 != 0``) and ``synchronised`` is
      False: ``theta`` is uniform over one ripple period, drawn per experiment; in an
      env's expected cost over ``K`` noise draws (:class:`~gbo_envs.physics.block.RowNoise`),
      draw ``j`` starts in the ``j``-th ``K``-th of the period (stratified).
      A step triggered by a clock hits the turning rotor at any angle. The
      angle is not a nuisance detail: on DCMotor-v0 (``r1 = 245`` rad/s, 39
      revolutions per second) with ``amplitude = 10`` and one ripple per revolution,
      a start fixed at ``theta = 0`` made the expected-cost surface a lottery of the
      ripple's phase at settling: shifting the phase by 0.1 rad (0.4 ms of trigger
      timing) moved the optimum by 2 grid cells and put the old optimum at 1.43 times the
      new optimal cost (0.5 rad: 7 cells, 1.59 times). Averaged over the angle,
      the surface is smooth;
      ``benchmarks/README.md``, "Cogging";
    * ``synchronised=True``, or no random generator (an identification replay of
      recorded inputs, whose ``phase`` is then fitted): ``theta = 0``, for a step
      triggered by an index pulse at a fixed rotor angle.

    Parameters
    ----------
    amplitude : float
        Peak ripple in input units, ``>= 0`` (0: none).
    period : float
        Position travelled per ripple period, in position units (the output
        integrated over time for a speed loop, e.g. ``2 pi / n_slots`` rad;
        the output's units for a position loop), ``> 0``.
    phase : float, default 0.0
        Ripple phase at ``theta = 0`` in rad.
    synchronised : bool, default False
        Whether an experiment that starts with the mechanism moving starts at ``theta = 0``
        (a step triggered at a fixed rotor angle) instead of a random angle.
    """

    name = "cogging"
    side = "actuator"
    parameters = (
        EffectParameter("amplitude", "input units", 0.0, _MAX, None, 0.0, "peak ripple"),
        EffectParameter("period", "position units (rad for a speed loop in rad/s)", 1e-12, _MAX, 2.0 * np.pi,
                        float("nan"), "position travelled per ripple period"),
        EffectParameter("phase", "rad", -2.0 * np.pi, 2.0 * np.pi, 0.0, float("nan"), "phase at the start"),
    )
    options = {"synchronised": (False, True)}
    magnitude_param = "amplitude"

    def __init__(self, amplitude: float, period: float = 2.0 * np.pi, phase: float = 0.0,
                 synchronised: bool = False) -> None:
        self._set_params(amplitude=amplitude, period=period, phase=phase)
        self.synchronised = self._check_option("synchronised", synchronised)
        if not np.isfinite(self.amplitude) or not np.isfinite(self.period):
            raise ValueError(f"cogging: parameters 'amplitude' and 'period' must be finite, "
                             f"got {self.amplitude}, {self.period}")
        self._angle = np.zeros(0)
        self._dt = 0.0
        self._start: RowNoise | None = None

    @property
    def stochastic(self) -> bool:
        """Whether the start angle may be random (not ``synchronised``, ``amplitude > 0``).

        ``amplitude`` may be an array: the twin's replays merge the blocks of several
        candidate fits into one with per-row parameters (:mod:`agents.twin.open_loop`)."""
        return not self.synchronised and bool(np.any(np.asarray(self.amplitude) > 0.0))

    def random_in(self, moving_at_start: bool) -> bool:
        """A mechanism at rest starts at ``theta = 0``: only a moving one draws its start angle."""
        return self.stochastic and moving_at_start

    def at_fixed_start(self) -> Cogging:
        """This ripple ``synchronised``: every experiment starts at ``theta = 0``."""
        return self if self.synchronised else Cogging(**{**self.params, "synchronised": True})

    def reset(self, batch, rng, dt, draws=None):
        self._angle = np.zeros(batch)
        self._dt = float(dt)
        self._start = RowNoise(rng, batch, draws) if rng is not None and self.stochastic else None

    @property
    def position(self) -> np.ndarray:
        """Shape (batch,): the position ``theta`` of each row now (its state), in position units."""
        return self._angle

    def ripple(self, angle: np.ndarray, travel: np.ndarray) -> np.ndarray:
        """Mean ripple over an interval starting at phase ``angle`` and advancing by ``travel`` (both rad).

        ``(cos(a) - cos(a + d)) / d = sin(a + d / 2) sinc(d / (2 pi))`` with numpy's
        normalised ``sinc``; it tends to ``sin(a)`` as ``d -> 0``.
        """
        return self.amplitude * np.sin(angle + travel / 2.0) * np.sinc(travel / (2.0 * np.pi))

    def _phase_angle(self) -> np.ndarray:
        return (2.0 * np.pi / self.period) * self._angle + self.phase

    def command_for(self, u_applied, speed):
        if self._start is not None:  # a moving mechanism starts at a random angle within one period
            moving = np.asarray(speed) != 0.0
            if np.any(moving):  # draw j of an expectation's K starts in the j-th K-th of a period
                self._angle = np.where(moving, self.period * self._start.stratified_uniform(), 0.0)
        travel = (2.0 * np.pi / self.period) * speed * self._dt
        return u_applied - self.ripple(self._phase_angle(), travel)

    def actuate(self, u, speed):
        travel = (2.0 * np.pi / self.period) * speed * self._dt
        out = u + self.ripple(self._phase_angle(), travel)
        self._angle = self._angle + speed * self._dt
        return out
