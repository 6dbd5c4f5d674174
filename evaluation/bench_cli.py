"""``gbo bench STUDY`` and ``gbo bench suite``: run a Monte Carlo study, or one tuner on the benchmark suite.

Examples::

    gbo bench --list
    gbo bench smoke --out /tmp/smoke                       # all cores, joblib
    gbo bench performance --batches 10                     # first 10 batches only (resumable)
    gbo bench performance --backend dask                   # a local dask.distributed cluster
    gbo bench performance --backend dask --address tcp://scheduler:8786
    gbo bench performance --report-only                    # redo the report from the saved batches
    gbo bench suite --tuner random --suite quick           # one tuner on the suite, leaderboard with the references
    gbo bench suite --import my_tuner --tuner my-tuner --tuner-kwargs '{"step": 0.05}'
    gbo bench suite --tuner my-tuner --plant LinearMotorCascadeRig-v0   # one suite plant only
    gbo bench suite --rebuild-references --tuner guided-bo # rerun the stale references of guided-bo

The commands' arguments are declared in :mod:`evaluation.bench_parser`; this module runs them.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

import agents
from evaluation.cli_args import EXIT_BAD_INPUT
from evaluation.leaderboard import RANKING_RULE
from evaluation.references import describe, kernel_warning, rebuild
from evaluation.report import write_report
from evaluation.study import TunerEntry, load_study, shipped_studies
from evaluation.study_runner import default_out_dir, forget, run_study
from evaluation.suite import load_suite, run_suite

__all__ = ["bench", "suite"]


#: Options of `gbo bench suite` only, and of a study only: their flags and the values that mean "not given".
_SUITE_ONLY = {"tuner": ("--tuner", []), "tuner_kwargs": ("--tuner-kwargs", {}), "label": ("--label", None),
               "imports": ("--import", []), "seeds": ("--seeds", None),
               "rebuild_references": ("--rebuild-references", False), "force": ("--force", False),
               "plant": ("--plant", [])}
_STUDY_ONLY = {"batches": ("--batches", None), "list": ("--list", False), "no_report": ("--no-report", False),
               "rerun": ("--rerun", [])}


def bench(args: argparse.Namespace) -> int:
    """Handler of ``gbo bench``; returns the exit status (130 after Ctrl-C, 1 if a batch failed)."""
    if args.study == "suite":
        return suite(args)
    given = [flag for key, (flag, unset) in _SUITE_ONLY.items() if getattr(args, key) != unset]
    if args.suite != "standard":
        given.append("--suite")
    if given:
        print(f"gbo bench: {', '.join(given)} only with `gbo bench suite`", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.list:
        for name in shipped_studies():
            study = load_study(name)
            if study.per_plant:
                print(f"{name:18s} {study.title} ({len(study.tuners)} tuners x {len(study.plants)} plants x "
                      f"{study.batches} batches)")
            else:
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
    if args.rerun:
        print(f"{study.name}: deleted {forget(study, out, args.rerun)} saved runs of {', '.join(args.rerun)}")
    status = 0
    if not args.report_only:
        run = run_study(study, out, backend=args.backend, address=args.address, workers=args.workers,
                        progress=False if args.quiet else None)  # ValueError before anything is written
        status = _finished(run, f"{study.name}: ", "batches", f"results in {out / 'results'}", "gbo bench")
        if status == 130:
            return status
    if not args.no_report:
        path = write_report(study, out)
        print(f"report: {path}")
    return status


def suite(args: argparse.Namespace) -> int:
    """Handler of ``gbo bench suite``: run a tuner on the suite and write the leaderboard, or rebuild references."""
    given = [flag for key, (flag, unset) in _STUDY_ONLY.items() if getattr(args, key) != unset]
    if given:
        print(f"gbo bench suite: {', '.join(given)} only with a study (gbo bench STUDY)", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.address and args.backend != "dask":
        print("gbo bench suite: --address needs --backend dask", file=sys.stderr)
        return EXIT_BAD_INPUT
    progress = False if args.quiet else None
    if args.rebuild_references:
        extra = [flag for flag, value in (("--tuner-kwargs", args.tuner_kwargs), ("--label", args.label),
                                          ("--import", args.imports), ("--seeds", args.seeds),
                                          ("--report-only", args.report_only)) if value]
        if extra:
            print(f"gbo bench suite: {', '.join(extra)} not with --rebuild-references (the references run the "
                  "standard suite with the kwargs of evaluation/studies/suite.toml)", file=sys.stderr)
            return EXIT_BAD_INPUT
        warning = kernel_warning()
        if warning:
            print(f"gbo bench suite: warning: {warning}", file=sys.stderr)
        done = rebuild(load_suite("standard"), tuners=args.tuner or None, out=Path(args.out or "out/references"),
                       force=args.force, plants=args.plant or None, backend=args.backend, address=args.address,
                       workers=args.workers, progress=progress)
        for tuner, plants in done.items():
            if tuner in ("interrupted", "failed"):
                continue
            print(f"{tuner}: {'rebuilt on ' + ', '.join(plants) if plants else 'current, nothing to rebuild'}")
        if "interrupted" in done:
            print("gbo bench suite: interrupted; rerun the same command to resume", file=sys.stderr)
            return 130
        if "failed" in done:
            print(f"gbo bench suite: runs failed ({done['failed']}); rerun to retry them", file=sys.stderr)
            return 1
        return 0
    if args.force:
        print("gbo bench suite: --force only with --rebuild-references", file=sys.stderr)
        return EXIT_BAD_INPUT
    if len(args.tuner) != 1:
        print("gbo bench suite: give one --tuner NAME (a registered tuner; yours with --import MODULE), "
              f"got {len(args.tuner)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    name = args.tuner[0]
    if name not in agents.registered_names():
        hint = " (is --import the module that registers it?)" if args.imports else \
            " (your own: --import MODULE that registers it)"
        raise ValueError(f"--tuner {name!r}: not a registered tuner; registered: "
                         f"{', '.join(agents.registered_names())}{hint}")
    entry = TunerEntry(name=name, label=args.label or name, params=dict(args.tuner_kwargs or {}))
    result = run_suite(entry, suite=_suite_plants(args.suite, args.plant), seeds=args.seeds,
                       imports=args.imports, out=Path(args.out or "out/suite"), backend=args.backend,
                       address=args.address, workers=args.workers, progress=progress, report_only=args.report_only)
    run = result.run
    if run is not None:
        status = _finished(run, f"suite {args.suite}: ", f"runs of {result.label}",
                           f"runs in {Path(args.out or 'out/suite')}", "gbo bench suite")
        if status:
            return status
    board = result.leaderboard
    for line in (result.references and _stale_lines(result.references)) or []:
        print(line)
    print(RANKING_RULE.replace("the reference", board.reference))
    for row in board.aggregate_.to_dict("records"):
        print(f"{row['rank']:>2}. {row['tuner']:<16} solved {100 * row['solved']:3.0f} % of {row['pairs']}, "
              f"vs {board.reference}: {row['geo_mean_vs_reference']:.2f} [{row['ci_low']:.2f}, {row['ci_high']:.2f}]"
              + (f" ({row['status']})" if row["status"] else "") + ("  <- yours" if row["tuner"] == result.label
                                                                     else ""))
    print(f"leaderboard: {result.paths['md']} (.csv, .html)")
    return 0


def _suite_plants(name: str, plants: list[str]):
    """The suite ``name``, or with ``plants`` (``--plant``) its study on those plants only."""
    if not plants:
        return name
    return load_suite(name).subset(plants=list(plants))


def _finished(run, head: str, what: str, where: str, command: str) -> int:
    """Print what a run of batches did; its exit status (130 after Ctrl-C, 1 if a batch failed, else 0)."""
    print(f"{head}{run.skipped + run.completed} of {run.total} {what} finished ({run.completed} now, "
          f"{run.wall_time:.1f} s); {where}")
    if run.interrupted:
        return 130
    if run.failed:
        print(f"{command}: {len(run.failed)} batch(es) failed; rerun to retry them", file=sys.stderr)
        return 1
    return 0


def _stale_lines(refs) -> list[str]:
    return describe(refs)
