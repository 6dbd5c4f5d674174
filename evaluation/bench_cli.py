"""``gbo bench STUDY``: run a Monte Carlo study, then write its report and figures.

Examples::

    gbo bench --list
    gbo bench smoke --out /tmp/smoke                       # all cores, joblib
    gbo bench performance --batches 10                     # first 10 batches only (resumable)
    gbo bench performance --backend dask                   # a local dask.distributed cluster
    gbo bench performance --backend dask --address tcp://scheduler:8786
    gbo bench performance --report-only                    # redo the report from the saved batches
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

from evaluation.cli_args import EXIT_BAD_INPUT, positive_int

__all__ = ["add_parser", "bench"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``bench`` sub-command to the ``gbo`` parser."""
    parser = subparsers.add_parser(
        "bench", help="run a Monte Carlo study (TOML spec) and write its report",
        description="Run a study's batches in parallel, saving each finished batch at once (rerun to resume), "
                    "then write report.md and PNG figures.",
        epilog="Examples:\n  gbo bench --list\n  gbo bench smoke --out /tmp/smoke\n"
               "  gbo bench performance --batches 10 --workers 2",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("study", nargs="?", help="a shipped study name (see --list) or a path to a .toml/.yaml spec")
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
    parser.add_argument("--quiet", action="store_true",
                        help="no progress bar (without it, a bar on stderr when stderr is a terminal)")
    parser.set_defaults(handler=bench)
    return parser


def bench(args: argparse.Namespace) -> int:
    """Handler of ``gbo bench``; returns the exit status (130 after Ctrl-C, 1 if a batch failed)."""
    from evaluation.study import load_study, shipped_studies
    from evaluation.study_runner import default_out_dir, run_study

    if args.list:
        for name in shipped_studies():
            study = load_study(name)
            print(f"{name:18s} {study.title} ({len(study.tuners)} tuners x {study.batches} batches x "
                  f"{study.budget} experiments)")
        return 0
    if not args.study:
        print("gbo bench: give a STUDY (a shipped name or a spec path); see gbo bench --list", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.address and args.backend != "dask":
        print("gbo bench: --address needs --backend dask", file=sys.stderr)
        return EXIT_BAD_INPUT
    if importlib.util.find_spec("pyarrow") is None:
        print("gbo bench: the batch results are Parquet files and need pyarrow, a dependency of gbo-envs "
              "missing from this environment; install it with `pip install pyarrow`", file=sys.stderr)
        return EXIT_BAD_INPUT
    study = load_study(args.study)  # StudySpecError (a ValueError) names file, key and allowed values
    if args.batches is not None:
        study = study.with_batches(args.batches)
    out = Path(args.out) if args.out else default_out_dir(study)
    status = 0
    if not args.report_only:
        run = run_study(study, out, backend=args.backend, address=args.address, workers=args.workers,
                        progress=False if args.quiet else None)  # ValueError before anything is written
        print(f"{study.name}: {run.skipped + run.completed} of {run.total} batches finished "
              f"({run.completed} now, {run.wall_time:.1f} s); results in {out / 'results'}")
        if run.interrupted:
            return 130
        if run.failed:
            print(f"gbo bench: {len(run.failed)} batch(es) failed; rerun to retry them", file=sys.stderr)
            status = 1
    if not args.no_report:
        from evaluation.report import write_report

        path = write_report(study, out)
        print(f"report: {path}")
    return status
