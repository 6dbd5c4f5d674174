"""Experiment records for identification: validation, decimation and the one batch the twin works on.

A record is an :class:`gbo_envs.experiment.Experiment` (docs/design.md,
"The experiment record"): equal-length float arrays ``t, r, u, y`` with ``t`` the
time since the reference step in s, ``r`` the reference (its last value is the
post-step level ``r2``), ``u`` the commanded plant input and ``y`` the measured
output. Identification needs a uniform time grid, so :func:`as_records` checks that too.

Records come in as Experiments (or the forms :func:`as_records` converts once, at the edge);
inside the twin they live as one :class:`Batch`: the records stacked into padded, masked rows
with how each one starts. It is the first stage of the workbench's pipeline (records, linear
fit, candidates, fits, ranking, report), and SRIVC (:func:`agents.twin.identify.identify`) reads
its rows of equal length (:meth:`Batch.groups`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from agents.twin.initial import InitialConditions, initial_conditions
from agents.twin.record_checks import check_magnitudes, warn_if_non_causal
from gbo_envs.experiment import SIGNALS, Experiment, RecordError, validate_signals

__all__ = ["BATCH_SAMPLES", "Batch", "MAX_HOLD_SPREAD", "UNIFORM_RTOL", "as_batch", "as_records", "decimate",
           "decimate_records", "hold_spread"]

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
#: Most samples (records times steps) in one group of SRIVC's filters (:meth:`Batch.groups`).
BATCH_SAMPLES = 2**18


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
            raise exc.at(f"record {i + 1}") from None  # counted from 1, as the experiments
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
    return _hold_spread(record.u, stride)


def _hold_spread(u: np.ndarray, stride: int) -> float:
    """:func:`hold_spread` of the command ``u`` (one record's samples, in order)."""
    m = (u.size // stride) * stride
    held = u[:m].reshape(-1, stride)
    within = float(np.sqrt(np.mean((held - held.mean(axis=1, keepdims=True)) ** 2)))
    excursion = float(np.sqrt(np.mean((u[:m] - u[-1]) ** 2)))
    return within / excursion if excursion > 0.0 else 0.0


def _common_stride(inputs: Sequence[np.ndarray], n_samples: int) -> tuple[int, int]:
    """The stride of :func:`decimate_records` for records with the commands ``inputs``, and the samples it keeps of
    each record.

    The first stride is the largest that keeps ``n_samples`` samples of the shortest record; it is shortened while
    a :func:`hold_spread` exceeds :data:`MAX_HOLD_SPREAD` (``<= 1``: keep the records whole), and keeps the samples
    within the time span of the first (as many of every record, as no record is shorter than that span).
    """
    first = min((u.size - 1) // (n_samples - 1) for u in inputs)
    stride = first
    while stride > 1 and max(_hold_spread(u, stride) for u in inputs) > MAX_HOLD_SPREAD:
        stride -= 1
    return stride, (n_samples - 1) * first // max(stride, 1) + 1


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
    stride, kept = _common_stride([rec.u for rec in records], n_samples)
    if stride <= 1:
        return records
    return [_keep_every(rec, stride, mean_input, kept) for rec in records]


@dataclass(frozen=True, eq=False)
class Batch:
    """Validated records stacked into padded, masked rows: the one form the twin's records take inside it.

    Made by :meth:`from_records` from :class:`~gbo_envs.Experiment` records (or the forms
    :func:`as_records` accepts), validated there once; its arrays are read-only.

    Attributes
    ----------
    t, r, u, y : ndarray of shape (n_records, n_steps)
        Time (s), reference, commanded input and measured output; padded with the last value (``t`` with
        its grid).
    mask : ndarray of bool, shape (n_records, n_steps)
        True on real samples, which lead each row (the padding follows them).
    dt : float
        Common sample time in s.
    index : ndarray of int, shape (n_records,)
        Experiment index of each record (0 for the first; used by ``drift``).
    first_index : int, default 0
        The 0-based :attr:`~gbo_envs.Experiment.index` of the experiment whose ``index`` is 0.
        ``numbers`` (``index + first_index + 1``) are the experiment numbers a person reads:
        counted from 1, as in the workbench CSV (docs/design.md, "Experiment numbers").
    initial : InitialConditions, optional
        How each record starts (:mod:`agents.twin.initial`): at a rest its data show (the rest
        level and command are pinned), at an unobserved rest, or moving; default: detected.
    decimated_to : int or None, default None
        The ``n_samples`` per record :meth:`from_records` decimated the records to (:func:`decimate_records`, with
        the mean input over each hold); ``None``: the records as given.
    """

    t: np.ndarray
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    mask: np.ndarray
    dt: float
    index: np.ndarray
    first_index: int = 0
    initial: InitialConditions | None = None
    decimated_to: int | None = None

    def __post_init__(self) -> None:
        if self.initial is None:
            object.__setattr__(self, "initial", initial_conditions(self.r, self.u, self.y, self.mask))
        closed = np.array([not np.array_equal(self.r[k][self.mask[k]], self.u[k][self.mask[k]])
                           for k in range(self.u.shape[0])])
        # per record: the largest |y| (padding included) and whether it is padded, for the residual's fast path
        extent = np.maximum(self.y.max(axis=1), -self.y.min(axis=1)) if self.y.size else np.zeros(0)
        padded = ~self.mask.all(axis=1)
        lengths = self.mask.sum(axis=1)
        for array in (closed, extent, padded, lengths):
            array.setflags(write=False)
        object.__setattr__(self, "_closed", closed)
        object.__setattr__(self, "_extent", extent)
        object.__setattr__(self, "_padded", padded)
        object.__setattr__(self, "_lengths", lengths)

    @classmethod
    def from_records(cls, records, experiment_index: Sequence[int] | None = None, initial: str = "auto", *,
                     n_samples: int | None = None) -> Batch:
        """Validate records (:func:`as_records`) and stack them into read-only arrays.

        Parameters
        ----------
        records : Experiment, mapping, sequence of those or of arrays, or pandas.DataFrame
            As :func:`as_records` takes them; every record with one sample time.
        experiment_index : sequence of int, optional
            Default: the records' :attr:`~gbo_envs.Experiment.index` as :func:`as_records` sets it.
        initial : str, default "auto"
            How the records start (:func:`agents.twin.initial.initial_conditions`: ``"auto"`` detects it).
        n_samples : int, optional
            Decimate the records to about ``n_samples`` samples each first, with the mean input over each
            hold (:func:`decimate_records`); ``None`` keeps every sample.

        Raises
        ------
        ValueError
            Bad records (:func:`as_records`), records of different sample times, an ``experiment_index``
            of another length, or values the fit cannot square (:func:`~agents.twin.record_checks.check_magnitudes`).

        Warns
        -----
        agents.twin.record_checks.NonCausalRecordWarning
            Records whose output answers their input in the same sample (not tested with ``n_samples``).
        """
        return cls.stack(as_records(records, min_steps=3), experiment_index, initial, n_samples=n_samples)

    @classmethod
    def stack(cls, records: Sequence[Experiment], experiment_index: Sequence[int] | None = None,
              initial: str = "auto", *, n_samples: int | None = None) -> Batch:
        """Stack records that :func:`as_records` validated into read-only arrays, without validating them again.

        Parameters
        ----------
        records : sequence of Experiment
            Records as :func:`as_records` returns them (or copies of those with other gains, cost or
            index, :meth:`~gbo_envs.Experiment.replace`).
        experiment_index, initial, n_samples
            As in :meth:`from_records`.

        Raises
        ------
        ValueError
            As in :meth:`from_records`, but for the checks of :func:`as_records`.

        Warns
        -----
        agents.twin.record_checks.NonCausalRecordWarning
            As in :meth:`from_records`.
        """
        data = list(records)
        if n_samples is not None:
            data = decimate_records(data, n_samples, mean_input=True)  # uniform samples of validated records
        dts = np.array([rec.dt for rec in data])
        if np.any(np.abs(dts - dts[0]) > 1e-6 * dts[0]):
            k = int(np.argmax(np.abs(dts - dts[0]) > 1e-6 * dts[0]))  # numbered from 1, as in the CSV
            raise ValueError(f"records: every experiment must have the same sample time; experiment "
                             f"{data[0].index + 1} has {dts[0]:g} s, experiment {data[k].index + 1} {dts[k]:g} s")
        if experiment_index is None:
            experiment_index = [rec.index for rec in data]
        index = np.asarray(list(experiment_index), dtype=int)
        if index.size != len(data):
            raise ValueError(f"experiment_index: need {len(data)} values, got {index.size}")
        first = int(index.min())
        arrays, mask = _stacked(data, grid=True)
        check_magnitudes(arrays, index + 1)
        start = initial_conditions(arrays["r"], arrays["u"], arrays["y"], mask, initial)
        batch = cls(**arrays, mask=mask, dt=float(dts[0]), index=index - first, first_index=first, initial=start,
                    decimated_to=n_samples)
        if n_samples is None:  # a closed loop's held mean input answers the outputs within the hold: not tested
            warn_if_non_causal(batch)
        return batch

    @property
    def closed_loop(self) -> np.ndarray:
        """Records with a controller (``r`` not equal to ``u``), bool of shape (n_records,) (read-only)."""
        return self._closed

    @property
    def n_records(self) -> int:
        """Number of records."""
        return self.u.shape[0]

    @property
    def numbers(self) -> np.ndarray:
        """Experiment number of each record, counted from 1 (the workbench CSV's ``experiment`` id)."""
        return self.index + self.first_index + 1

    @property
    def n_samples(self) -> int:
        """Real samples in all."""
        return int(self.mask.sum())

    @property
    def lengths(self) -> np.ndarray:
        """Real samples of each record, int of shape (n_records,) (read-only)."""
        return self._lengths

    def record_dt(self, k: int) -> float:
        """Mean sample time of record ``k`` in s, ``(t_last - t_first) / (n - 1)`` over its real samples
        (:attr:`gbo_envs.Experiment.dt`)."""
        m = int(self._lengths[k])
        return float((self.t[k, m - 1] - self.t[k, 0]) / (m - 1))

    def span(self, k: int) -> float:
        """Time from record ``k``'s first real sample to its last, s."""
        return float(self.t[k, int(self._lengths[k]) - 1] - self.t[k, 0])

    def y_extent(self, rows: np.ndarray) -> float:
        """``max |y|`` over the records ``rows`` (their padding included), units of ``y``."""
        return float(self._extent.max()) if self.is_all(rows) else float(self._extent[rows].max())

    def padded(self, rows: np.ndarray) -> bool:
        """Whether any of the records ``rows`` is shorter than the longest (has masked padding)."""
        return bool(self._padded.any()) if self.is_all(rows) else bool(self._padded[rows].any())

    def rows_of(self, array: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """``array[rows]`` (an array of this batch's shape), a view, not a copy, when ``rows`` are consecutive."""
        if rows.size and rows[-1] - rows[0] == rows.size - 1 and np.all(np.diff(rows) == 1):
            return array[rows[0]: rows[-1] + 1]
        return array[rows]

    def is_all(self, rows: np.ndarray) -> bool:
        """Whether ``rows`` are all the records in order (so that the arrays serve as they are, uncopied)."""
        return rows.size == self.n_records and np.array_equal(rows, np.arange(rows.size))

    def subset(self, rows: Sequence[int]) -> Batch:
        """The records ``rows`` (experiment indices kept)."""
        rows = np.asarray(rows, dtype=int)
        return Batch(self.t[rows], self.r[rows], self.u[rows], self.y[rows], self.mask[rows], self.dt,
                     self.index[rows], self.first_index, self.initial.subset(rows), self.decimated_to)

    def with_input(self, u: np.ndarray) -> Batch:
        """The records with the input ``u`` (shape of :attr:`u`; e.g. the plant input an actuator block makes of
        the command), their starts kept.

        Raises
        ------
        ValueError
            ``u`` is not finite on a real sample (naming the record).
        """
        u = np.asarray(u, dtype=float)
        bad = ~np.all(np.isfinite(u) | ~self.mask, axis=1)
        if bad.any():
            raise RecordError("u", f"non-finite value(s) in experiment {int(self.numbers[np.argmax(bad)])}")
        u.setflags(write=False)
        return dataclasses.replace(self, u=u)

    def thinned(self, n_samples: int | None, mean_input: bool = False) -> Batch:
        """The records decimated to about ``n_samples`` samples each, their starts kept; this batch when nothing is
        dropped.

        The samples :func:`decimate_records` keeps (one stride for all records, shortened while the command moves
        within a hold, as many samples of each), taken from the rows: their times and values as they are.

        Parameters
        ----------
        n_samples : int or None
            Samples to keep per record at most the stride allows, ``>= 2``; ``None`` keeps the records.
        mean_input : bool, default False
            Give each kept sample the mean of ``u`` over its hold interval (:func:`decimate`).

        Returns
        -------
        Batch
            Its ``dt`` is this batch's sample time in s; :meth:`record_dt` gives a row's thinned one.
        """
        if n_samples is None:
            return self
        lengths = self._lengths
        stride, kept = _common_stride([self.u[k, : lengths[k]] for k in range(self.n_records)], n_samples)
        if stride <= 1:
            return self
        idx = np.arange(kept) * stride  # every row keeps as many samples, on one grid: no padding
        arrays = {name: getattr(self, name)[:, idx] for name in ("t", "r", "u", "y")}
        if mean_input:
            total = np.concatenate([np.zeros((self.n_records, 1)), np.cumsum(self.u, axis=1)], axis=1)
            end = np.minimum(idx + stride, lengths[:, None])
            arrays["u"] = (np.take_along_axis(total, end, axis=1) - total[:, idx]) / (end - idx)
        mask = np.ones((self.n_records, kept), dtype=bool)
        for array in (*arrays.values(), mask):
            array.setflags(write=False)
        return Batch(**arrays, mask=mask, dt=self.dt, index=self.index, first_index=self.first_index,
                     initial=self.initial)

    def groups(self, max_samples: int = BATCH_SAMPLES) -> list[np.ndarray]:
        """The records in groups of one length and sample time, each at most ``max_samples`` samples (a record
        longer than that is a group alone): the rows SRIVC's filters stack (:func:`agents.twin.srivc.prepare`).

        Returns
        -------
        list of ndarray of int
            The rows of each group, in the order of their first record.
        """
        keys: dict[tuple[int, float], list[int]] = {}
        for k in range(self.n_records):
            keys.setdefault((int(self._lengths[k]), round(self.record_dt(k), 12)), []).append(k)
        out = []
        for (n_steps, _), group in keys.items():
            size = max(1, max_samples // n_steps)
            out.extend(np.array(group[start : start + size]) for start in range(0, len(group), size))
        return out


def as_batch(records, n_samples: int | None = None) -> Batch:
    """The records as one :class:`Batch`, decimated to ``n_samples``: a batch as it is, other records stacked once.

    Parameters
    ----------
    records : Batch, or records as :func:`as_records` takes them
        A batch is taken as it is when ``n_samples`` is ``None`` or the one it was stacked with
        (:attr:`Batch.decimated_to`); other records are validated and stacked by :meth:`Batch.from_records`.
    n_samples : int, optional
        Samples per record, ``>= 2`` (:func:`decimate_records`, with the mean input over each hold);
        ``None`` keeps every sample.

    Raises
    ------
    ValueError
        A batch stacked with another ``n_samples``, or bad records (:meth:`Batch.from_records`).
    """
    if not isinstance(records, Batch):
        return Batch.from_records(records, n_samples=n_samples)
    if n_samples is not None and records.decimated_to != n_samples:
        raise ValueError(f"n_samples: must be None, or the n_samples the records were stacked with "
                         f"(Batch.from_records(records, n_samples={n_samples})), when they are given as a Batch; "
                         f"got n_samples={n_samples} for a batch stacked with n_samples={records.decimated_to}")
    return records


def _stacked(records: Sequence[Experiment], grid: bool) -> tuple[dict, np.ndarray]:
    """``t, r, u, y`` of ``records`` stacked into read-only rows padded with the last value, and the mask of the
    real samples. ``grid``: every row's ``t`` is its first time plus multiples of its sample time; else the
    record's own times, the padding on from the last by its sample time."""
    n = max(rec.n_steps for rec in records)
    arrays = {name: np.empty((len(records), n)) for name in SIGNALS}
    mask = np.zeros((len(records), n), dtype=bool)
    for k, rec in enumerate(records):
        m = rec.n_steps
        mask[k, :m] = True
        for name in ("r", "u", "y"):
            arrays[name][k, :m] = getattr(rec, name)
            arrays[name][k, m:] = getattr(rec, name)[-1]
        if grid:
            arrays["t"][k] = rec.t[0] + np.arange(n) * rec.dt
        else:
            arrays["t"][k, :m] = rec.t
            arrays["t"][k, m:] = rec.t[-1] + np.arange(1, n - m + 1) * rec.dt
    for array in (*arrays.values(), mask):  # read-only: records of their rows share them, uncopied
        array.setflags(write=False)
    return arrays, mask
