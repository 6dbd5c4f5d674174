"""Read a session back: a :class:`~agents.TuningResult`, the workbench CSV, and the session table."""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path

from agents.result import TuningResult, constraint_columns
from agents.twin.csvio import write_csv
from evaluation.sessions.store import SessionInfo, SessionStore

__all__ = ["export_csv", "load_result", "sessions_table"]

#: Columns of ``gbo sessions``.
TABLE_COLUMNS = ("id", "env", "tuner", "seed", "budget", "done", "failed", "best cost", "status", "created",
                 "updated")


def load_result(store: SessionStore, session_id: int) -> TuningResult:
    """The stored session as a result: one plant row per experiment the tuner learned from, plus twin rows.

    Columns as :meth:`agents.Tuner.run` writes them, plus ``status`` (``ok`` or
    ``failed``: penalised) and ``reason``; ``wall_time`` is in s since the
    session was created. ``result.experiments`` holds the stored records
    (:meth:`~evaluation.sessions.store.ExperimentRow.to_experiment`).
    """
    info = store.session(session_id)
    result = TuningResult(tuner=info.tuner, env_id=info.env_id, gain_names=info.gain_names, seed=info.seed,
                          info={"params": info.spec.get("tuner_params", {}), "session_id": session_id,
                                "db": str(store.path)},
                          interrupted=info.done < info.budget,
                          constraints=dict(info.spec.get("env_kwargs", {}).get("constraints") or {}))
    plant_ids: set[int] = set()
    best = math.inf
    for row in store.experiments(session_id):
        if row.source == "plant":
            if not row.told:
                continue
            plant_ids.add(row.id)
            best = min(best, row.told_cost)
            record = row.to_experiment().replace(cost=row.told_cost)
        elif row.parent_id not in plant_ids or row.status != "ok":
            continue
        else:
            record = row.to_experiment()
        result.add(record, row.experiment, best if row.source == "plant" else math.nan,
                   (row.finished_at or row.started_at) - info.created_at,
                   {"true_cost": math.nan if row.true_cost is None else row.true_cost,
                    "unstable": bool(row.unstable), "status": row.status, "reason": row.reason,
                    **({} if row.source != "plant" else constraint_columns(row.extra, row.status == "failed"))})
    return result


def export_csv(store: SessionStore, out: str | Path, session_id: int | None = None, include_twin: bool = False,
               include_failed: bool = False) -> tuple[SessionInfo, int]:
    """Write a session in the workbench CSV format (:func:`agents.twin.csvio.write_csv`).

    Columns: ``experiment,t,r,u,y`` (one row per sample), then one column per
    gain (e.g. ``Kp,Ki``), then ``source`` and ``cost`` (the cost the tuner
    was told). ``agents.twin.csvio.read_csv(path, gain_names=("Kp", "Ki"))``
    reads it back as :class:`~gbo_envs.Experiment` records.

    Parameters
    ----------
    store : SessionStore
    out : str or Path
        CSV file to write.
    session_id : int, optional
        Default: the most recently updated session.
    include_twin : bool, default False
        Also write twin evaluations that stored ``t, r, u, y``.
    include_failed : bool, default False
        Also write failed plant experiments whose arrays were stored.

    Returns
    -------
    (SessionInfo, int)
        The session and the number of experiments written.

    Raises
    ------
    LookupError
        If the session holds no experiment to write.
    """
    info = store.session(session_id) if session_id is not None else store.latest_session()
    records = []
    for row in store.experiments(info.id):
        wanted = (row.source == "plant" and (row.status == "ok" or (include_failed and row.status == "failed"))) or (
            include_twin and row.source == "twin" and row.status == "ok")
        if not wanted:
            continue
        record = row.to_experiment()
        if not record.has_signals:
            continue
        cost = row.cost if row.source == "twin" else row.told_cost
        # the CSV numbers experiments from 1, as the session does: the record's 0-based index is one less
        records.append(record.replace(cost=math.nan if cost is None else cost, index=row.experiment - 1))
    if not records:
        raise LookupError(f"session {info.id}: no experiment with stored t, r, u, y to export")
    write_csv(records, out, gain_names=info.gain_names)
    return info, len(records)


def sessions_table(sessions: list[SessionInfo]) -> str:
    """The sessions as a plain-text table (columns :data:`TABLE_COLUMNS`)."""
    cells = [[str(s.id), s.env_id, s.tuner, "-" if s.seed is None else str(s.seed), str(s.budget), str(s.done),
              str(s.failed), "-" if math.isnan(s.best_cost) else f"{s.best_cost:.4g}", s.status,
              _when(s.created_at), _when(s.updated_at)] for s in sessions]
    widths = [max(len(h), *(len(row[i]) for row in cells)) if cells else len(h) for i, h in enumerate(TABLE_COLUMNS)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(TABLE_COLUMNS, widths))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths)) for row in cells]
    return "\n".join(line.rstrip() for line in lines)


def _when(timestamp: float) -> str:
    return dt.datetime.fromtimestamp(timestamp).strftime("%Y-%m-%d %H:%M:%S")
