"""The curves table and its file: one row per tuning run, its best-ratio curve and a short summary.

Columns of a curves table (:data:`CURVE_COLUMNS`): ``study, plant, tuner`` (label),
``tuner_name, params`` (JSON), ``env_id, env_kwargs`` (JSON), ``budget, batch,
seed, key, file`` (the batch file the run is, :attr:`evaluation.study_runner.BatchTask.filename`),
``curve`` and ``instant`` (lists of floats, one per experiment), ``optimum``
(``J*`` of the first experiment's plant), ``seconds, cpu_seconds,
plant_cpu_seconds`` (the run's wall and CPU time and the CPU time of the plant's
steps, NaN when unknown), ``summary`` (JSON: the tuner's own figures, see
:func:`evaluation.curves.run_summary`), ``source`` (``"engine"`` or where it was imported from) and
``violations`` (on a plant with constraints: the experiments that broke one, NaN elsewhere; the
best-ratio curve of such a plant counts only the feasible experiments).

:mod:`evaluation.curves` computes the rows from a study's batch files; :func:`write_curves` and
:func:`read_curves` keep them as Parquet (``curves.parquet``, :data:`CURVES_FILE`, in a study's folder:
runs kept as curves only, which :func:`evaluation.study_runner.run_study` skips).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from gbo_envs.atomic_write import atomic_write

__all__ = ["CURVE_COLUMNS", "CURVES_FILE", "read_curves", "write_curves"]

#: Name of a study folder's curves table.
CURVES_FILE = "curves.parquet"
#: Columns of a curves table (see the module docstring).
CURVE_COLUMNS = ["study", "plant", "tuner", "tuner_name", "params", "env_id", "env_kwargs", "budget", "batch", "seed",
                 "key", "file", "curve", "instant", "optimum", "seconds", "cpu_seconds", "plant_cpu_seconds", "summary",
                 "source", "commit", "violations"]


def write_curves(curves: pd.DataFrame, path: Path | str) -> Path:
    """Write a curves table atomically as Parquet (zstd; the lists as lists of float64)."""
    path = Path(path)
    frame = curves.reindex(columns=CURVE_COLUMNS).reset_index(drop=True)
    with atomic_write(path, "wb") as handle:
        frame.to_parquet(handle, index=False, compression="zstd")
    return path


def read_curves(path: Path | str) -> pd.DataFrame:
    """A curves table written by :func:`write_curves` (empty with the columns when the file is missing)."""
    path = Path(path)
    if not path.is_file():
        return pd.DataFrame(columns=CURVE_COLUMNS)
    frame = pd.read_parquet(path)
    for column in ("curve", "instant"):
        frame[column] = [None if v is None else np.asarray(v, dtype=float) for v in frame[column]]
    return frame
