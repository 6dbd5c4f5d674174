"""The arguments of ``gbo tune``, ``gbo sessions`` and ``gbo export`` (see :mod:`evaluation.tune_cli`).

The handlers, named here and imported when their command runs (:class:`evaluation.cli_args.Handler`), are
those of :mod:`evaluation.tune_cli`.
"""

from __future__ import annotations

import argparse

from agents.base import MAX_BUDGET
from evaluation.cli_args import EnvId, Handler, env_id, int_at_least, json_object, positive_int, seed

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
    tune.add_argument("--budget", type=int_at_least(1, MAX_BUDGET), required=True,
                      help=f"plant experiments the tuner learns from (1 to {MAX_BUDGET})")
    tune.add_argument("--db", default="runs.sqlite", help="SQLite file (default: runs.sqlite)")
    tune.add_argument("--seed", type=seed, default=0, help="seed of env and tuner (default: 0)")
    tune.add_argument("--env-kwargs", type=json_object, default={}, metavar="JSON",
                      help='gym.make keyword arguments, e.g. \'{"noise": false}\'')
    tune.add_argument("--tuner-kwargs", type=json_object, default={}, metavar="JSON",
                      help="tuner constructor keyword arguments as a JSON object")
    tune.add_argument("--constraints", type=json_object, default=None, metavar="JSON",
                      help='limits every experiment must keep (value <= limit), e.g. \'{"overshoot_pct": 2.0, '
                           '"peak_u": 140}\': a metric or peak_u (the largest |u|); the env\'s constraints '
                           "(docs/constraints.md)")
    tune.add_argument("--import", dest="imports", action="append", default=[], metavar="MODULE",
                      help="import MODULE first, found as `python -m` finds it (the current folder first): "
                           "it registers your own envs or tuners; repeatable")
    tune.add_argument("--on-crash", choices=("rerun", "stop"), default="rerun",
                      help="an experiment cut by a crash: run it again (default) or stop for a check of the rig")
    tune.add_argument("--max-skips", type=int_at_least(1), default=5,
                      help="stop after this many skipped failed experiments in a row (default: 5)")
    tune.add_argument("--force", action="store_true",
                      help="take over a session whose recorded owner process is gone (e.g. crashed on another host)")
    tune.add_argument("--quiet", "--no-progress", dest="quiet", action="store_true",
                      help="no progress bar (without it, a bar on stderr when stderr is a terminal)")
    tune.set_defaults(handler=Handler("evaluation.tune_cli:_tune"))

    sessions = subparsers.add_parser("sessions", help="list the tuning sessions of a database",
                                     description="List the tuning sessions stored in a gbo tune database: env, "
                                                 "tuner, seed, progress, best cost and status.",
                                     epilog="Example:\n  gbo sessions --db runs.sqlite",
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sessions.add_argument("--db", default="runs.sqlite", help="SQLite file (default: runs.sqlite)")
    sessions.add_argument("--json", action="store_true", help="print JSON instead of a table")
    sessions.set_defaults(handler=Handler("evaluation.tune_cli:_sessions"))

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
    export.set_defaults(handler=Handler("evaluation.tune_cli:_export"))
