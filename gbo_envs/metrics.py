"""Step-response performance metrics and the weighted cost of the paper.

Definitions follow Sec. "Performance Metrics" of the guided-BO paper; every
function works on a batch of responses of shape (batch, n_steps).
"""

from __future__ import annotations

import numpy as np

__all__ = ["METRIC_NAMES", "step_metrics", "weighted_cost"]

#: Order of the metrics in every array and of the weights ``w``.
METRIC_NAMES = ("overshoot_pct", "settling_time", "rise_time", "itae")

#: Settling band as a fraction of the step height, eq. (Ts).
SETTLING_BAND = 0.02
#: Rise-time levels as fractions of the step height (10 % -> 60 %).
RISE_LEVELS = (0.10, 0.60)


def step_metrics(t: np.ndarray, y: np.ndarray, r1: float, r2: float) -> np.ndarray:
    """Overshoot, settling time, rise time and ITAE of step responses.

    Parameters
    ----------
    t : ndarray of shape (n_steps,)
        Time since the step in s, starting at 0, uniformly spaced.
    y : ndarray of shape (batch, n_steps) or (n_steps,)
        Output in the units of the reference.
    r1, r2 : float
        Reference before and after the step (``r2 != r1``).

    Returns
    -------
    ndarray of shape (batch, 4) (or (4,) for a single response)
        Columns in :data:`METRIC_NAMES` order:

        * overshoot ``zeta = 100 max(0, (y_max - y(T)) / dr)`` in %, eq. (zeta);
        * settling time ``T_s`` in s, the first time after which
          ``|y - r2| <= 0.02 |dr|`` holds to the end, eq. (Ts) (``T`` if never);
        * rise time ``T_r`` in s from 10 % to 60 % of the way from ``r1`` to
          ``r2``, with crossing times linearly interpolated (``T`` if never);
        * ``e_ITAE = int_0^T t |y - r2| dt`` in (units of y) s^2, eq. (ITAE),
          by the trapezoidal rule.
    """
    single = np.ndim(y) == 1
    y = np.atleast_2d(np.asarray(y, dtype=float))
    t = np.asarray(t, dtype=float)
    dr = float(r2) - float(r1)
    if dr == 0.0:
        raise ValueError("r1, r2: the step height r2 - r1 must be non-zero")
    sign = np.sign(dr)
    t_final = t[-1]

    # eq. (zeta): peak overshoot relative to the final value y(T)
    peak = np.max(sign * y, axis=1) * sign
    overshoot = 100.0 * np.maximum(0.0, (peak - y[:, -1]) * sign / abs(dr))

    # eq. (Ts): last sample outside the 2 % band, settled from the next sample on
    error = np.abs(y - r2)
    outside = error > SETTLING_BAND * abs(dr)
    any_outside = outside.any(axis=1)
    last_outside = y.shape[1] - 1 - np.argmax(outside[:, ::-1], axis=1)
    settle_idx = np.where(any_outside, last_outside + 1, 0)
    settling = np.where(settle_idx < t.size, t[np.minimum(settle_idx, t.size - 1)], t_final)

    # rise time 10 % -> 60 % of the way (progress measured along the step direction)
    progress = (y - r1) / dr
    start, end = _first_crossings(t, progress, np.asarray(RISE_LEVELS))
    with np.errstate(invalid="ignore"):
        rise = np.where(np.isfinite(end), end - start, t_final)

    # eq. (ITAE), trapezoidal rule on the (uniform or not) time grid
    weighted = t * error
    itae = 0.5 * ((weighted[:, 1:] + weighted[:, :-1]) @ np.diff(t))

    out = np.stack([overshoot, settling, rise, itae], axis=1)
    return out[0] if single else out


def _first_crossings(t: np.ndarray, progress: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """Linearly interpolated first times ``progress`` reaches each level (``inf`` if never).

    Returns an array of shape (n_levels, batch); all levels in one vectorised pass.
    """
    above = progress[None, :, :] >= levels[:, None, None]  # (levels, batch, n_steps)
    reached = above.any(axis=2)
    idx = np.argmax(above, axis=2)
    prev = np.maximum(idx - 1, 0)
    rows = np.arange(progress.shape[0])[None, :]
    p0, p1 = progress[rows, prev], progress[rows, idx]
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(p1 > p0, (levels[:, None] - p0) / (p1 - p0), 0.0)
    frac = np.where(idx == 0, 0.0, np.clip(frac, 0.0, 1.0))
    times = t[prev] + frac * (t[idx] - t[prev])
    return np.where(reached, times, np.inf)


def weighted_cost(metrics: np.ndarray, weights: np.ndarray, normalizers: np.ndarray) -> np.ndarray:
    """Cost ``J = sum_i w_i f_i / n_i``, eqs. (J) and (J_used).

    Parameters
    ----------
    metrics : ndarray of shape (batch, 4) or (4,)
        Metrics in :data:`METRIC_NAMES` order.
    weights : ndarray of shape (4,)
        Positive weights ``w`` summing to 1 (DC motor: 0.44, 0.22, 0.22, 0.11).
    normalizers : ndarray of shape (4,)
        Mean of each metric over the reference gains (paper: 5 gains evenly
        spanning the feasible set), so that every normalised metric is about 1.

    Returns
    -------
    ndarray of shape (batch,) or float
        The dimensionless cost ``J``.
    """
    return np.asarray(metrics, dtype=float) @ (np.asarray(weights) / np.asarray(normalizers))
