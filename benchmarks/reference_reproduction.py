"""Does this machine reproduce the shipped suite references? Seed by seed, with the code and stack as they are.

The staleness check of ``gbo bench suite`` (:mod:`evaluation.references`) compares source hashes and
behaviour probes: a tuner's first 5 proposals on DCMotor-v0, a plant's responses at fixed gains. It
does not see what moves a run only on another plant or after the fifth experiment, nor a new
numerical stack (``constraints.txt``): scipy's L-BFGS-B, which maximises EI beyond two gains, is
not probed on DCMotor-v0's grid. This reruns the chosen seeds of every reference tuner on every
suite plant, as the study engine runs them (:func:`evaluation.study_runner.run_batch`), and
compares each experiment's optimality ratio with the stored one (relative tolerance ``--rtol``; the best ratio
so far where a reference kept only that)::

    python benchmarks/reference_reproduction.py --tuner bo --tuner optuna-gp
    python benchmarks/reference_reproduction.py --plant LinearMotorCascade-v0 --seeds 0 1

It prints one Markdown row per tuner and plant: the seeds whose curves agree, the first experiment
(1-based) where the others part, and the tuner's CPU per run. A reference that parts is rebuilt with
``gbo bench suite --rebuild-references --force --tuner TUNER --plant PLANT``. Each rerun is written to
``--out/results`` as the study engine writes a batch, so an interrupted check resumes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from evaluation.curves import load_curves, read_curves
from evaluation.references import kernel_warning, reference_file, suite_optima
from evaluation.study_runner import finished_files, plan_batches, run_batch, write_batch
from evaluation.suite import load_suite

RUN = ["tuner", "plant", "seed"]


def first_parting(new, old, rtol: float) -> int | None:
    """The first experiment (1-based) where two ratio curves part beyond ``rtol``, or ``None`` if they agree.

    Curves of different lengths part at the first experiment the shorter one lacks.
    """
    new, old = np.asarray(new, dtype=float), np.asarray(old, dtype=float)
    n = min(new.size, old.size)
    apart = np.flatnonzero(~np.isclose(new[:n], old[:n], rtol=rtol, atol=0.0, equal_nan=True))
    if apart.size:
        return int(apart[0]) + 1
    return None if new.size == old.size else n + 1


def _curves(rerun, reference):
    """Each experiment's ratio of both runs, or their best-ratio curves where the reference kept only that (runs
    imported from a run log)."""
    if reference["instant"] is None:
        return rerun["curve"], reference["curve"]
    return rerun["instant"], reference["instant"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tuner", action="append", help="a reference label (repeatable; default: all)")
    parser.add_argument("--plant", action="append", help="a suite plant label (repeatable; default: all)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds to rerun (default: 0)")
    parser.add_argument("--rtol", type=float, default=1e-6, help="relative tolerance of a ratio (default 1e-6)")
    parser.add_argument("--out", type=Path, default=Path("out") / "reference_reproduction",
                        help="folder of the reruns (resumed)")
    args = parser.parse_args()
    suite = load_suite("standard")
    try:
        suite.check_tuner_labels(args.tuner)
        suite.check_plant_labels(args.plant)
    except ValueError as error:
        parser.error(str(error))
    if not 0 < args.rtol < 1:
        parser.error(f"--rtol: must be in (0, 1), got {args.rtol}")
    warning = kernel_warning()
    if warning:
        print(f"warning: {warning}", file=sys.stderr)
    labels = args.tuner or suite.labels
    study = suite.subset(plants=args.plant, tuners=tuple(e for e in suite.tuners if e.label in labels))
    tasks = [task for task in plan_batches(study) if task.seed in args.seeds]
    stored = pd.concat([read_curves(reference_file(entry.label)).assign(tuner=entry.label) for entry in study.tuners])
    stored = stored.set_index(RUN)
    done = finished_files(args.out)
    pending = [task for task in tasks if (task.label, task.plant, task.seed) in stored.index
               and task.filename not in done]
    for task in tqdm(pending, desc="reruns", unit="run"):
        write_batch(run_batch(task), args.out, task.filename)
    optima = suite_optima(study, {task.plant: task.budget for task in tasks})
    reruns = load_curves(args.out, study, optima).set_index(RUN)
    print("| tuner | plant | seeds that agree | first experiment apart | tuner CPU s/run |")
    print("|---|---|---|---|---|")
    seeds_of = {}  # (tuner, plant) -> seeds, tuner by tuner
    for task in sorted(tasks, key=lambda task: suite.labels.index(task.label)):
        seeds_of.setdefault((task.label, task.plant), []).append(task.seed)
    for (label, plant), seeds in seeds_of.items():
        runs = [run for run in ((label, plant, seed) for seed in seeds) if run in reruns.index and run in stored.index]
        if not runs:
            print(f"| {label} | {plant} | no reference | - | - |")
            continue
        parts = {run[2]: first_parting(*_curves(reruns.loc[run], stored.loc[run]), args.rtol) for run in runs}
        apart = [f"seed {seed}: {at}" for seed, at in parts.items() if at is not None]
        cpu = np.mean([reruns.loc[run, "cpu_seconds"] - reruns.loc[run, "plant_cpu_seconds"] for run in runs])
        agree = sum(at is None for at in parts.values())
        print(f"| {label} | {plant} | {agree} of {len(runs)} | {', '.join(apart) or '-'} | {cpu:.1f} |")


if __name__ == "__main__":
    main()
