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
"""

from __future__ import annotations

import argparse
import json
import logging
import sys

from evaluation.cli_args import EXIT_BAD_INPUT, EnvId, env_id, int_at_least, json_object, positive_int

__all__ = ["add_parser"]


def add_parser(subparsers) -> None:
    """Add ``tune``, ``sessions`` and ``export`` to the ``gbo`` sub-command parsers."""
    tune = subparsers.add_parser("tune", help="run or resume a crash-safe tuning session stored in SQLite",
                                 description="Run a tuner on an env for a budget of plant experiments, committing "
                                             "every experiment to the database before the next is proposed. "
                                             "Rerun the same command to resume after an interruption. "
                                             "--import MODULE imports your own module first, so that the envs "
                                             "and tuners it registers can be named with --env and --tuner.",
                                 epilog="Examples:\n"
                                        "  gbo tune --env gbo_envs/DCMotor-v0 --tuner bo --budget 30 --db runs.sqlite\n"
                                        "  gbo tune --import my_rig --env my_rig/Rig-v0 --tuner guided-bo --budget 20",
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    tune.add_argument("--env", type=env_id, default=EnvId("gbo_envs/DCMotor-v0"),
                      help="registered env id (default: gbo_envs/DCMotor-v0; your own: see --import)")
    tune.add_argument("--tuner", default="bo", help="tuner registry name (default: bo)")
    tune.add_argument("--budget", type=positive_int, required=True, help="plant experiments the tuner learns from")
    tune.add_argument("--db", default="runs.sqlite", help="SQLite file (default: runs.sqlite)")
    tune.add_argument("--seed", type=int_at_least(0), default=0, help="seed of env and tuner (default: 0)")
    tune.add_argument("--env-kwargs", type=json_object, default={}, metavar="JSON",
                      help='gym.make keyword arguments, e.g. \'{"noise": false}\'')
    tune.add_argument("--tuner-kwargs", type=json_object, default={}, metavar="JSON",
                      help="tuner constructor keyword arguments as a JSON object")
    tune.add_argument("--import", dest="imports", action="append", default=[], metavar="MODULE",
                      help="import MODULE first, found as `python -m` finds it (the current folder first): "
                           "it registers your own envs or tuners; repeatable")
    tune.add_argument("--on-crash", choices=("rerun", "stop"), default="rerun",
                      help="an experiment cut by a crash: run it again (default) or stop for a check of the rig")
    tune.add_argument("--max-skips", type=int_at_least(0), default=5,
                      help="stop after this many skipped failed experiments in a row (default: 5)")
    tune.add_argument("--force", action="store_true",
                      help="take over a session whose recorded owner process is gone (e.g. crashed on another host)")
    tune.add_argument("--quiet", "--no-progress", dest="quiet", action="store_true",
                      help="no progress bar (without it, a bar on stderr when stderr is a terminal)")
    tune.set_defaults(handler=_tune)

    sessions = subparsers.add_parser("sessions", help="list the tuning sessions of a database",
                                     description="List the tuning sessions stored in a gbo tune database: env, "
                                                 "tuner, seed, progress, best cost and status.",
                                     epilog="Example:\n  gbo sessions --db runs.sqlite",
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sessions.add_argument("--db", default="runs.sqlite", help="SQLite file (default: runs.sqlite)")
    sessions.add_argument("--json", action="store_true", help="print JSON instead of a table")
    sessions.set_defaults(handler=_sessions)

    export = subparsers.add_parser("export", help="write a session as workbench CSV (experiment,t,r,u,y + gains)",
                                   description="Write the plant experiments of a session as a workbench CSV "
                                               "(experiment numbered from 1, t, r, u, y, the gains, source, cost) "
                                               "for gbo twin.",
                                   epilog="Example:\n  gbo export --db runs.sqlite --csv out/session.csv\n"
                                          "  gbo twin diagnose out/session.csv",
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    export.add_argument("--db", default="runs.sqlite", help="SQLite file (default: runs.sqlite)")
    export.add_argument("--session", type=positive_int, default=None, help="session id (default: the latest session)")
    export.add_argument("--csv", required=True, help="output CSV file")
    export.add_argument("--include-twin", action="store_true", help="also twin evaluations with stored arrays")
    export.add_argument("--include-failed", action="store_true", help="also failed experiments with stored arrays")
    export.set_defaults(handler=_export)


class _PrintEvents(logging.Handler):
    """Prints a tuner's events (:meth:`agents.Tuner.log_event`) to the current standard output."""

    def emit(self, record: logging.LogRecord) -> None:
        print(record.getMessage(), flush=True)


def _tune(args: argparse.Namespace) -> int:
    import math

    from agents import TuningStopped
    from agents.run_display import progress_enabled
    from evaluation.sessions import ReplayMismatch, SessionBusy, TuningSession

    progress = False if args.quiet else None
    events, printer, level = logging.getLogger("agents.base"), _PrintEvents(), None
    if not progress_enabled(progress):  # without a bar the tuner's events (e.g. "twin: + saturation ...") are printed
        level = events.level
        events.addHandler(printer)
        events.setLevel(logging.INFO)
    try:
        session = TuningSession(args.db, args.env, args.tuner, budget=args.budget, seed=args.seed,
                                env_kwargs=args.env_kwargs, tuner_kwargs=args.tuner_kwargs, on_crash=args.on_crash,
                                max_consecutive_skips=args.max_skips, force=args.force)
        result = session.run(progress=progress)
    except KeyboardInterrupt:
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
    print(f"session {session.session_id} in {args.db}: {result.n_experiments}/{args.budget} plant experiments"
          f"{resumed}, {failed} failed, {result.twin_evaluations} twin evaluations")
    ok = [row for row in result.plant_rows if row.get("status") == "ok"]
    if ok:
        best = min(ok, key=lambda row: row["cost"])
        gains = ", ".join(f"{name} = {best[name]:.6g}" for name in result.gain_names)
        true = "" if math.isnan(best["true_cost"]) else f" (true cost {best['true_cost']:.4f})"
        print(f"best measured: {gains}, cost {best['cost']:.4f}{true} at experiment {best['experiment']}")
    return 0


def _sessions(args: argparse.Namespace) -> int:
    from evaluation.sessions import SessionStore, sessions_table

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
    from evaluation.sessions import SessionStore, export_csv

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
