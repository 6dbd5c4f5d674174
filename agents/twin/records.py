"""Experiment records for identification: validation, decimation and batching.

A record is an :class:`gbo_envs.experiment.Experiment` (docs/design.md,
"The experiment record"): equal-length float arrays ``t, r, u, y`` with ``t`` the
time since the reference step in s, ``r`` the reference (its last value is the
post-step level ``r2``), ``u`` the commanded plant input and ``y`` the measured
output. Every record starts at rest at the pre-step level. Identification
needs a uniform time grid, so :func:`as_records` checks that too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from gbo_envs.experiment import SIGNALS, Experiment, RecordError, validate_signals

__all__ = ["BATCH_SAMPLES", "Batch", "MAX_HOLD_SPREAD", "UNIFORM_RTOL", "as_records", "decimate", "decimate_records",
           "hold_spread", "make_batches"]

#: Largest relative deviation of a sample step from the median step that identification accepts.
UNIFORM_RTOL = 1e-6
#: Largest :func:`hold_spread` of the command that :func:`decimate_records` accepts: a longer hold interval
#: is shortened. Over the corners and 40 random gains of each feasible set, the DC motors' records
#: (2,500 samples, stride 25) spread at most 0.047; the linear motors' near bang-bang moves (301 samples)
#: 0.43-0.49 at stride 3 and 0.31-0.36 at stride 2. There the mean of a saturated command over a hold is
#: not the saturated mean: on LinearMotorRig-v0 the true model replayed 100 of 301 samples 2.2 % of the
#: step off (0.018 % on the whole record), and on LinearMotor-v0 the diagnosed twin put the 7 A drive
#: limit at 38 A (on the whole records: 7.000 A, gain and pole within 0.01 %).
MAX_HOLD_SPREAD = 0.15
#: Most samples (records times steps) stacked in one SRIVC batch (:func:`make_batches`).
BATCH_SAMPLES = 2**18


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


def as_records(records, min_steps: int = 3) -> list[Experiment]:
    """Validate experiment records for identification and return them as :class:`~gbo_envs.Experiment` objects.

    Parameters
    ----------
    records : Experiment, mapping, sequence of those or of arrays, or pandas.DataFrame
        One record (an :class:`~gbo_envs.Experiment`, or a mapping with keys
        ``t, r, u, y`` such as an env ``info``; other keys are read as by
        :meth:`~gbo_envs.Experiment.from_mapping`), a sequence of such records
        or of arrays of shape (n_steps, 4) with the columns ``t, r, u, y``, or
        a DataFrame with columns ``t, r, u, y`` and, for several experiments,
        an ``experiment`` column (the CSV contract).
    min_steps : int, default 3
        Fewest samples a record may have.

    Returns
    -------
    list of Experiment
        With signals on a uniform time grid (within :data:`UNIFORM_RTOL`).
        ``index`` is each record's own (an Experiment's ``index``, a mapping's
        ``experiment_index``, a DataFrame's ``experiment`` number minus 1, as the
        CSV's numbers count from 1) when every record
        has one, else the position in ``records``.

    Raises
    ------
    ValueError
        Empty input, a missing field, arrays of unequal length or too short,
        NaN/inf values, or a time vector that is not uniformly increasing; the
        message names the record and the field
        (:func:`gbo_envs.experiment.validate_signals`).
    """
    items = _split(records)
    if len(items) == 0:
        raise ValueError("records: need at least one experiment record, got none")
    out, own_index = [], True
    for i, item in enumerate(items):
        try:
            record, has_index = _validated(item, min_steps)
        except RecordError as exc:
            raise exc.at(f"record {i}") from None
        out.append(record)
        own_index = own_index and has_index
    if not own_index:
        out = [record.replace(index=i) for i, record in enumerate(out)]
    return out


def _split(records) -> list:
    if hasattr(records, "groupby") and hasattr(records, "columns"):  # pandas DataFrame
        if "experiment" in records.columns:
            return [group for _, group in records.groupby("experiment", sort=False)]
        return [records]
    if isinstance(records, (Mapping, Experiment)):
        return [records]
    if isinstance(records, np.ndarray) and records.ndim == 2:
        return [records]
    if isinstance(records, (str, bytes)) or not isinstance(records, (Sequence, np.ndarray)):
        raise ValueError(f"records: expected a record mapping or a sequence of records, got {type(records).__name__}")
    return list(records)


def _validated(item, min_steps: int) -> tuple[Experiment, bool]:
    """The record and whether it carries its own experiment index."""
    if isinstance(item, Experiment):
        if not item.has_signals:
            raise RecordError("t, r, u, y", f"required for identification; {item!r} has none")
        validate_signals(item.t, item.r, item.u, item.y, min_steps=min_steps, uniform_rtol=UNIFORM_RTOL)
        return item, True
    if isinstance(item, Mapping):
        if isinstance(item.get("experiment"), Experiment):
            return _validated(item["experiment"], min_steps)
        missing = [name for name in SIGNALS if name not in item]
        if missing:
            raise RecordError("t, r, u, y", f"missing field(s) {missing}; a record needs t, r, u, y")
        validate_signals(*(item[name] for name in SIGNALS), min_steps=min_steps, uniform_rtol=UNIFORM_RTOL)
        return Experiment.from_mapping(item), "experiment_index" in item
    if hasattr(item, "columns") and hasattr(item, "__getitem__"):  # one experiment of a DataFrame
        missing = [name for name in SIGNALS if name not in item.columns]
        if missing:
            raise RecordError("t, r, u, y", f"missing column(s) {missing}; a record needs t, r, u, y")
        arrays = validate_signals(*(item[name].to_numpy() for name in SIGNALS), min_steps=min_steps,
                                  uniform_rtol=UNIFORM_RTOL)
        has_id = "experiment" in item.columns
        index = int(item["experiment"].iloc[0]) - 1 if has_id else 0  # the column counts from 1
        return Experiment(gains=(), **arrays, index=index), has_id
    try:
        table = np.asarray(item, dtype=float)
    except (TypeError, ValueError):
        raise RecordError("t, r, u, y", "expected a mapping with t, r, u, y or a numeric array") from None
    if table.ndim != 2 or table.shape[1] != 4:
        raise RecordError("t, r, u, y", "an array record must have shape (n_steps, 4) with columns t, r, u, y, "
                                        f"got shape {table.shape}")
    arrays = validate_signals(*table.T, min_steps=min_steps, uniform_rtol=UNIFORM_RTOL)
    return Experiment(gains=(), **arrays), False


def decimate(record: Experiment, n_samples: int | None, mean_input: bool = False) -> Experiment:
    """Keep ``n_samples`` uniformly spaced samples of a record, starting at the step.

    The paper's twin data set keeps ``n_tilde`` samples per experiment, eq. (Ds).
    With ``N`` samples the stride is ``(N - 1) // (n_samples - 1)``, so the kept
    samples are exact measurements on a uniform grid that ends at most one stride
    before the end of the record. ``None`` or ``n_samples >= N`` keeps the record.

    Parameters
    ----------
    record : Experiment
    n_samples : int or None
        Samples to keep, ``>= 2``.
    mean_input : bool, default False
        Give each kept sample the mean of ``u`` over its hold interval (from it to the
        next kept sample) instead of ``u`` at that instant. A zero-order-hold simulation
        at the decimated sample time (the grey-box twin's replay) then applies the same
        input impulse to the plant as the record did; the point sample lags by half a
        stride wherever ``u`` moves, and a model fitted to it makes up for that lag with
        wrong parameters (on DCMotor-v0 with a 138-unit drive limit, 100 of 2,500
        samples: a 4 % lower gain and a 5-unit input offset, and a twin optimum at 3 times
        the plant's optimal cost; with the mean, the true values within 0.05 %).
        The SRIVC fit of :class:`~agents.twin.LinearTwin` interpolates point samples
        (first-order hold) and keeps them.
    """
    if n_samples is None or n_samples >= record.n_steps:
        return record
    return _keep_every(record, (record.n_steps - 1) // (n_samples - 1), mean_input, n_samples)


def _keep_every(record: Experiment, stride: int, mean_input: bool, n_samples: int) -> Experiment:
    """Samples ``0, stride, ..., (n_samples - 1) stride`` of a record."""
    idx = np.arange(n_samples) * stride
    u = record.u[idx]
    if mean_input:
        total = np.concatenate([[0.0], np.cumsum(record.u)])
        end = np.minimum(idx + stride, record.n_steps)
        u = (total[end] - total[idx]) / (end - idx)
    return dataclasses.replace(record, t=record.t[idx], r=record.r[idx], u=u, y=record.y[idx])


def hold_spread(record: Experiment, stride: int) -> float:
    r"""How much the command moves within hold intervals of ``stride`` samples, relative to its excursion.

    .. math:: \frac{\operatorname{rms}_{j,i}\left(u_{j s + i} - \bar u_j\right)}
              {\operatorname{rms}_t\left(u_t - u_{N-1}\right)}

    with ``\bar u_j`` the mean over hold interval ``j`` (the input :func:`decimate` keeps with
    ``mean_input=True``). A linear plant sees the same input impulse either way; an actuator
    nonlinearity (a drive limit, a dead zone) sees the mean instead of the samples, which is
    the same only when this is small. ``0.0`` for a constant command.
    """
    m = (record.n_steps // stride) * stride
    held = record.u[:m].reshape(-1, stride)
    within = float(np.sqrt(np.mean((held - held.mean(axis=1, keepdims=True)) ** 2)))
    excursion = float(np.sqrt(np.mean((record.u[:m] - record.u[-1]) ** 2)))
    return within / excursion if excursion > 0.0 else 0.0


def decimate_records(records: Sequence[Experiment], n_samples: int | None,
                     mean_input: bool = False) -> list[Experiment]:
    """:func:`decimate` all records with one stride, shortened while the command moves within a hold.

    The stride is the largest that keeps ``n_samples`` samples of the shortest record (so
    that every record keeps the same sample time), reduced until the
    :func:`hold_spread` of every record is at most :data:`MAX_HOLD_SPREAD`; at stride 1
    the records are kept whole. The input of a kept sample (its mean over the hold with
    ``mean_input``, else its value) then stands for the samples it replaces, through an
    actuator nonlinearity too. A shortened stride keeps the time span of the first one
    (more samples).

    Parameters
    ----------
    records : sequence of Experiment
    n_samples : int or None
        Samples to keep per record at most the stride allows, ``>= 2``; ``None`` keeps the records.
    mean_input : bool, default False
        As in :func:`decimate`.
    """
    records = list(records)
    if n_samples is None or not records:
        return records
    first = min((rec.n_steps - 1) // (n_samples - 1) for rec in records)
    stride = first
    while stride > 1 and max(hold_spread(rec, stride) for rec in records) > MAX_HOLD_SPREAD:
        stride -= 1
    if stride <= 1:
        return records
    span = (n_samples - 1) * first  # the time the first stride's n_samples cover, in samples
    return [_keep_every(rec, stride, mean_input, min((rec.n_steps - 1) // stride, span // stride) + 1)
            for rec in records]


def make_batches(records: list[Experiment], max_samples: int = BATCH_SAMPLES) -> list[Batch]:
    """Group records by (length, sample time) and stack each group, in batches of at most ``max_samples`` samples.

    A group larger than ``max_samples`` is split (a record longer than it is a batch alone), so that
    the filters of SRIVC work on bounded arrays however many records there are.
    """
    groups: dict[tuple[int, float], list[int]] = {}
    for i, rec in enumerate(records):
        key = (rec.n_steps, round(rec.dt, 12))
        groups.setdefault(key, []).append(i)
    batches = []
    for (n_steps, _), group in groups.items():
        size = max(1, max_samples // n_steps)
        for start in range(0, len(group), size):
            batches.append(_stack(records, group[start : start + size]))
    return batches


def _stack(records: list[Experiment], members: list[int]) -> Batch:
    """The records ``members`` stacked into one batch."""
    return Batch(dt=float(records[members[0]].dt), u=np.stack([records[i].u for i in members]),
                 y=np.stack([records[i].y for i in members]), r2=np.array([records[i].r[-1] for i in members]),
                 index=np.array(members))
