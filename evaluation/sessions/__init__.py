"""Crash-safe tuning sessions: an SQLite experiment log, resume from a tuner snapshot, and export.

>>> from evaluation.sessions import TuningSession
>>> session = TuningSession("runs.sqlite", "gbo_envs/DCMotor-v0", "bo", budget=20, seed=0)  # doctest: +SKIP
>>> result = session.run(progress=True)  # doctest: +SKIP

A session is :meth:`agents.Tuner.run` with a
:class:`~evaluation.sessions.recorder.SessionRecorder`; rerunning the same
session after a crash resumes it (see :mod:`evaluation.sessions.recorder` for
the resume and the crash policy). The command line is ``gbo tune``,
``gbo sessions`` and ``gbo export`` (:mod:`evaluation.tune_cli`).
"""

from __future__ import annotations

from evaluation.sessions.export import export_csv, load_result, sessions_table
from evaluation.sessions.recorder import CRASH_POLICIES, ReplayMismatch, SessionRecorder, env_state, restore_env_state
from evaluation.sessions.store import NotASessionDatabase, SessionBusy, SessionStore, session_key
from evaluation.sessions.tuning_session import TuningSession, session_spec

__all__ = [
    "CRASH_POLICIES",
    "NotASessionDatabase",
    "ReplayMismatch",
    "SessionBusy",
    "SessionRecorder",
    "SessionStore",
    "TuningSession",
    "env_state",
    "export_csv",
    "load_result",
    "restore_env_state",
    "session_key",
    "session_spec",
    "sessions_table",
]
