"""Simulate grey-box models on their records: many ``(structure, parameters, records)`` sets per vectorised pass.

The rows of a pass do not interact (each row is one record under one model), so the
grouping of sets into passes changes no value; it bounds the memory of a pass
(:data:`SIMULATION_BATCH_SAMPLES`) and shares the per-call overhead of the time loop.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from agents.twin.model import ModelSpec
from agents.twin.open_loop import simulate_open_loop
from agents.twin.records import Batch

__all__ = ["SIMULATION_BATCH_SAMPLES", "simulate_both", "simulate_sets"]

#: Most samples (records times steps) simulated in one vectorised pass (about 8 MB per signal).
SIMULATION_BATCH_SAMPLES = 2**20
#: Passes simulated at the same time, in threads: the compiled stepping and ``scipy.signal.lfilter`` release
#: the GIL, so on two cores two passes take little more than one.
SIMULATION_THREADS = min(2, os.cpu_count() or 1)


def simulate_sets(data: Batch, sets: Sequence[tuple[ModelSpec, np.ndarray, np.ndarray]],
                  true_output: bool = False) -> list[np.ndarray]:
    """Simulated measurements of many ``(spec, theta, rows)`` sets in one vectorised pass.

    ``true_output=True`` returns the plant output before the sensor blocks
    (smooth in the parameters even when the sensor quantizes).

    Returns
    -------
    list of ndarray of shape (len(rows), n_steps)
        ``nan`` rows where a parameter set is invalid (e.g. an unstable plant).
    """
    return [pair[1 if true_output else 0] for pair in simulate_both(data, sets)]


def simulate_both(data: Batch, sets: Sequence[tuple[ModelSpec, np.ndarray, np.ndarray]]) -> list[tuple]:
    """``(measurement, plant output before the sensors)`` of each set, in vectorised passes.

    Consecutive sets are simulated together up to :data:`SIMULATION_BATCH_SAMPLES` samples
    (a larger set alone, a few records at a time), so that the memory of one pass is bounded;
    up to :data:`SIMULATION_THREADS` passes run at the same time. The rows of a pass do not
    interact, so neither the grouping nor the threads change the values.
    """
    n_steps = data.u.shape[1]
    passes, batch, size = [], [], 0
    for one in sets:
        if batch and size + one[2].size * n_steps > SIMULATION_BATCH_SAMPLES:
            passes.append(batch)
            batch, size = [], 0
        if one[2].size * n_steps > SIMULATION_BATCH_SAMPLES:
            passes.append(one)  # a set alone, in parts
        else:
            batch.append(one)
            size += one[2].size * n_steps
    if batch:
        passes.append(batch)

    def run(item) -> list[tuple]:
        return [_simulate_in_parts(data, *item)] if isinstance(item, tuple) else _simulate_batch(data, item)

    if len(passes) > 1 and SIMULATION_THREADS > 1:
        with ThreadPoolExecutor(max_workers=SIMULATION_THREADS) as pool:
            results = list(pool.map(run, passes))
    else:
        results = [run(item) for item in passes]
    return [pair for result in results for pair in result]


def _simulate_in_parts(data: Batch, spec: ModelSpec, theta: np.ndarray, rows: np.ndarray) -> tuple:
    """``(measurement, plant output before the sensors)`` of one large set, a few records per pass."""
    k, n_steps = rows.size, data.u.shape[1]
    g = spec.n_global
    y0, bias, start = _nuisance(theta[g:], k)
    y, y_true = np.empty((k, n_steps)), np.empty((k, n_steps))
    per_pass = max(1, SIMULATION_BATCH_SAMPLES // n_steps)
    for first in range(0, k, per_pass):
        part = slice(first, first + per_pass)
        piece = np.concatenate([theta[:g], y0[part], bias[part], start[part].ravel()])
        y[part], y_true[part] = _simulate_batch(data, [(spec, piece, rows[part])])[0]
    return y, y_true


def _nuisance(tail: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(y0, bias, start)`` of ``k`` records from the parameters after the global ones (``start``: (k, m))."""
    m = tail.size // k - 2
    return tail[:k], tail[k : 2 * k], tail[2 * k :].reshape(k, m)


def _simulate_batch(data: Batch, sets: Sequence[tuple[ModelSpec, np.ndarray, np.ndarray]]) -> list[tuple]:
    """``(measurement, plant output before the sensors)`` of each set, in one vectorised pass.

    Every row replays its record's commands in ``data.u`` itself (``command_rows``, no copy of them),
    and each set's outputs are its rows of the pass's outputs (views: a set's rows are contiguous).
    """
    plants, chains, commands, y0, bias, start, index, spans = [], [], [], [], [], [], [], []
    first = 0
    for spec, theta, rows in sets:
        k = rows.size
        g = spec.n_global
        try:
            plant = spec.plant(theta[:g])
            blocks = spec.blocks(theta[:g])
        except ValueError:
            spans.append(None)
            continue
        plants += [plant] * k
        chains += [blocks] * k
        commands.append(rows)
        rest_level, rest_bias, moving = _nuisance(theta[g:], k)
        y0.append(rest_level)
        bias.append(rest_bias)
        start.append(moving)
        index.append(data.index[rows])
        spans.append(slice(first, first + k))
        first += k
    out: list = [None] * len(sets)
    if first:
        try:
            with np.errstate(all="ignore"):
                width = max(m.shape[1] for m in start)
                initial = None if width == 0 else np.concatenate(
                    [np.pad(m, ((0, 0), (0, width - m.shape[1]))) for m in start])
                res = simulate_open_loop(plants, data.u, data.dt, chains, y0=np.concatenate(y0),
                                         bias=np.concatenate(bias), experiment_index=np.concatenate(index),
                                         initial=initial, command_rows=np.concatenate(commands))
        except (np.linalg.LinAlgError, ValueError):  # a plant that cannot be sampled (overflowing coefficients)
            if len(sets) > 1:
                return [_simulate_batch(data, [one])[0] for one in sets]
        else:
            for s, span in enumerate(spans):
                if span is not None:
                    out[s] = (res.y[span], res.y_true[span])
    return [(np.full((rows.size, data.u.shape[1]), np.nan),) * 2 if pair is None else pair
            for pair, (_, _, rows) in zip(out, sets)]
