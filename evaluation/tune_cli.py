"""``gbo tune``, ``gbo sessions`` and ``gbo export``: crash-safe tuning sessions from the command line.

::

    gbo tune --env gbo_envs/DCMotor-v0 --tuner bo --budget 30 --db runs.sqlite --seed 0
    gbo sessions --db runs.sqlite
    gbo export --db runs.sqlite --csv out/session.csv        # the latest session

Rerunning an interrupted ``gbo tune`` command resumes its session (see
:mod:`evaluation.sessions.recorder`); rerunning it with another ``--budget``
extends or shortens the same session. ``gbo sessions`` and ``gbo export`` open
the database read-only, and every command refuses a file that is not a
session database without changing it. ``--import MODULE`` imports a module first,
for envs and tuners registered outside this package (e.g. an
:class:`~gbo_envs.envs.external.ExternalPlantEnv` around your rig).

The commands' arguments are declared in :mod:`evaluation.tune_parser`; this module runs them.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys

from agents import TuningStopped
from agents.run_display import progress_enabled
from evaluation.cli_args import EXIT_BAD_INPUT, OutputClosed
from evaluation.sessions import ReplayMismatch, SessionBusy, SessionStore, TuningSession, export_csv, sessions_table
from gbo_envs.constraints import Constraints


class _PrintEvents(logging.Handler):
    """Prints a tuner's events (:meth:`agents.Tuner.log_event`) to the current standard output."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            print(record.getMessage(), flush=True)
        except BrokenPipeError:  # gbo tune ... | head: stop as if interrupted, the session left to resume
            raise OutputClosed() from None


def _tune(args: argparse.Namespace) -> int:
    env_kwargs = dict(args.env_kwargs)
    if args.constraints is not None:  # refused before the logger below is touched
        try:
            Constraints(args.constraints)
        except (TypeError, ValueError) as exc:
            print(f"gbo tune: --constraints: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
        env_kwargs["constraints"] = dict(args.constraints)
    progress = False if args.quiet else None
    events, printer, level = logging.getLogger("agents.base"), _PrintEvents(), None
    if not progress_enabled(progress):  # without a bar the tuner's events (e.g. "twin: + saturation ...") are printed
        level = events.level
        events.addHandler(printer)
        events.setLevel(logging.INFO)
    try:
        session = TuningSession(args.db, args.env, args.tuner, budget=args.budget, seed=args.seed,
                                env_kwargs=env_kwargs, tuner_kwargs=args.tuner_kwargs, on_crash=args.on_crash,
                                max_consecutive_skips=args.max_skips, force=args.force)
        result = session.run(progress=progress)
    except KeyboardInterrupt as exc:
        if isinstance(exc, OutputClosed) or isinstance(exc.__cause__, OutputClosed):
            raise OutputClosed() from None
        print("gbo tune: interrupted; finished experiments are stored, rerun the same command to resume",
              file=sys.stderr)
        return 130
    except (TuningStopped, ReplayMismatch, SessionBusy) as exc:
        print(f"gbo tune: {exc}", file=sys.stderr)
        return 1
    finally:  # the logger is the process's: leave it as it was (gbo tune may run inside a Python session)
        if level is not None:
            events.removeHandler(printer)
            events.setLevel(level)
    resumed = f" (resumed after {session.n_replayed})" if session.n_replayed else ""
    if result.n_experiments > args.budget:
        resumed += f"; the session already held more than --budget {args.budget}, nothing was run"
    failed = sum(row.get("status") == "failed" for row in result.plant_rows)
    broke = f", {result.violations} broke a constraint" if result.constraints else ""
    print(f"session {session.session_id} in {args.db}: {result.n_experiments}/{args.budget} plant experiments"
          f"{resumed}, {failed} failed{broke}, {result.twin_evaluations} twin evaluations")
    ok = [row for row in result.plant_rows if row.get("status") == "ok"]
    if result.constraints:  # the best is the best feasible experiment
        ok = [row for row in ok if row.get("feasible") is True]
    if ok:
        best = min(ok, key=lambda row: row["cost"])
        gains = ", ".join(f"{name} = {best[name]:.6g}" for name in result.gain_names)
        true = "" if math.isnan(best["true_cost"]) else f" (true cost {best['true_cost']:.4f})"
        print(f"best measured: {gains}, cost {best['cost']:.4f}{true} at experiment {best['experiment']}")
    return 0


def _sessions(args: argparse.Namespace) -> int:
    store = SessionStore(args.db, read_only=True)  # a missing or foreign file: one line and exit status 2
    with store:
        sessions = store.sessions()
    if args.json:
        print(json.dumps([{"id": s.id, "env": s.env_id, "tuner": s.tuner, "seed": s.seed, "budget": s.budget,
                           "done": s.done, "failed": s.failed, "best_cost": None if s.best_cost != s.best_cost
                           else s.best_cost, "status": s.status, "created": s.created_at, "updated": s.updated_at}
                          for s in sessions]))
    else:
        print(sessions_table(sessions))
    return 0


def _export(args: argparse.Namespace) -> int:
    store = SessionStore(args.db, read_only=True)
    with store:
        try:
            info, count = export_csv(store, args.csv, session_id=args.session, include_twin=args.include_twin,
                                     include_failed=args.include_failed)
        except LookupError as exc:  # no such session: bad input, as the boundary's exit status says
            print(f"gbo export: {exc.args[0] if exc.args else exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
    print(f"wrote {count} experiments of session {info.id} ({info.tuner} on {info.env_id}) to {args.csv}")
    return 0
