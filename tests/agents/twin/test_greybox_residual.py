"""The simulation error a grey-box fit minimises stays finite when a trial model diverges."""

from __future__ import annotations

import numpy as np

from agents.twin.least_squares import residual
from agents.twin.records import Batch


def _data(n_records=2, n=50, mask=None):
    t = np.tile(np.arange(n) * 0.01, (n_records, 1))
    y = np.sin(t) + 5.0
    mask = np.ones_like(t, dtype=bool) if mask is None else mask
    return Batch(t=t, r=np.full_like(t, 6.0), u=np.ones_like(t), y=y, mask=mask, dt=0.01, index=np.arange(n_records))


def test_a_diverged_simulation_gives_a_bounded_residual_whose_squares_do_not_overflow():
    data = _data()
    rows = np.arange(data.n_records)
    y_sim = data.y.copy()
    y_sim[0, 10:] = 1e300  # a diverging trial model, still finite
    y_sim[1, 20] = np.nan
    y_sim[1, 30] = -np.inf
    err = residual(data, rows, y_sim)
    penalty = 1e6 * (1.0 + np.abs(data.y).max())
    assert np.all(np.isfinite(err)) and np.max(np.abs(err)) <= penalty
    assert np.isfinite(np.dot(err.ravel(), err.ravel()))
    np.testing.assert_array_equal(err[0, :10], 0.0)  # the exact samples keep their zero error


def test_residual_written_into_out_equals_the_new_array():
    mask = np.ones((3, 50), dtype=bool)
    mask[2, 40:] = False  # padding samples give 0
    data = _data(n_records=3, mask=mask)
    rows = np.array([2, 0])
    y_sim = data.y[rows] + 0.25
    y_sim[1, 5] = np.inf
    out = np.full((2, data.y.shape[1]), 7.0)
    got = residual(data, rows, y_sim, out=out)
    assert got is out
    np.testing.assert_array_equal(out, residual(data, rows, y_sim))
    np.testing.assert_array_equal(out[0, 40:], 0.0)
