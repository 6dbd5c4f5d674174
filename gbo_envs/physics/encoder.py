"""Encoders: the measurement chains of the rigs, with the noise in front of the count.

A real encoder does not quantise the true output. Shaft vibration, eccentricity
of the code disc and electrical noise on the edges jitter the position the
read head sees, and the counter counts whole increments of that jittered
position. The count therefore dithers between neighbouring increments, and
its expectation over the jitter and the unknown phase of the code disc is a
smooth function of the true position, unlike ``floor()`` of it.

* :class:`PositionEncoder`: an absolute position sensor (e.g. the MS01 of the
  paper's linear motor rig) read as the nearest whole increment.
* :class:`SpeedEncoder`: an incremental rotary encoder whose counts a drive's
  firmware differentiates over a moving window of samples to get the speed.

Both are sensor-side :class:`~gbo_envs.physics.block.EffectBlock` objects with
measurement noise (``stochastic = True``): they draw their random numbers from
a :class:`~gbo_envs.physics.block.RowNoise`, so that an env can average a cost
over common random numbers. They are not in the effect catalogue: a twin
models their mean behaviour with ``quantization``.
"""

from __future__ import annotations

import numpy as np

from gbo_envs.physics.block import EffectBlock, EffectParameter, RowNoise, validated_count, validated_finite

__all__ = ["PositionEncoder", "SpeedEncoder"]

_INF = float("inf")
_NAN = float("nan")  # "zero" of a parameter that is not the block's magnitude


class PositionEncoder(EffectBlock):
    """Absolute position sensor with read-head jitter: ``y_m = q round((y + nu) / q)``.

    ``nu ~ N(0, jitter^2)`` is drawn afresh at every sample (vibration and
    electrical noise), ``q`` is the resolution. With ``jitter`` of a sizeable
    fraction of ``q`` the reading dithers between neighbouring levels, as a
    real sensor's last digit does at standstill.

    Parameters
    ----------
    resolution : float
        Increment ``q`` in output units (m for a linear sensor), ``> 0``.
    jitter : float
        Standard deviation of the position noise before the count, in output
        units, ``>= 0``.
    """

    name = "position_encoder"
    side = "sensor"
    parameters = (
        EffectParameter("resolution", "output units", 0.0, _INF, None, _NAN, "increment of the sensor"),
        EffectParameter("jitter", "output units", 0.0, _INF, 0.0, 0.0, "std of the position noise before the count"),
    )
    magnitude_param = "jitter"

    def __init__(self, resolution: float, jitter: float = 0.0) -> None:
        self._set_params(resolution=resolution, jitter=jitter)
        validated_finite("resolution", self.resolution, "output units", positive=True, owner=self.name)
        self._noise: RowNoise | None = None

    @property
    def stochastic(self) -> bool:
        """Whether the reading is noisy (``jitter > 0``)."""
        return self.jitter > 0.0

    def reset(self, batch, rng, dt, draws=None):
        self._noise = RowNoise(rng, batch, draws) if self.jitter > 0.0 else None

    def measure(self, y):
        scaled = y / self.resolution
        if self._noise is not None:
            scaled = scaled + (self.jitter / self.resolution) * self._noise.standard_normal()
        return self.resolution * np.round(scaled)


class SpeedEncoder(EffectBlock):
    """Incremental rotary encoder differentiated over a moving window, as drive firmware reads a speed.

    Stages, at every sample ``k`` of length ``dt`` (s):

    1. shaft angle ``a[k] = a[k-1] + dt (w[k] + w[k-1]) / 2`` (rad) from the
       true speed ``w`` (rad/s), started at a random phase of the code disc,
       uniform over one increment (the disc's position at the start of an
       experiment is unknown);
    2. jitter: ``a[k] + nu[k]``, ``nu ~ N(0, jitter^2)`` in rad, fresh at
       every sample (shaft vibration, disc eccentricity, edge noise);
    3. count: ``c[k] = floor((a[k] + nu[k]) / Delta)`` whole increments,
       ``Delta = 2 pi / lines`` rad;
    4. speed: ``w_m[k] = (c[k] - c[k - M]) Delta / (M dt)`` rad/s over the
       last ``M = window`` samples. Its resolution is ``Delta / (M dt)``.

    Before the first sample the shaft is taken to have turned at the first
    measured speed (the experiment starts at rest at a constant speed). The
    window delays the reading by about ``(M - 1) dt / 2`` on average.

    Parameters
    ----------
    lines : int
        Increments per revolution, ``>= 1``.
    window : int
        Samples ``M`` over which the counts are differenced, ``>= 1``.
    jitter : float
        Standard deviation of the angle noise before the count in rad, ``>= 0``.
    """

    name = "speed_encoder"
    side = "sensor"
    stochastic = True
    parameters = (
        EffectParameter("lines", "increments per revolution", 1.0, _INF, None, _NAN, "increments per turn"),
        EffectParameter("window", "samples", 1.0, _INF, 1.0, _NAN, "samples the counts are differenced over"),
        EffectParameter("jitter", "rad", 0.0, _INF, 0.0, 0.0, "std of the angle noise before the count"),
    )
    magnitude_param = "jitter"

    def __init__(self, lines: int, window: int = 1, jitter: float = 0.0) -> None:
        lines = validated_count("lines", lines, owner=self.name)
        window = validated_count("window", window, owner=self.name)
        self._set_params(lines=lines, window=window, jitter=jitter)
        self.lines, self.window = lines, window
        self._noise: RowNoise | None = None

    @property
    def increment(self) -> float:
        """Angle of one increment ``Delta = 2 pi / lines`` in rad."""
        return 2.0 * np.pi / self.lines

    def speed_resolution(self, dt: float) -> float:
        """Step of the measured speed ``Delta / (window dt)`` in rad/s at sample time ``dt`` s."""
        return self.increment / (self.window * dt)

    def reset(self, batch, rng, dt, draws=None):
        self._noise = RowNoise(rng, batch, draws)
        self._jitter = self.jitter / self.increment  # in increments
        self._half_sample = dt / (2.0 * self.increment)  # trapezoid: increments per (rad/s) of y[k] + y[k-1]
        self._speed_per_count = self.speed_resolution(dt)
        self._angle = None  # in increments; set on the first sample

    def _count(self, angle: np.ndarray, samples: int | None = None) -> np.ndarray:
        """Whole increments of the jittered angle (stages 2-3)."""
        if not self._jitter:
            return np.floor(angle)
        return np.floor(angle + self._jitter * self._noise.standard_normal(samples))

    def measure(self, y):
        if self._angle is None:
            # at rest at speed y before the step: the last M counts of a constant rotation
            self._angle = self._noise.uniform()
            past = self._angle - (2.0 * self._half_sample) * y * np.arange(self.window, 0, -1)[:, None]
            self._counts = self._count(past, self.window)
            self._slot = 0
        else:
            self._angle = self._angle + self._half_sample * (y + self._last_speed)
        self._last_speed = y
        count = self._count(self._angle)
        speed = (count - self._counts[self._slot]) * self._speed_per_count
        self._counts[self._slot] = count
        self._slot = (self._slot + 1) % self.window
        return speed
