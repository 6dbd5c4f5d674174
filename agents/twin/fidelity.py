"""The twin's fidelity: the root-mean-square simulation error of eq. (RMSE), the one RMSE of :mod:`agents.twin`."""

from __future__ import annotations

import numpy as np

__all__ = ["rmse"]


def rmse(error, mask=None, height=None) -> float:
    r"""Eq. (RMSE): root mean square of the simulation error over the real samples of all records.

    .. math:: e_{RMSE} = \sqrt{\frac{1}{N} \sum_k \sum_t \left(\frac{e_k(t)}{h_k}\right)^2}

    Parameters
    ----------
    error : array_like of shape (n_records, n_steps) or (n_steps,)
        Measured minus simulated output (or any difference of two outputs), in the units of ``y``.
    mask : array_like of bool, same shape as ``error``, optional
        True on real samples (padding excluded); default all samples. ``N`` counts the real samples.
    height : array_like of shape (n_records,) or the shape of ``error``, optional
        Divisor ``h_k`` of each record's error, e.g. the step height ``|r2 - y0|`` (the
        paper's normalised RMSE, dimensionless); default none (RMSE in the units of ``y``).

    Returns
    -------
    float
        ``inf`` when a value is not finite (a diverged simulation, or a record of zero ``height``).
    """
    err = np.asarray(error, dtype=float)
    if height is not None:
        h = np.asarray(height, dtype=float)
        h = np.where(h > 0.0, h, np.nan)
        err = err / (h[:, None] if err.ndim == 2 and h.ndim == 1 else h)
    if mask is None:
        count = err.size
    else:
        err = np.where(mask, err, 0.0)
        count = int(np.sum(mask))
    value = float(np.sqrt(np.sum(err**2) / count))
    return value if np.isfinite(value) else np.inf
