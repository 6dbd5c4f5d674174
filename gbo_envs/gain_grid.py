"""Regular grids over a box of controller gains.

The paper evaluates the cost on a dense grid of the feasible set: for the
ground truth ``theta* = argmin J(theta)`` (Sec. VI) and as the candidate set
over which the acquisition is maximised (eq. (EI)). Both grids, and every
benchmark grid, are built here, so they agree point for point.
"""

from __future__ import annotations

import numpy as np

__all__ = ["grid_axes", "grid_points"]


def grid_axes(low, high, points_per_gain: int) -> tuple[np.ndarray, ...]:
    """Evenly spaced values of each gain, ends included.

    Parameters
    ----------
    low, high : array_like of shape (n_gains,)
        Finite box bounds in gain units, ``low <= high`` element-wise.
    points_per_gain : int
        Values per gain, ``>= 1``.

    Returns
    -------
    tuple of ndarray
        One array of shape (points_per_gain,) per gain, from ``low[i]`` to ``high[i]``
        (``numpy.linspace``, so float32 bounds give float32 values).
    """
    low = np.asarray(low)
    high = np.asarray(high)
    if low.ndim != 1 or low.shape != high.shape or low.size == 0:
        raise ValueError(f"low, high: must be 1-D arrays of one common length >= 1, got shapes {low.shape} "
                         f"and {high.shape}")
    if not (np.issubdtype(low.dtype, np.number) and np.issubdtype(high.dtype, np.number)):
        raise ValueError(f"low, high: must be numeric, got dtypes {low.dtype} and {high.dtype}")
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(low <= high)):
        raise ValueError(f"low, high: must be finite with low <= high, got low={low}, high={high}")
    if isinstance(points_per_gain, bool) or int(points_per_gain) != points_per_gain or points_per_gain < 1:
        raise ValueError(f"points_per_gain: must be an integer >= 1, got {points_per_gain}")
    return tuple(np.linspace(lo, hi, int(points_per_gain)) for lo, hi in zip(low, high))


def grid_points(axes) -> np.ndarray:
    """Every combination of the axis values, the first gain varying slowest.

    Parameters
    ----------
    axes : sequence of 1-D array_like
        The values of each gain, e.g. from :func:`grid_axes`.

    Returns
    -------
    ndarray of shape (prod(len(a) for a in axes), len(axes))
        One grid point a row, in ``numpy.meshgrid(..., indexing="ij")`` order, so that
        ``values.reshape(tuple(len(a) for a in axes))`` puts gain ``i`` on axis ``i``.
    """
    axes = [np.asarray(a) for a in axes]
    if not axes or any(a.ndim != 1 or a.size == 0 for a in axes):
        raise ValueError("axes: must be one or more non-empty 1-D arrays")
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.column_stack([m.ravel() for m in mesh])
