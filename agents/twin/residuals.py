"""Residual analysis of a fitted twin: whiteness, input cross-correlation and where the model fails."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agents.twin.model import GreyFit
from agents.twin.records import Batch

__all__ = ["ResidualAnalysis", "residuals"]

Z99 = 2.58  # two-sided 99 % quantile of the standard normal





@dataclass(frozen=True, eq=False)
class ResidualAnalysis:
    """Where and how a model fails.

    Attributes
    ----------
    lags : ndarray of int, shape (n_lags,)
        ``0..L`` for the autocorrelation.
    acf : ndarray of shape (n_lags,)
        Normalised residual autocorrelation, pooled over records.
    ccf_lags : ndarray of int, shape (2 L + 1,)
    ccf : ndarray of shape (2 L + 1,)
        Normalised residual-input cross-correlation ``corr(e(t), u(t - lag))``.
    band : float
        99 % band ``2.58 / sqrt(N)`` of both under whiteness and independence.
    white, independent : bool
        Whether the acf (lags >= 1) and ccf stay inside the band (a 1 % excess allowed).
    bins : dict
        ``{"time" | "experiment" | "input" | "output" | "velocity_sign": {"centers", "rms", "mean", "count"}}``.
    worst : list of dict
        Worst segments: experiment, ``t_start``, ``t_end`` (s), rms and mean residual.
    """

    lags: np.ndarray
    acf: np.ndarray
    ccf_lags: np.ndarray
    ccf: np.ndarray
    band: float
    white: bool
    independent: bool
    bins: dict
    worst: list

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return {"band": self.band, "white": self.white, "independent": self.independent,
                "acf": self.acf.tolist(), "ccf_lags": self.ccf_lags.tolist(), "ccf": self.ccf.tolist(),
                "bins": {k: {kk: np.asarray(vv).tolist() for kk, vv in v.items()} for k, v in self.bins.items()},
                "worst": self.worst}


def residuals(data: Batch, fit: GreyFit, max_lag: int | None = None, n_bins: int = 10,
              n_worst: int = 5) -> ResidualAnalysis:
    """Residual whiteness, residual-input correlation and the residual's distribution over the operating range."""
    m = data.mask
    every = bool(m.all())

    def padded_zero(x: np.ndarray) -> np.ndarray:
        """``x`` with 0 on the padding (``x`` itself when nothing is padded: no copy of all samples)."""
        return x if every else np.where(m, x, 0.0)

    e = padded_zero(data.y - fit.y_sim)
    n_min = int(data.mask.sum(axis=1).min())
    lag_max = int(max_lag if max_lag is not None else min(50, max(n_min // 4, 1)))
    means = np.sum(e, axis=1) / data.mask.sum(axis=1)
    ec = padded_zero(e - means[:, None])
    del e  # computed again for the bins: fewer arrays of all samples at once
    u_mean = np.sum(padded_zero(data.u), axis=1) / data.mask.sum(axis=1)
    uc = padded_zero(data.u - u_mean[:, None])
    n_total = data.n_samples
    ee, uu = float(np.sum(ec**2)), float(np.sum(uc**2))
    acf = np.array([np.sum(ec[:, lag:] * ec[:, : ec.shape[1] - lag]) for lag in range(lag_max + 1)])
    acf = acf / max(ee, 1e-300)
    lags = np.arange(-lag_max, lag_max + 1)
    ccf = np.array([np.sum(ec[:, lag:] * uc[:, : uc.shape[1] - lag]) if lag >= 0 else
                    np.sum(ec[:, : ec.shape[1] + lag] * uc[:, -lag:]) for lag in lags])
    ccf = ccf / max(np.sqrt(ee * uu), 1e-300)
    del ec, uc  # memory for the bins below
    e = padded_zero(data.y - fit.y_sim)
    band = Z99 / np.sqrt(n_total)
    white = bool(np.mean(np.abs(acf[1:]) > band) <= 0.01)
    independent = bool(np.mean(np.abs(ccf) > band) <= 0.01)
    # a speed loop: the sign of the speed itself; a position loop: of the position's derivative
    velocity = data.y if fit.spec.output != "position" else np.gradient(data.y, data.dt, axis=1)

    def real(x: np.ndarray) -> np.ndarray:
        """The real samples of ``x``, record after record (a view of ``x`` when there is no padding)."""
        return x.reshape(-1) if every else x[m]

    e_real = real(e)
    bins = {
        "time": _binned(real(data.t - data.t[:, :1]), e_real, n_bins),
        "experiment": _grouped(*_by_record(data.numbers, data.mask.sum(axis=1)), e_real),
        "input": _binned(real(data.u), e_real, n_bins, quantiles=True),
        "output": _binned(real(data.y), e_real, n_bins, quantiles=True),
        "velocity_sign": _grouped(*_by_sign(np.sign(np.round(real(velocity), 12))), e_real),
    }
    return ResidualAnalysis(np.arange(lag_max + 1), acf, lags, ccf, float(band), white, independent, bins,
                            _worst_segments(data, e, n_worst))


def _binned(x: np.ndarray, e: np.ndarray, n_bins: int, quantiles: bool = False) -> dict:
    edges = np.unique(np.percentile(x, np.linspace(0, 100, n_bins + 1))) if quantiles else \
        np.linspace(x.min(), x.max(), n_bins + 1)
    if edges.size < 2:
        edges = np.array([x.min(), x.max() + 1e-12])
    which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
    centers = 0.5 * (edges[:-1] + edges[1:])
    count = np.bincount(which, minlength=centers.size)
    total = np.bincount(which, weights=e, minlength=centers.size)
    sq = np.bincount(which, weights=e**2, minlength=centers.size)
    with np.errstate(invalid="ignore", divide="ignore"):
        return {"centers": centers, "rms": np.sqrt(sq / count), "mean": total / count, "count": count}


def _grouped(keys: np.ndarray, which: np.ndarray, e: np.ndarray) -> dict:
    """Count, RMS and mean of ``e`` per key, sample ``i`` having ``keys[which[i]]`` (keys sorted, each present)."""
    count = np.bincount(which)
    return {"centers": keys.astype(float), "rms": np.sqrt(np.bincount(which, weights=e**2) / count),
            "mean": np.bincount(which, weights=e) / count, "count": count}


def _by_record(numbers: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(keys, which)`` of the real samples by their record's number, without sorting every sample."""
    keys, which = np.unique(numbers, return_inverse=True)
    return keys, np.repeat(which, lengths)  # record after record, as the real samples


def _by_sign(signs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(keys, which)`` of samples by their sign (-1, 0 or 1), as ``np.unique`` gives them, without sorting."""
    keys = np.array([value for value in (-1.0, 0.0, 1.0) if np.any(signs == value)])
    return keys, np.searchsorted(keys, signs)


def _worst_segments(data: Batch, e: np.ndarray, n_worst: int) -> list[dict]:
    n_min = int(data.mask.sum(axis=1).min())
    width = max(5, n_min // 20)
    kernel = np.ones(width) / width
    found = []
    for k in range(data.n_records):
        n = int(data.mask[k].sum())
        power = np.convolve(e[k, :n] ** 2, kernel, mode="valid")
        taken = np.zeros(power.size, dtype=bool)
        for _ in range(n_worst):
            cand = np.where(taken, -np.inf, power)
            i = int(np.argmax(cand))
            if not np.isfinite(cand[i]):
                break
            taken[max(0, i - width + 1) : i + width] = True
            found.append((float(power[i]), k, i))
    found.sort(reverse=True)
    out = []
    for power, k, i in found[:n_worst]:
        seg = e[k, i : i + width]
        out.append({"experiment": int(data.numbers[k]), "t_start": float(data.t[k, i]),
                    "t_end": float(data.t[k, i + width - 1]), "rms": float(np.sqrt(power)),
                    "mean": float(np.mean(seg))})
    return out
