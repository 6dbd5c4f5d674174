"""What a residual looks like, for a diagnosis that found no candidate while the model is far from the noise floor.

A physicist does not sign "stop" at 20 times the noise floor: the model misses something, and the
residual says what kind of thing. :func:`residual_shape` reads it: the peak of its spectrum (Hz and
rad/s), the plant mode it shows (:func:`agents.twin.modes.plant_modes`), and its correlation with the
input ``u``, the output ``y`` and the output's rate ``dy/dt`` (a static input map follows ``u``, a
sensor map or a missing output-dependent term ``y``, a friction or damping term the speed).
:func:`shape_text` puts it in words, with the general candidates (grown orders, maps: every candidate
outside the catalogue of effects) that were tried and why each failed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from agents.twin.model import GreyFit, output_error
from agents.twin.modes import Mode, plant_modes
from agents.twin.records import Batch
from gbo_envs.physics.effects import EFFECT_NAMES

__all__ = ["FAR_FROM_FLOOR", "residual_shape", "shape_text", "tried_general"]

#: A model whose RMSE is above this many noise floors is not at the floor: the stop advice describes the residual.
FAR_FROM_FLOOR = 3.0
#: Zero padding of the residual's periodogram (times the record length): peaks of a short record between bins.
PADDING = 4


def residual_shape(data: Batch, fit: GreyFit, modes: Sequence[Mode] | None = None) -> dict:
    """The residual ``y - y_sim`` of ``fit`` described: its spectral peak, its plant mode and its correlations.

    ``modes`` are the plant's modes in the residual of ``fit`` (:func:`agents.twin.modes.plant_modes`; default:
    scanned here).

    Returns
    -------
    dict
        ``peak_hz``, ``peak_rad_s`` (the mean periodogram's largest value from 1.5 periods per record
        to half the Nyquist frequency; ``None`` for records under 16 samples), ``peak_ratio`` (its power
        over the band's median, -), ``mode`` (``{"frequency", "hertz", "damping", "share"}`` of the
        strongest plant mode, or ``None``), ``corr_u``, ``corr_y``, ``corr_dy`` (correlation of the
        residual with ``u``, ``y`` and ``dy/dt``, each record centred, -), ``rmse`` (units of ``y``).
    """
    mask = data.mask
    e = output_error(data.y, fit.y_sim, mask, fit.spec, data.closed_loop)
    out = {"rmse": float(fit.rmse), "peak_hz": None, "peak_rad_s": None, "peak_ratio": None, "mode": None}
    n = int(mask.sum(axis=1).min())
    if n >= 16:
        x = e[:, :n] - e[:, :n].mean(axis=1, keepdims=True)
        power = np.mean(np.abs(np.fft.rfft(x * np.hanning(n), n=PADDING * n, axis=1)) ** 2, axis=0)
        f = np.fft.rfftfreq(PADDING * n, data.dt)
        band = (f >= 1.5 / (n * data.dt)) & (f <= 0.25 / data.dt)
        if band.sum() >= 3:
            i = np.flatnonzero(band)[np.argmax(power[band])]
            out.update(peak_hz=float(f[i]), peak_rad_s=float(2.0 * np.pi * f[i]),
                       peak_ratio=float(power[i] / max(np.median(power[band]), 1e-300)))
    if modes is None:
        modes = plant_modes(data, fit, n_modes=1)
    if modes:
        m = modes[0]
        out["mode"] = {"frequency": m.frequency, "hertz": m.hertz, "damping": m.damping, "share": m.share}
    dy = np.gradient(data.y, data.dt, axis=1)
    for key, signal in (("corr_u", data.u), ("corr_y", data.y), ("corr_dy", dy)):
        out[key] = _centred_corr(e, signal, mask)
    return out


def tried_general(candidates: list[dict]) -> list[dict]:
    """The general candidates among a ranking's ``candidates``: grown orders and every structure outside the
    catalogue of effects (a static map), as ``{"effect", "verdict", "share"}``."""
    return [{"effect": c["effect"], "verdict": c.get("verdict", ""), "share": float(c.get("share", 0.0))}
            for c in candidates if c.get("kind") == "order" or c["effect"] not in EFFECT_NAMES]


def shape_text(shape: Mapping, tried: list[dict], noise: float, units: Mapping[str, str] | None = None) -> str:
    """The residual of :func:`residual_shape` and the general candidates ``tried`` in words, for the stop advice.

    ``noise`` is the noise floor (units of ``y``); ``units`` ``{"y": ...}`` names its unit.
    """
    y = (units or {}).get("y") or "(units of y)"
    parts = [f"the residual (RMSE {shape['rmse']:.3g} {y}) is {shape['rmse'] / noise:.3g}× the noise floor "
             f"({noise:.3g} {y}): the model misses something"]
    if shape.get("peak_hz") is not None:
        parts.append(f"its spectrum peaks at {shape['peak_hz']:.3g} Hz ({shape['peak_rad_s']:.3g} rad/s, "
                     f"{shape['peak_ratio']:.3g}× the median power)")
    mode = shape.get("mode")
    if mode:
        parts.append(f"it follows the plant input through a mode at {mode['hertz']:.3g} Hz "
                     f"({mode['frequency']:.3g} rad/s, damping about {mode['damping']:.2g}, {mode['share']:.0f} % "
                     f"of its power)")
    else:
        parts.append("it shows no mode of the plant")
    parts.append(f"it correlates with u (r={shape['corr_u']:.2f}), y (r={shape['corr_y']:.2f}) and dy/dt "
                 f"(r={shape['corr_dy']:.2f})")
    if tried:
        parts.append("general candidates tried: " + ", ".join(
            f"{t['effect'].replace('_', ' ')} ({t['verdict']}; explains {t['share']:.0f} %)" for t in tried))
    else:
        parts.append("no general candidate (grown order, map) was tried")
    return "; ".join(parts)


def _centred_corr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """Correlation of ``a`` and ``b`` over the real samples, each record's mean removed from both (-)."""
    count = np.maximum(mask.sum(axis=1, keepdims=True), 1)

    def centred(x: np.ndarray) -> np.ndarray:
        return np.where(mask, x - np.sum(np.where(mask, x, 0.0), axis=1, keepdims=True) / count, 0.0)

    x, z = centred(a)[mask], centred(b)[mask]
    den = float(np.sqrt(np.sum(x**2) * np.sum(z**2)))
    return float(np.sum(x * z) / den) if den > 0 else 0.0
