"""The records of a grey-box fit, stacked: equal-length rows, padded and masked, with how each one starts.

:class:`GreyData` is the first stage of the workbench's pipeline (records, linear fit,
candidates, fits, ranking, report): every later stage reads the records from it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from agents.twin.initial import InitialConditions, initial_conditions
from agents.twin.records import as_records, decimate_records

__all__ = ["GreyData"]


@dataclass(frozen=True, eq=False)
class GreyData:
    """Records stacked for grey-box fitting (shorter records padded, masked out).

    Attributes
    ----------
    t, r, u, y : ndarray of shape (n_records, n_steps)
        Time (s), reference, commanded input and measured output; padded with the last value.
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

    def __post_init__(self) -> None:
        if self.initial is None:
            object.__setattr__(self, "initial", initial_conditions(self.r, self.u, self.y, self.mask))
        closed = np.array([not np.array_equal(self.r[k][self.mask[k]], self.u[k][self.mask[k]])
                           for k in range(self.u.shape[0])])
        closed.setflags(write=False)
        object.__setattr__(self, "_closed", closed)
        # per record: the largest |y| (padding included) and whether it is padded, for the residual's fast path
        extent = np.maximum(self.y.max(axis=1), -self.y.min(axis=1)) if self.y.size else np.zeros(0)
        padded = ~self.mask.all(axis=1)
        for array in (extent, padded):
            array.setflags(write=False)
        object.__setattr__(self, "_extent", extent)
        object.__setattr__(self, "_padded", padded)

    @classmethod
    def decimated(cls, records, n_samples: int | None, initial: str = "auto") -> GreyData:
        """The records decimated to about ``n_samples`` samples each, with the mean input over each hold
        (:func:`agents.twin.records.decimate_records`; ``None`` keeps every sample), then stacked."""
        return cls.from_records(decimate_records(as_records(records, min_steps=3), n_samples, mean_input=True),
                                initial=initial)

    @classmethod
    def from_records(cls, records, experiment_index: Sequence[int] | None = None,
                     initial: str = "auto") -> GreyData:
        """Validate records (:func:`agents.twin.records.as_records`) and stack them into read-only arrays.

        ``experiment_index`` defaults to the records' :attr:`~gbo_envs.Experiment.index`
        as :func:`~agents.twin.records.as_records` sets it. ``initial`` says how the records
        start (:func:`agents.twin.initial.initial_conditions`: ``"auto"`` detects it).
        """
        data = as_records(records, min_steps=3)
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
        index = index - first
        n = max(rec.n_steps for rec in data)
        arrays = {name: np.empty((len(data), n)) for name in ("t", "r", "u", "y")}
        mask = np.zeros((len(data), n), dtype=bool)
        for k, rec in enumerate(data):
            m = rec.n_steps
            mask[k, :m] = True
            for name in ("r", "u", "y"):
                arrays[name][k, :m] = getattr(rec, name)
                arrays[name][k, m:] = getattr(rec, name)[-1]
            arrays["t"][k] = rec.t[0] + np.arange(n) * rec.dt
        for array in (*arrays.values(), mask):  # read-only: records of their rows share them, uncopied
            array.setflags(write=False)
        start = initial_conditions(arrays["r"], arrays["u"], arrays["y"], mask, initial)
        return cls(**arrays, mask=mask, dt=float(dts[0]), index=index, first_index=first, initial=start)

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

    def y_extent(self, rows: np.ndarray) -> float:
        """``max |y|`` over the records ``rows`` (their padding included), units of ``y``."""
        return float(self._extent.max()) if self.is_all(rows) else float(self._extent[rows].max())

    def padded(self, rows: np.ndarray) -> bool:
        """Whether any of the records ``rows`` is shorter than the longest (has masked padding)."""
        return bool(self._padded.any()) if self.is_all(rows) else bool(self._padded[rows].any())

    def rows_of(self, array: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """``array[rows]`` (an array of this data's shape), a view, not a copy, when ``rows`` are consecutive."""
        if rows.size and rows[-1] - rows[0] == rows.size - 1 and np.all(np.diff(rows) == 1):
            return array[rows[0]: rows[-1] + 1]
        return array[rows]

    def is_all(self, rows: np.ndarray) -> bool:
        """Whether ``rows`` are all the records in order (so that the arrays serve as they are, uncopied)."""
        return rows.size == self.n_records and np.array_equal(rows, np.arange(rows.size))

    def subset(self, rows: Sequence[int]) -> GreyData:
        """The records ``rows`` (experiment indices kept)."""
        rows = np.asarray(rows, dtype=int)
        return GreyData(self.t[rows], self.r[rows], self.u[rows], self.y[rows], self.mask[rows], self.dt,
                        self.index[rows], self.first_index, self.initial.subset(rows))
