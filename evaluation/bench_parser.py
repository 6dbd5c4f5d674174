"""The arguments of ``gbo bench STUDY`` and ``gbo bench suite`` (see :mod:`evaluation.bench_cli`).

The handlers, named here and imported when their command runs (:class:`evaluation.cli_args.Handler`), are
those of :mod:`evaluation.bench_cli`.
"""

from __future__ import annotations

import argparse

from evaluation.cli_args import Handler, json_object, positive_int

__all__ = ["add_parser"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``bench`` sub-command to the ``gbo`` parser."""
    parser = subparsers.add_parser(
        "bench", help="run a Monte Carlo study (TOML spec) and write its report, or a tuner on the benchmark suite",
        description="Run a study's batches in parallel, saving each finished batch at once (rerun to resume), "
                    "then write report.md and PNG figures. `gbo bench suite --tuner NAME` runs one tuner on the "
                    "benchmark suite (every registered env, the effect plants and the time-varying envs, 30 seeds) "
                    "and writes leaderboard.md/.csv/.html with the shipped reference results, which are not rerun.",
        epilog="Examples:\n  gbo bench --list\n  gbo bench smoke --out /tmp/smoke\n"
               "  gbo bench performance --batches 10 --workers 2\n"
               "  gbo bench suite --tuner random --suite quick\n"
               "  gbo bench suite --import my_tuner --tuner my-tuner --suite quick\n"
               "  gbo bench suite --rebuild-references --tuner guided-bo",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("study", nargs="?", help="a shipped study name (see --list), a path to a .toml/.yaml spec, "
                                                 "or `suite` (one tuner on the benchmark suite)")
    parser.add_argument("--list", action="store_true", help="list the shipped studies and exit")
    parser.add_argument("--batches", type=positive_int, help="run only the first N batches of every tuner")
    parser.add_argument("--backend", choices=("local", "dask"), default="local",
                        help="local: joblib processes (default); dask: dask.distributed")
    parser.add_argument("--address", help="dask scheduler address (default with --backend dask: a LocalCluster)")
    parser.add_argument("--workers", type=positive_int,
                        help="worker processes (default: all cores; 1 = in this process)")
    parser.add_argument("--out", help="output folder (default: out/studies/<study>)")
    parser.add_argument("--no-report", action="store_true", help="only run the batches")
    parser.add_argument("--report-only", action="store_true", help="only write the report from saved batches")
    parser.add_argument("--rerun", action="append", default=[], metavar="LABEL",
                        help="delete the saved runs of this tuner entry first, so that they run again with the current "
                             "code (repeatable)")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress bar (without it, a bar on stderr when stderr is a terminal)")
    suite = parser.add_argument_group("gbo bench suite")
    suite.add_argument("--tuner", action="append", default=[], metavar="NAME",
                       help="the tuner's registry name (yours: see --import); with --rebuild-references: a reference "
                            "to rebuild (repeatable; default: every stale or missing one)")
    suite.add_argument("--tuner-kwargs", type=json_object, default={}, metavar="JSON",
                       help="the tuner's constructor keyword arguments as a JSON object")
    suite.add_argument("--label", help="the tuner's name in the leaderboard (default: --tuner)")
    suite.add_argument("--import", dest="imports", action="append", default=[], metavar="MODULE",
                       help="import MODULE first (in every worker too), found as `python -m` finds it (the current "
                            "folder first): it registers your tuner; repeatable")
    suite.add_argument("--suite", choices=("standard", "quick"), default="standard",
                       help="standard: every suite plant x 30 seeds (default); quick: 3 plants x 3 seeds")
    suite.add_argument("--seeds", type=positive_int, help="seeds per plant (default: the suite's, 30 or 3)")
    suite.add_argument("--rebuild-references", action="store_true",
                       help="rerun the stale and missing reference results (see --tuner) and write them into the "
                            "package's references folder")
    suite.add_argument("--force", action="store_true", help="with --rebuild-references: rebuild current ones too")
    suite.add_argument("--plant", action="append", default=[], metavar="LABEL",
                       help="run and rank on this suite plant only, or with --rebuild-references rebuild on it only "
                            "(repeatable; default: every plant)")
    parser.set_defaults(handler=Handler("evaluation.bench_cli:bench"))
    return parser
