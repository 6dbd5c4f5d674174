"""Measurement resolution and noise floor of an output, read from the data alone, as real sensors make it.

Three things make a real measurement's noise hard to read, and each has its estimate here:

* **Quantization** (an encoder's count, a speed from counts over a window): the output
  moves in whole steps of a quantum ``q``; :func:`quantization_step` finds it from the
  changes of ``y`` (multiples of one step, up to the precision the file was written
  with). The floor is never below ``q / sqrt(12)``, the RMS of rounding to ``q``.
* **Coloured noise and filtered speed estimates** (a low-pass filter, a moving-window
  speed): neighbouring samples share their noise, so differences of ``y`` cancel most
  of it and the white-noise estimate from second differences falls far below the truth.
  The noise's own variance is read where the signal holds still: where the input has been
  constant long enough for the response to settle, the second half of each such segment,
  around a quadratic trend (:func:`settled_noise`).
* **White noise**: ``var(Delta^2 e) = 6 sigma^2`` (:func:`white_noise`), the estimate when
  the data have no settled segment.

:func:`noise_floor_estimate` combines them into a :class:`NoiseFloor`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agents.twin.records import Batch

__all__ = ["NOISE_FLOOR_LABELS", "NoiseFloor", "noise_floor", "noise_floor_estimate", "noise_floor_method",
           "noiseless_quantum", "quantization_step", "settled_noise", "white_noise", "white_noise_floor"]

#: Median of chi-square with 1 degree of freedom: a robust ``var`` is ``median(x^2) / 0.4549``.
_CHI2_MEDIAN = 0.4549
#: Fewest samples of a settled segment (its second half) that :func:`settled_noise` uses.
MIN_SETTLED = 20
#: A change of the output counts as a whole multiple of the quantum within this fraction of it.
QUANTUM_TOLERANCE = 0.05
#: A quantized output whose levels jitter (:func:`_jittered_step`): changes below this fraction of the quantum
#: are jitter about a level, and a step is a whole multiple within half of it.
JITTER_SHARE = 0.25

#: What :func:`noise_floor` measured, by method: the label printed next to its value.
NOISE_FLOOR_LABELS = {
    "settled": "noise floor (spread of y where the response has settled, coloured or filtered noise included; "
               "not a lower bound)",
    "second_differences": "noise floor (white-noise estimate from second differences of y; the response's own "
                          "curvature adds to it, and coloured noise is underestimated: not a lower bound)",
    "quantization": "noise floor (quantization q/sqrt(12) of the output's resolution q; a model that follows the "
                    "quantized levels can fit below it: not a lower bound)",
    "none": "noise floor: not estimable from these data",
}


@dataclass(frozen=True)
class NoiseFloor:
    """The measurement's noise floor and what it is made of (:func:`noise_floor_estimate`).

    Attributes
    ----------
    rmse : float or None
        The floor in units of ``y``: the settled spread (else the white-noise estimate), never
        below ``quantum / sqrt(12)``; ``None`` when nothing can be estimated.
    method : str
        Which estimate gave ``rmse``: a key of :data:`NOISE_FLOOR_LABELS`.
    quantum : float or None
        The output's resolution ``q`` in units of ``y``, if it moves in whole steps.
    white : float or None
        The second-difference (white-noise) estimate, units of ``y``.
    settled : float or None
        The spread where the response has settled, units of ``y``.
    """

    rmse: float | None
    method: str
    quantum: float | None = None
    white: float | None = None
    settled: float | None = None

    @property
    def label(self) -> str:
        """What the floor is, in words."""
        return NOISE_FLOOR_LABELS[self.method]

    def to_dict(self) -> dict:
        """JSON-ready: ``rmse, method, label, quantum, white, settled``."""
        return {"rmse": self.rmse, "method": self.method, "label": self.label, "quantum": self.quantum,
                "white": self.white, "settled": self.settled}


def quantization_step(y: np.ndarray, mask: np.ndarray | None = None,
                      jitter: bool = False) -> tuple[float | None, float]:
    """Resolution of a quantized measurement from the histogram of its sample-to-sample changes.

    The non-zero changes of a quantized output are whole multiples of its quantum ``q``
    (whatever offset its levels have). Real sensors blur this in two ways, both handled:
    the precision a file was written with (changes below ``1e-9`` of the output's magnitude
    are not changes), and a jitter much smaller than ``q`` (a speed computed from whole
    counts over a window whose length jitters: 240.83, 240.85, 251.31 rad/s for a quantum
    of 10.47): when the changes fall into two groups more than a factor 10 apart, the small
    ones are that jitter and ``q`` is read from the large ones. ``q`` is the median of the
    smallest steps (those within a factor of 1.5 of their 5th percentile); the test counts
    the steps up to 10 ``q`` (a relative jitter grows with the multiple). With ``jitter``, levels
    that jitter in proportion to themselves, with no factor-10 gap between the jitter and the
    steps, count too (:func:`_jittered_step`): the resolution the noise floor takes, while a
    quantization candidate's step stays a fitted parameter there.

    Returns
    -------
    step : float or None
        The smallest common step of the output's changes, ``None`` if the changes are not multiples of one step.
    share : float
        Fraction of those steps within :data:`QUANTUM_TOLERANCE` of a whole multiple of ``step``.
    """
    d = np.abs(np.diff(y, axis=-1))
    if mask is not None:
        d = d[mask[..., 1:]]
    d = np.sort(d[d > 1e-9 * max(float(np.max(np.abs(y))), 1.0)])
    if d.size < 20:
        return None, 0.0
    gaps = np.diff(np.log(d))
    split = int(np.argmax(gaps)) + 1 if gaps.size else 0
    if split and gaps[split - 1] > np.log(10.0) and d.size - split >= 20:
        d = d[split:]  # the small changes are jitter around the levels, not steps between them
    low = np.percentile(d, 5)
    near = d[(d > 0.5 * low) & (d < 1.5 * low)]
    q = float(np.median(near)) if near.size else float(low)
    ratio = d[d <= 10.5 * q] / q
    share = float(np.mean(np.abs(ratio - np.round(ratio)) < QUANTUM_TOLERANCE))
    if share > 0.8 or not jitter:
        return (q if share > 0.8 else None), share
    return _jittered_step(d, share)


def _jittered_step(d: np.ndarray, share: float) -> tuple[float | None, float]:
    """The quantum of sorted changes ``d`` whose levels jitter in proportion to the level (a speed from whole
    counts over a timed interval: ``n q (1 + eps)``), where no factor-10 gap parts the jitter from the steps.

    A candidate step ``q`` (the median of the changes within 20 % of each of the changes' upper percentiles)
    counts when no change lies between :data:`JITTER_SHARE` ``q`` and ``(1 - JITTER_SHARE) q`` (the jitter stays
    well below a step, steps are whole multiples: the gap a continuous noise fills), and more than 80 % of
    the changes from ``(1 - JITTER_SHARE) q`` up to ``10.5 q``, at least 20, lie within ``JITTER_SHARE / 2 q``
    of a whole multiple. The smallest such ``q`` is returned with that share; ``(None, share)`` when none.
    """
    for q0 in np.unique(np.percentile(d, np.arange(50, 100))):
        q = float(np.median(d[(d > 0.8 * q0) & (d < 1.2 * q0)]))
        if np.mean((d > JITTER_SHARE * q) & (d < (1.0 - JITTER_SHARE) * q)) > 0.01:
            continue
        steps = d[(d >= (1.0 - JITTER_SHARE) * q) & (d <= 10.5 * q)] / q
        if steps.size < 20:
            continue
        fraction = float(np.mean(np.abs(steps - np.round(steps)) < 0.5 * JITTER_SHARE))
        if fraction > 0.8:
            return q, fraction
    return None, share


def white_noise(y: np.ndarray, mask: np.ndarray) -> float | None:
    """White-noise std from second differences: ``median((Delta^2 y)^2) / (6 * 0.4549)`` is ``sigma^2``.

    White noise ``e`` of std ``sigma`` gives ``var(Delta^2 e) = 6 sigma^2``, while the smooth
    response of a sampled plant contributes little to ``Delta^2 y``; the median is robust to the
    few kinks at steps and limits. ``None`` with fewer than 10 second differences.
    """
    d2 = np.diff(y, n=2, axis=1)[mask[:, 2:]]
    if d2.size < 10:
        return None
    return float(np.sqrt(np.median(d2**2) / (6.0 * _CHI2_MEDIAN)))


def settled_noise(data: Batch) -> float | None:
    """Spread of ``y`` where the response has settled: the noise's own std, coloured or filtered included.

    A segment is a run of samples over which the input ``u`` is constant (open-loop steps, or a
    closed loop whose command holds still, e.g. at a limit): there the plant settles and ``y``
    is its level plus the sensor's noise. In closed loop the command follows the noise, and the
    plant's motion it drives is part of what a replay of ``u`` reproduces, so a closed loop's
    spread is no noise floor. The second half of a segment, at least :data:`MIN_SETTLED` samples, is a candidate,
    around a quadratic trend (a slow tail). It counts as settled when what is left is noise,
    short-correlated: the moving average of the residual over a quarter of the half-segment keeps
    less than half of its spread (white noise keeps ``sqrt(4 / m)`` of it, noise correlated over
    ``c`` samples about ``sqrt(4 c / m)``; a response still ringing or creeping keeps most).
    The result is the median over settled segments (weighted by their samples) of the
    residual's robust std (``1.4826 MAD``).

    Returns
    -------
    float or None
        In units of ``y``; ``None`` when no segment has settled.
    """
    spreads, weights = [], []
    for k in range(data.n_records):
        n = int(data.mask[k].sum())
        for start, stop in _constant_runs(data.u[k, :n]):
            half = start + (stop - start) // 2
            if stop - half < MIN_SETTLED:
                continue
            y = data.y[k, half:stop]
            x = np.linspace(-1.0, 1.0, y.size)
            residual = y - np.polyval(np.polyfit(x, y, 2), x)
            spread = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
            window = max(y.size // 4, 2)
            slow = np.convolve(residual, np.full(window, 1.0 / window), mode="valid")
            if spread > 0.0 and float(np.std(slow)) < 0.5 * spread:
                spreads.append(spread)
                weights.append(y.size)
    if not spreads:
        return None
    order = np.argsort(spreads)
    cumulative = np.cumsum(np.asarray(weights)[order])
    return float(np.asarray(spreads)[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def _constant_runs(x: np.ndarray) -> list[tuple[int, int]]:
    """``[(start, stop)]`` of the maximal runs where ``x`` holds one value (within ``1e-12`` of its scale)."""
    tol = 1e-12 * max(float(np.max(np.abs(x))), 1e-300)
    edges = np.flatnonzero(np.abs(np.diff(x)) > tol) + 1
    bounds = np.concatenate([[0], edges, [x.size]])
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def noise_floor_estimate(data: Batch) -> NoiseFloor:
    """The measurement's noise floor: settled spread (else white noise), floored by the quantum.

    The floor is an estimate of the measurement noise, not a lower bound of a model's error: a
    model that reproduces a quantized or coloured measurement can fit below it.
    """
    quantum = quantization_step(data.y, data.mask, jitter=True)[0]
    white = white_noise(data.y, data.mask)
    settled = settled_noise(data)
    rounding = None if quantum is None else quantum / np.sqrt(12.0)
    candidates = [(settled, "settled"), (white, "second_differences")]
    value, method = next(((v, m) for v, m in candidates if v is not None and v > 0.0), (None, "none"))
    if rounding is not None and (value is None or value < rounding):
        value, method = rounding, "quantization"
    return NoiseFloor(None if value is None else float(value), method, quantum, white, settled)


def white_noise_floor(data: Batch) -> float | None:
    """The white-noise part of the floor, as a twin simulates measurement noise: second differences of ``y``,
    or ``q / sqrt(12)`` when more than half of them are exactly zero (a quantized output without visible noise).

    A twin's noise model is white (:class:`agents.twin.TwinEnv`), so guided BO sizes it, and the thresholds
    relative to it, from this part (:func:`agents.twin.selection.measurement_noise`); the workbench's floor
    (:func:`noise_floor_estimate`) also counts coloured noise and is never below the quantum.
    """
    d2 = np.diff(data.y, n=2, axis=1)[data.mask[:, 2:]]
    if d2.size < 10:
        return None
    if not _holds_still(data, d2):
        return white_noise(data.y, data.mask)
    q = quantization_step(data.y, data.mask)[0]
    return None if q is None else float(q / np.sqrt(12.0))


def noiseless_quantum(data: Batch) -> float | None:
    """The resolution ``q`` (units of ``y``) of an output quantized without visible noise, else ``None``.

    As :func:`white_noise_floor` reads it: more than half of the second differences of ``y`` are exactly
    zero, and its changes are whole multiples of one step (:func:`quantization_step`). Such a
    measurement is a deterministic rounding of the response, not white noise of std ``q / sqrt(12)``:
    it never exceeds the reference by less than a level.
    """
    d2 = np.diff(data.y, n=2, axis=1)[data.mask[:, 2:]]
    if d2.size < 10 or not _holds_still(data, d2):
        return None
    return quantization_step(data.y, data.mask)[0]


def _holds_still(data: Batch, d2: np.ndarray) -> bool:
    """Whether more than half of the second differences ``d2`` of ``y`` are exactly zero (no visible noise)."""
    scale = max(float(np.max(np.abs(data.y[data.mask]))), 1.0)
    return not np.mean(np.abs(d2) <= 1e-12 * scale) < 0.5


def noise_floor(data: Batch) -> float | None:
    """The floor of :func:`noise_floor_estimate`, in units of ``y`` (``None`` when not estimable)."""
    return noise_floor_estimate(data).rmse


def noise_floor_method(data: Batch) -> str:
    """How :func:`noise_floor` estimated the floor: a key of :data:`NOISE_FLOOR_LABELS`."""
    return noise_floor_estimate(data).method
