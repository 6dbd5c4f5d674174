"""One closed-loop step experiment as one record, and the one validator of its signals.

Every part of the project that holds an experiment holds an :class:`Experiment`:
an env ``step`` puts it in ``info["experiment"]``, a tuning result keeps one per
real experiment, a tuning session stores and restores it, and the digital
twin and its workbench CSV read and write it. :func:`validate_signals` is the
only check of ``t, r, u, y``; everything that accepts records calls it, so a
bad record fails the same way, naming the field and the rule, wherever it enters.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from gbo_envs.metrics import METRIC_NAMES

__all__ = ["Experiment", "RecordError", "SIGNALS", "SOURCES", "validate_signals"]

#: The four sampled signals of a record, in this order.
SIGNALS = ("t", "r", "u", "y")
#: Where an experiment ran.
SOURCES = ("plant", "twin")


class RecordError(ValueError):
    """A malformed experiment record.

    Attributes
    ----------
    field : str
        The offending field (``"t"``, ``"gains"``, ... or ``"t, r, u, y"``).
    rule : str
        The rule it breaks, with the offending value.
    sample : int or None
        Index of the first offending sample, when the rule concerns one.
    where : str
        Which record (``"record 3"``), prefixed to the message when given.
    """

    def __init__(self, field: str, rule: str, sample: int | None = None, where: str = "") -> None:
        super().__init__(f"{where + ', ' if where else ''}{field}: {rule}")
        self.field, self.rule, self.sample, self.where = field, rule, sample, where

    def at(self, where: str) -> RecordError:
        """The same error located at ``where`` (e.g. ``"record 3"``)."""
        return RecordError(self.field, self.rule, self.sample, where)


def validate_signals(t, r, u, y, *, min_steps: int = 3, uniform_rtol: float | None = None) -> dict[str, np.ndarray]:
    """Check the signals of one experiment and return them as float arrays.

    Parameters
    ----------
    t : array_like of shape (n_steps,)
        Time since the reference step in s, strictly increasing.
    r, u, y : array_like of shape (n_steps,)
        Reference, commanded plant input and measured output, in the plant's units.
    min_steps : int, default 3
        Fewest samples a record may have, ``>= 2``.
    uniform_rtol : float, optional
        When given, every sample step must lie within ``uniform_rtol`` times the
        median step of it (identification needs a uniform grid); ``None`` allows
        any increasing time, as a rig with jitter delivers.

    Returns
    -------
    dict of str to ndarray
        ``t, r, u, y`` as float64 arrays of shape (n_steps,) (no copy of float64 input).

    Raises
    ------
    RecordError
        A ``ValueError`` naming the field and the rule: non-numeric or not 1-D,
        unequal lengths, fewer than ``min_steps`` samples, a NaN or inf value,
        ``t`` not strictly increasing or (with ``uniform_rtol``) not uniform.
    """
    if isinstance(min_steps, bool) or not isinstance(min_steps, numbers.Integral) or min_steps < 2:
        raise ValueError(f"min_steps: must be an integer >= 2, got {min_steps!r}")
    if uniform_rtol is not None and not (math.isfinite(uniform_rtol) and uniform_rtol > 0):
        raise ValueError(f"uniform_rtol: must be a number > 0 or None, got {uniform_rtol!r}")
    arrays = {}
    for name, values in zip(SIGNALS, (t, r, u, y)):
        try:
            array = np.asarray(values, dtype=np.float64)
        except (TypeError, ValueError):
            raise RecordError(name, f"must be numeric, got {type(values).__name__}") from None
        if array.ndim != 1:
            raise RecordError(name, f"must be a 1-D array of shape (n_steps,), got shape {array.shape}")
        arrays[name] = array
    lengths = {name: array.size for name, array in arrays.items()}
    if len(set(lengths.values())) != 1:
        raise RecordError("t, r, u, y", f"must have equal lengths, got {lengths}")
    n = lengths["t"]
    if n < min_steps:
        raise RecordError("t, r, u, y", f"need at least {min_steps} samples, got {n}", sample=0)
    with np.errstate(over="ignore", invalid="ignore"):
        # fast path: a NaN or inf makes the dot product non-finite (so can overflow, above 1e154: then check exactly)
        faulty = [name for name, array in arrays.items()
                  if not math.isfinite(float(array @ array)) and not np.isfinite(array).all()]
    if faulty:
        name, array = faulty[0], arrays[faulty[0]]
        bad = np.flatnonzero(~np.isfinite(array))
        raise RecordError(name, f"must be finite, got {array[bad[0]]} at sample {bad[0]} "
                                f"({bad.size} non-finite value{'s' if bad.size > 1 else ''})", sample=int(bad[0]))
    time = arrays["t"]
    steps = np.diff(time)
    if steps.min() <= 0.0:
        k = int(np.flatnonzero(steps <= 0.0)[0]) + 1
        raise RecordError("t", f"must increase strictly, got {time[k]:g} s at sample {k} after {time[k - 1]:g} s",
                          sample=k)
    if uniform_rtol is not None:
        dt = float(np.median(steps))
        off = np.flatnonzero(np.abs(steps - dt) > uniform_rtol * dt)
        if off.size:
            k = int(off[0]) + 1
            raise RecordError("t", f"must be uniformly spaced (dt = {dt:g} s), got a step of {steps[k - 1]:g} s "
                                   f"to {time[k]:g} s at sample {k}", sample=k)
    return arrays


@dataclass(frozen=True, eq=False)
class Experiment:
    """One closed-loop step experiment on the plant or on its digital twin.

    Construction validates every field (:func:`validate_signals` for the
    signals) and stores read-only copies (or the arrays themselves when they are
    read-only already, see :func:`_frozen`), so an ``Experiment`` is always sound.
    The signals are optional as a group: a twin evaluation that only computed
    the cost, or a failed plant experiment, has none (:attr:`has_signals`).

    Parameters
    ----------
    gains : array_like of shape (n_gains,)
        Controller gains, in the env's gain units (``env.unwrapped.gain_units``,
        e.g. Kp in 1 and Ki in 1/s for the DC motor's PI); shape (0,) when unknown.
    t : array_like of shape (n_steps,), optional
        Time since the reference step in s, strictly increasing.
    r : array_like of shape (n_steps,), optional
        Reference, in the units of the output (rad/s for a speed loop, m for a
        position loop); its last value is the post-step level.
    u : array_like of shape (n_steps,), optional
        Commanded plant input (the controller output before any actuator
        effect), in the plant's input units.
    y : array_like of shape (n_steps,), optional
        Measured output, in the units of ``r``.
    cost : float, default NaN
        Weighted cost ``J`` of eq. (J_used), dimensionless; NaN when not known
        (e.g. a record read from a CSV without a cost column).
    metrics : mapping or array_like of shape (4,), default {}
        Step-response metrics by name (``overshoot_pct`` in %, ``settling_time``
        and ``rise_time`` in s, ``itae`` in s^2 times the output unit); an
        array is read in :data:`~gbo_envs.metrics.METRIC_NAMES` order. NaN marks
        a metric that could not be measured.
    source : {"plant", "twin"}, default "plant"
        Where the experiment ran.
    index : int, default 0
        Which experiment: the env's 0-based ``experiment_index`` (what
        time-varying plants and the ``drift`` effect count), the experiment id
        of a workbench CSV, or for a twin evaluation the index of the plant
        experiment it was made for.

    Raises
    ------
    RecordError
        A ``ValueError`` naming the field and the rule it breaks.
    """

    gains: np.ndarray
    t: np.ndarray | None = None
    r: np.ndarray | None = None
    u: np.ndarray | None = None
    y: np.ndarray | None = None
    cost: float = math.nan
    metrics: Mapping[str, float] = field(default_factory=dict)
    source: str = "plant"
    index: int = 0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "gains", _frozen(_gains(self.gains)))
        signals = [getattr(self, name) for name in SIGNALS]
        given = [name for name, value in zip(SIGNALS, signals) if value is not None]
        if given and len(given) != len(SIGNALS):
            raise RecordError("t, r, u, y", f"give all four signals or none, got only {', '.join(given)}")
        if given:
            for name, array in validate_signals(*signals).items():
                set_(self, name, _frozen(array))
        set_(self, "cost", _cost(self.cost))
        set_(self, "metrics", _metrics(self.metrics))
        if self.source not in SOURCES:
            raise RecordError("source", f"must be one of {SOURCES}, got {self.source!r}")
        if isinstance(self.index, bool) or not isinstance(self.index, numbers.Integral):
            raise RecordError("index", f"must be an integer, got {self.index!r}")
        set_(self, "index", int(self.index))

    @classmethod
    def from_mapping(cls, record: Mapping, *, source: str | None = None, index: int | None = None) -> Experiment:
        """The record of an env ``info`` dict or any mapping with the field names.

        ``record["experiment"]``, when it is an :class:`Experiment` (an env's
        ``info``), is returned as it is. Otherwise the fields are read from the
        keys ``gains, t, r, u, y, cost, metrics, source`` and ``experiment_index``
        (the env's name for :attr:`index`); missing ones take their defaults.
        ``source`` and ``index`` override what the mapping says.
        """
        if not isinstance(record, Mapping):
            raise TypeError(f"record: expected a mapping, got {type(record).__name__}")
        given = record.get("experiment")
        if isinstance(given, Experiment):
            found = given
        else:
            gains, cost, metrics = record.get("gains"), record.get("cost"), record.get("metrics")
            found = cls(gains=() if gains is None else gains, **{name: record.get(name) for name in SIGNALS},
                        cost=math.nan if cost is None else cost, metrics={} if metrics is None else metrics,
                        source=record.get("source", "plant") if source is None else source,
                        index=record.get("experiment_index", 0) if index is None else index)
        if (source is None or source == found.source) and (index is None or index == found.index):
            return found
        return found.replace(source=found.source if source is None else source,
                             index=found.index if index is None else index)

    def replace(self, **changes) -> Experiment:
        """A copy with ``changes`` applied: the changed fields validated, the signals again only if one changes."""
        if any(name in changes for name in SIGNALS) or self.t is None:
            return dataclasses.replace(self, **changes)
        kept = [f.name for f in dataclasses.fields(self) if f.name not in SIGNALS]
        fields = {name: changes.pop(name, getattr(self, name)) for name in kept}
        if changes:
            raise TypeError(f"replace: unknown field(s) {sorted(changes)}")
        copy = type(self)(**fields)  # validates the fields other than the signals
        for name in SIGNALS:
            object.__setattr__(copy, name, getattr(self, name))  # validated and frozen at construction
        return copy

    @property
    def has_signals(self) -> bool:
        """Whether ``t, r, u, y`` were recorded."""
        return self.t is not None

    @property
    def n_steps(self) -> int:
        """Number of samples (0 without signals)."""
        return 0 if self.t is None else int(self.t.size)

    @property
    def dt(self) -> float:
        """Mean sample time in s, ``(t[-1] - t[0]) / (n_steps - 1)`` (NaN without signals)."""
        if self.t is None:
            return math.nan
        return float((self.t[-1] - self.t[0]) / (self.t.size - 1))

    def to_dict(self) -> dict:
        """The fields as a dict in the env ``info`` layout (``index`` as ``experiment_index``; no signals if absent)."""
        out = {"gains": self.gains, "cost": self.cost, "metrics": dict(self.metrics), "source": self.source,
               "experiment_index": self.index}
        if self.has_signals:
            out.update({name: getattr(self, name) for name in SIGNALS})
        return out

    def __eq__(self, other) -> bool:
        """Same fields, arrays compared exactly and NaN equal to NaN (so a replayed record equals the original)."""
        if not isinstance(other, Experiment):
            return NotImplemented
        same_arrays = all(
            (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b, equal_nan=True))
            for a, b in ((getattr(self, name), getattr(other, name)) for name in ("gains", *SIGNALS)))
        return (same_arrays and _same_float(self.cost, other.cost) and self.source == other.source
                and self.index == other.index and self.metrics.keys() == other.metrics.keys()
                and all(_same_float(v, other.metrics[k]) for k, v in self.metrics.items()))

    __hash__ = None  # compared by value (arrays inside), so not hashable

    def __reduce__(self):
        """Pickle through the constructor, so an unpickled record is validated and read-only again."""
        return type(self), tuple(getattr(self, name) for name in self.__dataclass_fields__)

    def __repr__(self) -> str:
        gains = ", ".join(f"{g:.6g}" for g in self.gains)
        return (f"Experiment(source={self.source!r}, index={self.index}, gains=[{gains}], cost={self.cost:.6g}, "
                f"n_steps={self.n_steps})")


def _frozen(array: np.ndarray) -> np.ndarray:
    """``array`` as read-only float64: itself when it is read-only already, down to the array that owns its
    memory (e.g. a row of :class:`agents.twin.records.Batch`, a column that :func:`agents.twin.csvio.read_csv`
    parsed), else a read-only copy. Records of much data then share it instead of copying it."""
    if array.dtype == np.float64 and _read_only(array):
        return array
    out = np.array(array, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out


def _read_only(array: np.ndarray) -> bool:
    """Whether ``array`` and every array it views are read-only, the last one owning its memory."""
    while isinstance(array, np.ndarray):
        if array.flags.writeable:
            return False
        if array.base is None:
            return True
        array = array.base
    return False  # memory of another object (a buffer that may be writeable)


def _gains(values) -> np.ndarray:
    try:
        gains = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise RecordError("gains", f"must be numeric, got {values!r}") from None
    if gains.ndim != 1:
        raise RecordError("gains", f"must be a 1-D array of shape (n_gains,), got shape {gains.shape}")
    bad = np.flatnonzero(~np.isfinite(gains))
    if bad.size:
        raise RecordError("gains", f"must be finite, got {gains[bad[0]]} at position {bad[0]}")
    return gains


def _cost(value) -> float:
    if isinstance(value, (bool, str, bytes)):
        raise RecordError("cost", f"must be a number (NaN when unknown), got {value!r}")
    try:
        cost = float(value)
    except (TypeError, ValueError):
        raise RecordError("cost", f"must be a number (NaN when unknown), got {value!r}") from None
    if math.isinf(cost):
        raise RecordError("cost", f"must be finite or NaN (unknown), got {cost}")
    return cost


def _metrics(values) -> dict[str, float]:
    if isinstance(values, Mapping):
        items = list(values.items())
    else:
        array = np.asarray(values, dtype=np.float64)
        if array.shape != (len(METRIC_NAMES),):
            raise RecordError("metrics", f"must be a mapping or {len(METRIC_NAMES)} values in the order "
                                         f"{METRIC_NAMES}, got shape {array.shape}")
        items = list(zip(METRIC_NAMES, array))
    out = {}
    for name, value in items:
        try:
            out[str(name)] = float(value)
        except (TypeError, ValueError):
            raise RecordError("metrics", f"{name!r} must be a number, got {value!r}") from None
    return out


def _same_float(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))
