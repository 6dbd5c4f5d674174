"""The workbench's measured-data CSV: :class:`~gbo_envs.Experiment` records in, records out.

Format (docs/design.md, "Workbench CSV"): a header with at least
``experiment,t,r,u,y``, one row per sample: experiment number (integer, counted
from 1 as everywhere a person reads it: the record's 0-based ``index`` plus 1), time since
the record's start in s (increasing and uniformly spaced within an experiment),
reference, commanded plant input, measured output. Open-loop data (no controller)
may leave out ``r``: it is then the input ``u`` itself. Optional columns, constant
within an experiment: the gains (``gain0, gain1, ...`` or named, e.g.
``Kp,Ki``), ``source`` (``plant`` or ``twin``) and ``cost``; other columns are
allowed and ignored. :func:`write_csv` writes ``experiment,t,r,u,y``, the gain
columns, ``source`` and ``cost`` (empty when unknown); ``gbo export`` writes the
same. Row numbers in messages are line numbers of the file (the header is line 1).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gbo_envs.atomic_write import atomic_write
from gbo_envs.experiment import SIGNALS, SOURCES, Experiment, RecordError, validate_signals

__all__ = ["REQUIRED_COLUMNS", "UNIFORM_RTOL_CSV", "read_csv", "records_from_env", "records_from_loop", "write_csv"]

#: Columns every workbench CSV must have (``r`` may be left out for open-loop data: it is then ``u``).
REQUIRED_COLUMNS = ("experiment", *SIGNALS)
#: Required columns that may be missing, and the column that stands in for each.
STAND_INS = {"r": "u"}
#: Largest relative deviation of a sample step from the median step within an experiment of a CSV.
UNIFORM_RTOL_CSV = 1e-3
_MIN_SAMPLES = 3
#: Bytes read to tell a binary file (NUL bytes) from text.
_SNIFF_BYTES = 8192
_MISSING = ("", "nan", "na", "null", "none")
#: Rows of a CSV parsed at a time by :func:`read_csv` (bounds the parser's memory).
CHUNK_ROWS = 2**17
#: Largest experiment id of a CSV: the integers a float holds exactly (2**53).
MAX_EXPERIMENT_ID = 2**53


def read_csv(path: str | Path, gain_names: Sequence[str] | None = None) -> list[Experiment]:
    """Read and validate a workbench CSV.

    Parameters
    ----------
    path : str or Path
    gain_names : sequence of str, optional
        Columns holding the gains (e.g. ``("Kp", "Ki")`` for a ``gbo export``
        file). Default: ``gain0, gain1, ...`` as far as present (none: the
        records' gains have shape (0,)).

    Returns
    -------
    list of Experiment
        One record per experiment, in order of first appearance, with
        ``index`` = the experiment number minus 1 (0-based, as the env's
        ``experiment_index``), ``source`` and ``cost`` from their
        columns when present (else ``"plant"`` and NaN) and empty ``metrics``.

    Raises
    ------
    ValueError
        Missing columns, no data rows, a non-numeric or missing (NaN) value, a
        non-integer experiment id, a value of an optional column that changes
        within an experiment, a time that does not increase or is not
        uniformly spaced within an experiment
        (:func:`gbo_envs.experiment.validate_signals`), an experiment with
        fewer than 3 samples, or a last row without a line break at its end (a
        file cut short, e.g. by an interrupted copy); the message names the
        row (file line) and the column.
    FileNotFoundError
        If ``path`` does not exist. A folder, a file that is not UTF-8 text
        or not a table raises ``ValueError`` naming the file.
    """
    import pandas as pd

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise ValueError(f"{path}: is a folder; expected a CSV file with the header {','.join(REQUIRED_COLUMNS)}")
    if not path.is_file():  # opening a named pipe waits for a writer, and the reader reads the file several times
        raise ValueError(f"{path}: not a regular file (a named pipe, device or socket); the CSV is read more than "
                         "once, so save the data to a file first")
    with open(path, "rb") as handle:
        if b"\x00" in handle.read(_SNIFF_BYTES):
            raise ValueError(f"{path}: a binary file (it holds NUL bytes); a workbench CSV is UTF-8 text with the "
                             f"header {','.join(REQUIRED_COLUMNS)}")
    _check_complete(path)
    options = {"keep_default_na": False, "skipinitialspace": True, "encoding": "utf-8"}
    with _parse_errors(path):
        try:
            header = pd.read_csv(path, nrows=0, **options).columns
        except pd.errors.EmptyDataError as exc:
            raise ValueError(f"{path}: the file is empty; expected a header {','.join(REQUIRED_COLUMNS)}") from exc
    raw_names = {str(c).strip(): c for c in header}
    columns = list(raw_names)
    absent = {c: other for c, other in STAND_INS.items() if c not in columns}  # open loop without r: r = u
    missing = [c for c in REQUIRED_COLUMNS if c not in columns and c not in absent]
    if gain_names is not None:
        missing += [c for c in gain_names if c not in columns]
    if missing:
        raise ValueError(f"{path}, row 1 (header): missing column(s) {missing}; the header must contain "
                         f"{','.join(REQUIRED_COLUMNS)} (found {columns}; r may be left out for open-loop data)")
    if gain_names is None:
        gain_names = []
        while f"gain{len(gain_names)}" in columns:
            gain_names.append(f"gain{len(gain_names)}")
    numeric = {column: False for column in (*REQUIRED_COLUMNS, *gain_names) if column not in absent}
    if "cost" in columns:
        numeric["cost"] = True  # missing values allowed
    with _parse_errors(path):
        values, source_codes, source_names = _read_columns(path, raw_names, numeric, "source" in columns, options)
    if values["experiment"].size == 0:
        raise ValueError(f"{path}: no data rows after the header")
    for column, other in absent.items():
        values[column] = values[other]
    costs = values.pop("cost", None)
    exp = values.pop("experiment")
    not_int = np.flatnonzero((exp != np.round(exp)) | (np.abs(exp) > MAX_EXPERIMENT_ID))
    if not_int.size:
        i = int(not_int[0])
        raise ValueError(f"{path}, row {i + 2}, column 'experiment': experiment id must be an integer from "
                         f"-{MAX_EXPERIMENT_ID} to {MAX_EXPERIMENT_ID}, got {float(exp[i])!r}")
    groups = _experiment_rows(exp.astype(int))
    del exp
    for name in SIGNALS:  # read-only down to their memory: the records share these columns, uncopied
        for array in (values[name].base, values[name]):
            if isinstance(array, np.ndarray):
                array.setflags(write=False)
    records = []
    for ident, rows in groups:
        take = slice(rows[0], rows[-1] + 1) if rows[-1] - rows[0] + 1 == rows.size else rows  # a view if in one run
        try:
            signals = validate_signals(*(values[name][take] for name in SIGNALS), min_steps=_MIN_SAMPLES,
                                       uniform_rtol=UNIFORM_RTOL_CSV)
        except RecordError as exc:
            column = "experiment" if exc.field == "t, r, u, y" else exc.field
            raise ValueError(f"{path}, row {rows[exc.sample or 0] + 2}, column {column!r}: experiment {ident}: "
                             f"{exc.rule}") from None
        gains = [_constant(path, ident, rows, name, values[name][take]) for name in gain_names]
        cost = math.nan if costs is None else _constant(path, ident, rows, "cost", costs[take])
        source = "plant" if source_codes is None else \
            _constant(path, ident, rows, "source", source_codes[take], names=source_names)
        if source not in SOURCES:
            raise ValueError(f"{path}, row {rows[0] + 2}, column 'source': must be one of {SOURCES}, got {source!r}")
        records.append(Experiment(gains=gains, **signals, cost=cost, source=source, index=ident - 1))
    return records


def write_csv(records, path: str | Path, gain_names: Sequence[str] | None = None) -> Path:
    """Write records as a workbench CSV; returns the path.

    Parameters
    ----------
    records : sequence of Experiment or of mappings
        Records with signals (mappings are read by
        :meth:`~gbo_envs.Experiment.from_mapping`, e.g. env ``info`` dicts).
        The experiment number is each record's ``index`` plus 1 (counted from 1).
    path : str or Path
        File to write (its folder is created), atomically (:func:`gbo_envs.atomic_write.atomic_write`):
        an existing file is replaced whole or not at all.
    gain_names : sequence of str, optional
        Names of the gain columns (default ``gain0, gain1, ...``).

    Raises
    ------
    ValueError
        A record without signals, or records with different numbers of gains
        than ``gain_names``.
    """
    import pandas as pd

    frames = []
    for k, item in enumerate(records):
        record = item if isinstance(item, Experiment) else Experiment.from_mapping(item)
        if not record.has_signals:
            raise ValueError(f"records[{k}]: has no t, r, u, y to write ({record!r})")
        names = list(gain_names) if gain_names is not None else [f"gain{j}" for j in range(record.gains.size)]
        if len(names) != record.gains.size:
            raise ValueError(f"gain_names: {len(names)} names {names} for records[{k}] with "
                             f"{record.gains.size} gains")
        n = record.n_steps
        frame = {"experiment": np.full(n, record.index + 1, dtype=int)}
        frame.update({name: getattr(record, name) for name in SIGNALS})
        frame.update({name: np.full(n, g) for name, g in zip(names, record.gains)})
        frame["source"] = np.full(n, record.source)
        frame["cost"] = np.full(n, record.cost)
        frames.append(pd.DataFrame(frame))
    if not frames:
        raise ValueError("records: need at least one record to write, got none")
    path = Path(path)
    with atomic_write(path, newline="") as handle:  # a reader sees the whole old or the whole new file
        pd.concat(frames, ignore_index=True).to_csv(handle, index=False)  # shortest exact repr: lossless round trip
    return path


def _check_complete(path: Path) -> None:
    """Raise if a non-empty file does not end with a line break: its last row may be cut mid-value.

    Every CSV writer (pandas, the ``csv`` module, spreadsheets, :func:`write_csv`)
    ends each row, the last one included, with a line break; a file cut short
    by an interrupted write ends inside a row, where a cut number (``305.1``
    read as ``30``) would pass every other check.
    """
    with open(path, "rb") as handle:
        if handle.seek(0, 2) == 0:
            return  # empty: reported by the parser
        handle.seek(-1, 2)
        if handle.read(1) in (b"\n", b"\r"):
            return
        handle.seek(0)
        lines = sum(chunk.count(b"\n") for chunk in iter(lambda: handle.read(1 << 20), b"")) + 1
    raise ValueError(f"{path}, row {lines}: the last row ends without a line break, so the file may have been cut "
                     "short mid-row (an interrupted write or copy); if the row is complete, add a line break at "
                     "the end of the file")


@contextlib.contextmanager
def _parse_errors(path: Path):
    """Turn the parser's codec and table errors into a ``ValueError`` naming the file."""
    import pandas as pd

    try:
        yield
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text (it holds the byte {exc.object[exc.start:exc.start + 1]!r}); "
                         f"a workbench CSV is UTF-8 text with the header {','.join(REQUIRED_COLUMNS)}") from None
    except pd.errors.ParserError as exc:
        raise ValueError(f"{path}: not a CSV table ({' '.join(str(exc).split())})") from None


def _read_columns(path: Path, raw_names: dict, numeric: dict, with_source: bool, options: dict):
    """The numeric columns as floats and the ``source`` column as codes, parsed ``CHUNK_ROWS`` rows at a time.

    Parameters
    ----------
    path : Path
    raw_names : dict
        Column name (stripped) to its name in the file.
    numeric : dict
        Numeric columns to read, each mapped to whether a missing value is allowed (read as NaN).
    with_source : bool
        Whether to read the ``source`` column.
    options : dict
        Options of :func:`pandas.read_csv`.

    Returns
    -------
    values : dict
        Column name to its values, ndarray of shape (n_rows,).
    source_codes : ndarray of int or None
        Per row, an index into ``source_names`` (None without ``source``).
    source_names : list of str or None
        The distinct stripped texts of the ``source`` column.

    Raises
    ------
    ValueError
        A missing, non-numeric or non-finite value, naming its row and column (:func:`_numbers`).
    """
    import pandas as pd

    usecols = [raw_names[c] for c in numeric] + ([raw_names["source"]] if with_source else [])
    # each column filled in place (not pieces joined at the end, whose freed pieces would scatter the heap)
    columns = _Columns({**dict.fromkeys(numeric, float), **({"source": np.int32} if with_source else {})},
                       _count_lines(path))
    checked_as_text = []  # columns with a value that is not a finite number in a chunk: checked on the whole file
    names: dict = {}
    for chunk in pd.read_csv(path, usecols=usecols, chunksize=CHUNK_ROWS, **options):
        out = columns.append(len(chunk))
        for column, allow_missing in numeric.items():
            if column not in checked_as_text:
                numbers = _finite_numbers(chunk[raw_names[column]], allow_missing)
                if numbers is None:
                    checked_as_text.append(column)
                else:
                    out[column][:] = numbers
        if with_source:
            chunk_codes, chunk_names = pd.factorize(chunk[raw_names["source"]].astype(str).str.strip())
            out["source"][:] = np.array([names.setdefault(name, len(names)) for name in chunk_names])[chunk_codes]
    values = columns.values()
    for column, allow_missing in numeric.items():  # in order, so that the first bad column is the one named
        if column in checked_as_text:
            values[column] = _numbers(path, column, raw_names[column], allow_missing)
    if not with_source:
        return values, None, None
    return values, values.pop("source"), list(names)


def _experiment_rows(ids: np.ndarray):
    """``(experiment id, its rows in file order)`` of each experiment, in order of first appearance.

    A file that lists the experiments in increasing order (as :func:`write_csv` and ``gbo export``
    write them) is cut where the id changes; other orders are grouped by one stable sort.
    """
    if bool(np.all(ids[1:] >= ids[:-1])):
        starts = np.flatnonzero(np.concatenate([[True], ids[1:] != ids[:-1]]))
        bounds = [(int(ids[a]), a, b) for a, b in zip(starts, [*starts[1:], ids.size])]
        return ((ident, np.arange(a, b)) for ident, a, b in bounds)
    order = np.argsort(ids, kind="stable")
    idents, first, counts = np.unique(ids[order], return_index=True, return_counts=True)
    return ((int(idents[j]), order[first[j] : first[j] + counts[j]]) for j in np.argsort(order[first]))


def _count_lines(path: Path) -> int:
    """Line breaks in the file: at least its rows after the header (every row ends with one)."""
    with open(path, "rb") as handle:
        return sum(block.count(b"\n") for block in iter(lambda: handle.read(1 << 20), b""))


class _Columns:
    """Columns filled chunk after chunk in arrays of a given capacity (grown if the rows exceed it).

    Parameters
    ----------
    dtypes : dict
        Column name to its dtype.
    capacity : int
        Rows expected at most.
    """

    def __init__(self, dtypes: dict, capacity: int) -> None:
        self.arrays = {name: np.empty(max(capacity, 1), dtype=dtype) for name, dtype in dtypes.items()}
        self.size = 0

    def append(self, n: int) -> dict[str, np.ndarray]:
        """Room for ``n`` more rows: each column's slice to write them into."""
        capacity = next(iter(self.arrays.values())).size
        if self.size + n > capacity:  # more rows than line breaks (e.g. a file with "\r" line ends)
            for name, array in self.arrays.items():
                self.arrays[name] = np.empty(max(2 * capacity, self.size + n), dtype=array.dtype)
                self.arrays[name][: self.size] = array[: self.size]
        first, self.size = self.size, self.size + n
        return {name: array[first : self.size] for name, array in self.arrays.items()}

    def values(self) -> dict[str, np.ndarray]:
        """The filled part of each column."""
        return {name: array[: self.size] for name, array in self.arrays.items()}


def _finite_numbers(series, allow_missing: bool) -> np.ndarray | None:
    """A chunk's column as floats, or None if it has a value that is not a finite number (nor allowed missing)."""

    if series.dtype.kind in "iuf":
        numbers = series.to_numpy(dtype=float)
        return numbers if np.isfinite(numbers).all() else None
    text = series.astype(str).str.strip()
    numbers, blank = _parse_text(text)
    if (~np.isfinite(numbers) & ~(blank & allow_missing)).any():
        return None
    return np.where(blank, np.nan, numbers) if allow_missing else numbers


def _parse_text(text) -> tuple[np.ndarray, np.ndarray]:
    """``(numbers, blank)`` of a column's stripped texts: floats (NaN where not a number), and which are missing."""
    import pandas as pd

    return pd.to_numeric(text, errors="coerce").to_numpy(dtype=float), text.str.lower().isin(_MISSING).to_numpy()


def _numbers(path: Path, column: str, raw_name, allow_missing: bool = False) -> np.ndarray:
    """Column ``raw_name`` of the file checked on its text, as floats; a missing, non-numeric or infinite value
    raises naming its row (the file line) and ``column``."""
    import pandas as pd

    text = pd.read_csv(path, usecols=[raw_name], dtype=str, keep_default_na=False,
                       skipinitialspace=True)[raw_name].astype(str).str.strip()
    numbers, blank = _parse_text(text)
    bad = np.flatnonzero(~np.isfinite(numbers) & ~(blank & allow_missing))
    if bad.size:
        i = int(bad[0])
        raw = text.iloc[i]
        what = "missing value" if raw.lower() in _MISSING else (
            f"non-finite value {raw!r}" if raw.lower().lstrip("+-") in ("inf", "infinity") else
            f"non-numeric value {raw!r}")
        raise ValueError(f"{path}, row {i + 2}, column {column!r}: {what}")
    return np.where(blank, np.nan, numbers) if allow_missing else numbers


def _constant(path: Path, ident: int, rows: np.ndarray, column: str, values: np.ndarray, names=None):
    """The one value of ``column`` within experiment ``ident`` (rows ``rows`` of the data).

    ``values`` are numbers, or codes into ``names`` (the column's distinct texts).
    """
    def show(value):
        return float(value) if names is None else str(names[value])

    first = values[0]
    changed = np.flatnonzero(values != first) if names is not None else \
        np.flatnonzero((values != first) & ~(np.isnan(values) & np.isnan(first)))
    if changed.size:
        i = int(changed[0])
        raise ValueError(f"{path}, row {rows[i] + 2}, column {column!r}: must be constant within experiment "
                         f"{ident}, got {show(values[i])!r} after {show(first)!r}")
    return show(first)


def records_from_env(env, gains: np.ndarray, seed: int | None = None) -> list[Experiment]:
    """Run one env experiment per row of ``gains`` (shape (n, n_gains)) and return their records."""
    if seed is not None:
        env.reset(seed=seed)
    return [Experiment.from_mapping(env.step(np.asarray(g, dtype=float))[4]) for g in np.atleast_2d(gains)]


def records_from_loop(loop, gains: np.ndarray, rng: np.random.Generator, start_index: int = 0) -> list[Experiment]:
    """Closed-loop experiments of a :class:`gbo_envs.ClosedLoop` (any reference step, e.g. through zero speed).

    Experiment ``k`` runs ``loop.at_experiment(start_index + k)`` (so ``drift``
    acts) at ``gains[k]``, with the loop's sensor noise from ``rng``.

    Returns
    -------
    list of Experiment
        Records with signals, ``gains`` and ``index = start_index + k`` (no cost or metrics).
    """
    out = []
    for k, g in enumerate(np.atleast_2d(np.asarray(gains, dtype=float))):
        res = loop.at_experiment(start_index + k).simulate(g[None, :], rng=rng)
        out.append(Experiment(gains=g, t=res.t, r=res.r, u=res.u[0], y=res.y[0], index=start_index + k))
    return out
