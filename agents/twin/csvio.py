"""The workbench's measured-data CSV: reading with row-and-column error messages, writing, records from loops.

Format (docs/design.md, "Workbench CSV"): a header with at least
``experiment,t,r,u,y`` (extra columns are allowed and ignored), one row per
sample: experiment id (integer), time since the step in s (increasing and
uniformly spaced within an experiment), reference, commanded plant input,
measured output. Row numbers in messages are line numbers of the file (the
header is line 1).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = ["REQUIRED_COLUMNS", "read_csv", "records_from_env", "records_from_loop", "write_csv"]

#: Columns every workbench CSV must have.
REQUIRED_COLUMNS = ("experiment", "t", "r", "u", "y")
_MIN_SAMPLES = 3


def read_csv(path: str | Path) -> list[dict]:
    """Read and validate a workbench CSV.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    list of dict
        One record per experiment, in order of first appearance, with arrays
        ``t, r, u, y`` of shape (n_steps,), ``experiment`` (the id) and
        ``experiment_index`` (the id, for plant-side effects such as drift).

    Raises
    ------
    ValueError
        Missing columns, no data rows, a non-numeric or missing (NaN) value,
        a non-integer experiment id, a time that does not increase or is not
        uniformly spaced within an experiment, or an experiment with fewer than
        3 samples; the message names the row (file line) and the column.
    FileNotFoundError
        If ``path`` does not exist.
    """
    import pandas as pd

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        frame = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
    except pd.errors.EmptyDataError as exc:
        raise ValueError(f"{path}: the file is empty; expected a header {','.join(REQUIRED_COLUMNS)}") from exc
    frame.columns = [str(c).strip() for c in frame.columns]
    missing = [c for c in REQUIRED_COLUMNS if c not in frame.columns]
    if missing:
        raise ValueError(f"{path}, row 1 (header): missing column(s) {missing}; the header must contain "
                         f"{','.join(REQUIRED_COLUMNS)} (found {list(frame.columns)})")
    if len(frame) == 0:
        raise ValueError(f"{path}: no data rows after the header")
    values = {}
    for column in REQUIRED_COLUMNS:
        text = frame[column].astype(str).str.strip()
        numbers = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(numbers))
        if bad.size:
            i = int(bad[0])
            raw = text.iloc[i]
            what = "missing value" if raw == "" or raw.lower() in ("nan", "na", "null", "none") else (
                f"non-finite value {raw!r}" if raw.lower().lstrip("+-") in ("inf", "infinity") else
                f"non-numeric value {raw!r}")
            raise ValueError(f"{path}, row {i + 2}, column {column!r}: {what}")
        values[column] = numbers
    exp = values["experiment"]
    not_int = np.flatnonzero(exp != np.round(exp))
    if not_int.size:
        i = int(not_int[0])
        raise ValueError(f"{path}, row {i + 2}, column 'experiment': experiment id must be an integer, "
                         f"got {frame['experiment'].iloc[i]!r}")
    ids = exp.astype(int)
    order = list(dict.fromkeys(ids.tolist()))
    records = []
    for ident in order:
        rows = np.flatnonzero(ids == ident)
        if rows.size < _MIN_SAMPLES:
            raise ValueError(f"{path}, row {rows[0] + 2}, column 'experiment': experiment {ident} has "
                             f"{rows.size} sample(s); an experiment needs at least {_MIN_SAMPLES}")
        t = values["t"][rows]
        steps = np.diff(t)
        back = np.flatnonzero(steps <= 0.0)
        if back.size:
            j = int(back[0]) + 1
            raise ValueError(f"{path}, row {rows[j] + 2}, column 't': time {t[j]:g} s does not increase within "
                             f"experiment {ident} (previous sample {t[j - 1]:g} s at row {rows[j - 1] + 2})")
        dt = float(np.median(steps))
        off = np.flatnonzero(np.abs(steps - dt) > 1e-3 * dt)
        if off.size:
            j = int(off[0]) + 1
            raise ValueError(f"{path}, row {rows[j] + 2}, column 't': samples must be uniformly spaced within "
                             f"experiment {ident} (dt = {dt:g} s), the step to {t[j]:g} s is {steps[j - 1]:g} s")
        records.append({"t": t, "r": values["r"][rows], "u": values["u"][rows], "y": values["y"][rows],
                        "experiment": int(ident), "experiment_index": int(ident)})
    return records


def write_csv(records: Sequence[dict], path: str | Path, experiments: Sequence[int] | None = None) -> Path:
    """Write records (mappings with ``t, r, u, y``) as a workbench CSV; returns the path.

    Experiment ids are ``experiments``, else each record's ``experiment_index``
    (or ``experiment``), else 0, 1, ...; extra scalar entries of a record such
    as ``gains`` are written as extra columns (``gain0, gain1, ...``).
    """
    import pandas as pd

    frames = []
    for k, rec in enumerate(records):
        if experiments is not None:
            ident = int(experiments[k])
        else:
            ident = int(rec.get("experiment_index", rec.get("experiment", k)))
        n = np.asarray(rec["t"]).size
        frame = {"experiment": np.full(n, ident, dtype=int)}
        frame.update({name: np.asarray(rec[name], dtype=float) for name in ("t", "r", "u", "y")})
        if "gains" in rec:
            for j, g in enumerate(np.atleast_1d(rec["gains"])):
                frame[f"gain{j}"] = np.full(n, float(g))
        frames.append(pd.DataFrame(frame))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    pd.concat(frames, ignore_index=True).to_csv(path, index=False, float_format="%.10g")
    return path


def records_from_env(env, gains: np.ndarray, seed: int | None = None) -> list[dict]:
    """Run one env experiment per row of ``gains`` (shape (n, n_gains)) and return the ``info`` records."""
    if seed is not None:
        env.reset(seed=seed)
    return [env.step(np.asarray(g, dtype=float))[4] for g in np.atleast_2d(gains)]


def records_from_loop(loop, gains: np.ndarray, rng: np.random.Generator, start_index: int = 0) -> list[dict]:
    """Closed-loop experiments of a :class:`gbo_envs.ClosedLoop` (any reference step, e.g. through zero speed).

    Experiment ``k`` runs ``loop.at_experiment(start_index + k)`` (so ``drift``
    acts) at ``gains[k]``, with the loop's sensor noise from ``rng``.

    Returns
    -------
    list of dict
        Records with ``t, r, u, y``, ``gains`` and ``experiment_index``.
    """
    out = []
    for k, g in enumerate(np.atleast_2d(np.asarray(gains, dtype=float))):
        res = loop.at_experiment(start_index + k).simulate(g[None, :], rng=rng)
        out.append({"t": res.t, "r": res.r, "u": res.u[0], "y": res.y[0], "gains": g,
                    "experiment_index": start_index + k})
    return out
