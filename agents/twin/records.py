"""Closed-loop experiment records: validation, decimation and batching for identification.

A record is one step experiment as an env ``step`` reports it in ``info``
(docs/design.md, "The experiment record"): equal-length float arrays ``t, r, u, y`` with
``t`` the time since the reference step in s, ``r`` the reference (its last
value is the post-step level ``r2``), ``u`` the commanded plant input and ``y``
the measured output. Every record starts at rest at the pre-step level.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Record", "Batch", "as_records", "decimate", "make_batches"]

_FIELDS = ("t", "r", "u", "y")


@dataclass(frozen=True, eq=False)
class Record:
    """One validated experiment.

    Attributes
    ----------
    t, r, u, y : ndarray of shape (n_steps,)
        Time in s (uniformly sampled, increasing), reference, commanded input, measured output.
    dt : float
        Sample time in s.
    """

    t: np.ndarray
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    dt: float

    @property
    def n_steps(self) -> int:
        """Number of samples."""
        return self.t.size


@dataclass(frozen=True, eq=False)
class Batch:
    """Records of equal length and sample time, stacked for vectorised filtering.

    Attributes
    ----------
    dt : float
        Sample time in s.
    u, y, r2 : ndarray of shape (n_records, n_steps), (n_records, n_steps), (n_records,)
        Stacked input, output and post-step reference level.
    index : ndarray of int, shape (n_records,)
        Position of each record in the validated list.
    """

    dt: float
    u: np.ndarray
    y: np.ndarray
    r2: np.ndarray
    index: np.ndarray

    @property
    def n_steps(self) -> int:
        """Samples per record."""
        return self.u.shape[1]


def as_records(records, min_steps: int = 3) -> list[Record]:
    """Validate experiment records and return them as :class:`Record` objects.

    Parameters
    ----------
    records : mapping, sequence of mappings or arrays, or pandas.DataFrame
        One record (a mapping with keys ``t, r, u, y``, extra keys ignored), a
        sequence of such mappings or of arrays of shape (n_steps, 4) with the
        columns ``t, r, u, y``, or a DataFrame with columns ``t, r, u, y`` and,
        for several experiments, an ``experiment`` column (the CSV contract).
    min_steps : int, default 3
        Fewest samples a record may have.

    Returns
    -------
    list of Record

    Raises
    ------
    ValueError
        Empty input, a missing field, arrays of unequal length or too short,
        NaN/inf values, or a time vector that is not uniformly increasing; the
        message names the record and the field.
    """
    items = _split(records)
    if len(items) == 0:
        raise ValueError("records: need at least one experiment record, got none")
    return [_validated(i, item, min_steps) for i, item in enumerate(items)]


def _split(records) -> list:
    if hasattr(records, "groupby") and hasattr(records, "columns"):  # pandas DataFrame
        if "experiment" in records.columns:
            return [group for _, group in records.groupby("experiment", sort=False)]
        return [records]
    if isinstance(records, Mapping):
        return [records]
    if isinstance(records, np.ndarray) and records.ndim == 2:
        return [records]
    if isinstance(records, (str, bytes)) or not isinstance(records, (Sequence, np.ndarray)):
        raise ValueError(f"records: expected a record mapping or a sequence of records, got {type(records).__name__}")
    return list(records)


def _validated(index: int, item, min_steps: int) -> Record:
    where = f"record {index}"
    if isinstance(item, Mapping) or (hasattr(item, "columns") and hasattr(item, "__getitem__")):
        missing = [name for name in _FIELDS if name not in item]
        if missing:
            raise ValueError(f"{where}: missing field(s) {missing}; a record needs t, r, u, y")
        arrays = {}
        for name in _FIELDS:
            try:
                arrays[name] = np.asarray(item[name], dtype=float)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"{where}, field {name!r}: not numeric") from exc
    else:
        try:
            table = np.asarray(item, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: expected a mapping with t, r, u, y or a numeric array") from exc
        if table.ndim != 2 or table.shape[1] != 4:
            raise ValueError(f"{where}: an array record must have shape (n_steps, 4) with columns t, r, u, y, "
                             f"got shape {table.shape}")
        arrays = {name: table[:, j] for j, name in enumerate(_FIELDS)}
    for name, values in arrays.items():
        if values.ndim != 1:
            raise ValueError(f"{where}, field {name!r}: expected a 1-D array, got shape {values.shape}")
    lengths = {name: values.size for name, values in arrays.items()}
    if len(set(lengths.values())) != 1:
        raise ValueError(f"{where}: t, r, u, y must have equal lengths, got {lengths}")
    n = lengths["t"]
    if n < min_steps:
        raise ValueError(f"{where}: needs at least {min_steps} samples, got {n}")
    for name, values in arrays.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise ValueError(f"{where}, field {name!r}: non-finite value {values[bad[0]]} at sample {bad[0]}")
    t = arrays["t"]
    steps = np.diff(t)
    dt = (t[-1] - t[0]) / (n - 1)
    if dt <= 0.0 or np.any(steps <= 0.0):
        first = int(np.flatnonzero(steps <= 0.0)[0]) + 1 if np.any(steps <= 0.0) else 1
        raise ValueError(f"{where}, field 't': time must increase, it does not at sample {first}")
    if np.max(np.abs(steps - dt)) > 1e-6 * dt:
        worst = int(np.argmax(np.abs(steps - dt))) + 1
        raise ValueError(f"{where}, field 't': samples must be uniformly spaced (dt = {dt:g} s), "
                         f"they are not at sample {worst}")
    return Record(t=t, r=arrays["r"], u=arrays["u"], y=arrays["y"], dt=float(dt))


def decimate(record: Record, n_samples: int | None) -> Record:
    """Keep ``n_samples`` uniformly spaced samples of a record, starting at the step.

    The paper's twin data set keeps ``n_tilde`` samples per experiment, eq. (Ds).
    With ``N`` samples the stride is ``(N - 1) // (n_samples - 1)``, so the kept
    samples are exact measurements on a uniform grid that ends at most one stride
    before the end of the record. ``None`` or ``n_samples >= N`` keeps the record.
    """
    if n_samples is None or n_samples >= record.n_steps:
        return record
    stride = (record.n_steps - 1) // (n_samples - 1)
    idx = np.arange(n_samples) * stride
    return Record(t=record.t[idx], r=record.r[idx], u=record.u[idx], y=record.y[idx], dt=record.dt * stride)


def make_batches(records: list[Record]) -> list[Batch]:
    """Group records by (length, sample time) and stack each group."""
    groups: dict[tuple[int, float], list[int]] = {}
    for i, rec in enumerate(records):
        key = (rec.n_steps, round(rec.dt, 12))
        groups.setdefault(key, []).append(i)
    batches = []
    for members in groups.values():
        batches.append(Batch(
            dt=float(records[members[0]].dt),
            u=np.stack([records[i].u for i in members]),
            y=np.stack([records[i].y for i in members]),
            r2=np.array([records[i].r[-1] for i in members]),
            index=np.array(members),
        ))
    return batches
