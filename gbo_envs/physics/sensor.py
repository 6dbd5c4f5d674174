"""Sensor effects: quantization of the measured output (encoder, ADC resolution).

A sensor offset is :class:`gbo_envs.physics.actuator.Offset` with ``on="sensor"``.
"""

from __future__ import annotations

import numpy as np

from gbo_envs.physics.block import MAGNITUDE_LIMIT, EffectBlock, EffectParameter

__all__ = ["Quantization"]


class Quantization(EffectBlock):
    """Finite sensor resolution: the measurement is a whole number of steps.

    ``mode = "round"``: ``y_measured = step * round(y / step)`` (nearest level,
    e.g. an ADC); ``mode = "floor"``: ``step * floor(y / step)`` (counts, e.g.
    an encoder read as whole increments). A DC motor speed from an encoder of
    ``N`` lines per revolution sampled every ``dt`` has
    ``step = 2 pi / (N dt)`` rad/s; a linear encoder of 5 um has ``step = 5e-6`` m.

    Parameters
    ----------
    step : float
        Resolution in output units, ``>= 0`` (0: ideal sensor).
    mode : {"round", "floor"}, default "round"
        How a value between two levels is read.
    """

    name = "quantization"
    side = "sensor"
    parameters = (EffectParameter("step", "output units", 0.0, MAGNITUDE_LIMIT, None, 0.0,
                                  "distance between two measurable output levels"),)
    options = {"mode": ("round", "floor")}
    magnitude_param = "step"

    def __init__(self, step: float, mode: str = "round") -> None:
        self._set_params(step=step)
        self.mode = self._check_option("mode", mode)
        if not np.isfinite(self.step):
            raise ValueError(f"quantization: parameter 'step' must be finite, got {self.step}")

    def measure(self, y):
        if self.step == 0.0:
            return y
        scaled = y / self.step
        return self.step * (np.round(scaled) if self.mode == "round" else np.floor(scaled))
