"""Does this machine reproduce the shipped suite references? Seed by seed, with the code and stack as they are.

The staleness check of ``gbo bench suite`` (:mod:`evaluation.references`) compares source hashes and
behaviour probes: a tuner's first 5 proposals on DCMotor-v0, a plant's responses at fixed gains. It
does not see what moves a run only on another plant or after the fifth experiment, nor a new
numerical stack (``constraints.txt``): scipy's L-BFGS-B, which maximises EI beyond two gains, is
not probed on DCMotor-v0's grid. This reruns the chosen seeds of every reference tuner on every
suite plant, as the study engine runs them (:func:`evaluation.study_runner.run_batch`), and
compares each experiment's optimality ratio with the stored one (relative tolerance ``--rtol``)::

    python benchmarks/reference_reproduction.py --tuner bo --tuner optuna-gp
    python benchmarks/reference_reproduction.py --plant LinearMotorCascade-v0 --seeds 0 1

It prints one Markdown row per tuner and plant: the seeds whose curves agree, the first experiment
(1-based) where the others part, and the tuner's CPU per run. A reference that parts is rebuilt with
``gbo bench suite --rebuild-references --force --tuner TUNER --plant PLANT``. Runs are written to
``--out`` as they finish, so an interrupted check resumes.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from tqdm import tqdm

from evaluation.curves import curves_from_results, read_curves
from evaluation.references import reference_file, suite_optima
from evaluation.study_runner import plan_batches, run_batch
from evaluation.suite import load_suite


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tuner", action="append", help="a reference label (repeatable; default: all)")
    parser.add_argument("--plant", action="append", help="a suite plant label (repeatable; default: all)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds to rerun (default: 0)")
    parser.add_argument("--rtol", type=float, default=1e-6, help="relative tolerance of a ratio (default 1e-6)")
    parser.add_argument("--out", type=Path, default=Path("out") / "reference_reproduction",
                        help="folder of the finished comparisons (resumed)")
    args = parser.parse_args()
    suite = load_suite("standard")
    labels = [entry.label for entry in suite.tuners]
    plants = [plant.label for plant in suite.plants]
    for name, given, known in (("--tuner", args.tuner, labels), ("--plant", args.plant, plants)):
        unknown = sorted(set(given or ()) - set(known))
        if unknown:
            parser.error(f"{name}: {unknown} not in the standard suite; choose from {known}")
    if not 0 < args.rtol < 1:
        parser.error(f"--rtol: must be in (0, 1), got {args.rtol}")
    study = suite.subset(plants=args.plant, tuners=tuple(e for e in suite.tuners if e.label in (args.tuner or labels)))
    tasks = [task for task in plan_batches(study) if task.seed in args.seeds]
    optima = suite_optima(study, {task.plant: task.budget for task in tasks})
    args.out.mkdir(parents=True, exist_ok=True)
    done_file = args.out / "comparisons.jsonl"
    done = {}
    if done_file.exists():
        for line in done_file.read_text().splitlines():
            row = json.loads(line)
            done[(row["tuner"], row["plant"], row["seed"], row["rtol"])] = row
    references = {}
    for task in tqdm(tasks, desc="reruns", unit="run"):
        key = (task.label, task.plant, task.seed, args.rtol)
        if key in done:
            continue
        if task.label not in references:
            references[task.label] = read_curves(reference_file(task.label))
        stored = references[task.label]
        stored = stored[(stored["plant"] == task.plant) & (stored["seed"] == task.seed)]
        row = {"tuner": task.label, "plant": task.plant, "seed": task.seed, "rtol": args.rtol}
        if not len(stored):
            row.update(parts=None, missing=True, cpu=None)
        else:
            frame = run_batch(task)
            frame["plant"] = task.plant
            new = curves_from_results(frame, optima).iloc[0]
            row.update(parts=first_parting(new["instant"], stored.iloc[0]["instant"], args.rtol), missing=False,
                       cpu=float(new["cpu_seconds"] - new["plant_cpu_seconds"]))
        with done_file.open("a") as handle:
            handle.write(json.dumps(row) + "\n")
        done[key] = row
    print("| tuner | plant | seeds that agree | first experiment apart | tuner CPU s/run |")
    print("|---|---|---|---|---|")
    for label in dict.fromkeys(task.label for task in tasks):
        for plant in dict.fromkeys(task.plant for task in tasks if task.label == label):
            rows = [done[(label, plant, seed, args.rtol)] for seed in args.seeds
                    if (label, plant, seed, args.rtol) in done]
            if not rows or all(row["missing"] for row in rows):
                print(f"| {label} | {plant} | no reference | - | - |")
                continue
            agree = [row["seed"] for row in rows if row["parts"] is None and not row["missing"]]
            apart = [f"seed {row['seed']}: {row['parts']}" for row in rows if row["parts"] is not None]
            cpu = np.mean([row["cpu"] for row in rows if row["cpu"] is not None])
            print(f"| {label} | {plant} | {len(agree)} of {len(rows)} | {', '.join(apart) or '-'} | {cpu:.1f} |")


if __name__ == "__main__":
    main()
