"""The delayed commands of the open-loop simulation: each row's own delay, rows in any order."""

from __future__ import annotations

import numpy as np

from agents.twin.open_loop import _delayed


def _reference(u, perm, lags, u_rest):
    """The delayed commands by index arrays (the former formula)."""
    u = u[perm]
    k = np.arange(u.shape[1])[None, :] - lags[:, None]
    return np.where(k >= 0, np.take_along_axis(u, np.maximum(k, 0), axis=1), u_rest[:, None])


def test_delayed_matches_index_formula_for_mixed_delays_and_orders():
    rng = np.random.default_rng(0)
    u = rng.normal(size=(7, 9))
    u_rest = rng.normal(size=7)
    for perm in (np.arange(7), rng.permutation(7)):
        for lags in (np.zeros(7, dtype=int), np.full(7, 3), np.array([0, 2, 2, 9, 12, 1, 0])):
            np.testing.assert_array_equal(_delayed(u, perm, lags, u_rest), _reference(u, perm, lags, u_rest))
    out = _delayed(u, np.arange(7), np.full(7, 2), u_rest)
    np.testing.assert_array_equal(out[:, :2], np.repeat(u_rest[:, None], 2, axis=1))
    np.testing.assert_array_equal(out[:, 2:], u[:, :7])
