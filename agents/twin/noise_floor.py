"""Measurement resolution and noise floor of an output, read from the data alone."""

from __future__ import annotations

import numpy as np

from agents.twin.greybox import GreyData

__all__ = ["NOISE_FLOOR_LABELS", "noise_floor", "noise_floor_estimate", "noise_floor_method", "quantization_step"]


def quantization_step(y: np.ndarray, mask: np.ndarray | None = None) -> tuple[float | None, float]:
    """Resolution of a quantized measurement from the histogram of its sample-to-sample changes.

    Returns
    -------
    step : float or None
        The smallest common step of the output's changes, ``None`` if the changes are not multiples of one step.
    share : float
        Fraction of the non-zero changes within 5 % of a whole multiple of ``step``.
    """
    d = np.abs(np.diff(y, axis=-1))
    if mask is not None:
        d = d[mask[..., 1:]]
    d = d[d > 1e-12 * max(float(np.max(np.abs(y))), 1.0)]
    if d.size < 20:
        return None, 0.0
    low = np.percentile(d, 5)
    near = d[(d > 0.5 * low) & (d < 1.5 * low)]
    q = float(np.median(near)) if near.size else float(low)
    ratio = d / q
    share = float(np.mean(np.abs(ratio - np.round(ratio)) < 0.05))
    return (q if share > 0.8 else None), share


#: What :func:`noise_floor` measured, by method: the label printed next to its value.
NOISE_FLOOR_LABELS = {
    "second_differences": "noise floor (white-noise estimate from second differences of y; the response's own "
                          "curvature adds to it, so a good model can fit below it: not a lower bound)",
    "quantization": "noise floor (quantization q/sqrt(12) of the output's resolution q; a model that follows the "
                    "quantized levels can fit below it: not a lower bound)",
    "none": "noise floor: not estimable from these data",
}


def noise_floor(data: GreyData) -> float | None:
    """Measurement-noise floor of ``y`` in output units, from its second differences.

    White noise ``e`` of std ``sigma`` gives ``var(Delta^2 e) = 6 sigma^2``, while the
    smooth response of a sampled plant contributes little to ``Delta^2 y``; the
    median of ``(Delta^2 y)^2`` (robust to the few kinks at steps and limits)
    divided by ``6 * 0.4549`` (median of chi-square with 1 degree of freedom) is
    ``sigma^2``. A quantized output with no visible noise (more than half of the
    second differences exactly zero) gives the quantization floor ``q / sqrt(12)``
    instead; ``None`` when neither can be estimated. :func:`noise_floor_method` says which.

    It is an estimate of the measurement noise, not a lower bound of a model's error:
    the response's own curvature adds to the second differences, and a model that
    reproduces a quantized or coloured measurement can fit below it.
    """
    return noise_floor_estimate(data)[0]


def noise_floor_method(data: GreyData) -> str:
    """How :func:`noise_floor` estimated the floor: ``"second_differences"``, ``"quantization"`` or ``"none"``.

    :data:`NOISE_FLOOR_LABELS` maps it to the label printed next to the value.
    """
    return noise_floor_estimate(data)[1]


def noise_floor_estimate(data: GreyData) -> tuple[float | None, str]:
    """``(noise_floor(data), noise_floor_method(data))`` from one estimate."""
    d2 = np.diff(data.y, n=2, axis=1)[data.mask[:, 2:]]
    if d2.size < 10:
        return None, "none"
    scale = max(float(np.max(np.abs(data.y[data.mask]))), 1.0)
    if np.mean(np.abs(d2) <= 1e-12 * scale) < 0.5:
        return float(np.sqrt(np.median(d2**2) / (6.0 * 0.4549))), "second_differences"
    q = quantization_step(data.y, data.mask)[0]
    return (None, "none") if q is None else (float(q / np.sqrt(12.0)), "quantization")
