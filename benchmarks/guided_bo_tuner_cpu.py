"""Tuner CPU of whole guided-BO runs on the plants of the ``guided_bo_ablation`` study (issue 37).

Runs the study's ``guided-bo`` entry (``agents.make("guided-bo")``, the env's episode length as
budget) on each plant and seed through the study engine's own batch function
(:func:`evaluation.study_runner.run_batch`: BLAS single-threaded, env and tuner seeded with the
seed) and prints one JSON object per run: the tuner's CPU seconds (the run's CPU time minus the
plant steps'), the wall time, the twin's effects at the end and ``curve_max_rel_diff``: the
largest relative difference of the run's best-ratio curve from the one kept for that plant and
seed in ``docs/reports/guided_bo_ablation/curves.parquet`` (``null`` if none is kept; ``0.0``:
the same curve). Before the runs, the compiled simulation is loaded (or compiled) once, its
seconds printed apart as ``compile_s``::

    python benchmarks/guided_bo_tuner_cpu.py --seeds 0 1 2
    python benchmarks/guided_bo_tuner_cpu.py --seeds 0 --plants DCMotor-v0 DC+saturation

The study's optima (``J*`` of each plant) are read from, or computed into, the report's
``optima.json``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from evaluation.curves import CURVES_FILE, curves_from_results, plant_optima, read_curves
from evaluation.study import load_study
from evaluation.study_runner import plan_batches, run_batch

REPORT = Path(__file__).resolve().parents[1] / "docs" / "reports" / "guided_bo_ablation"


def main() -> None:
    study = load_study("guided_bo_ablation")
    labels = [plant.label for plant in study.plants]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", nargs="+", choices=labels, default=labels)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    args = parser.parse_args()
    from gbo_envs.physics.kernels import warm_up

    print(json.dumps({"compile_s": round(warm_up(), 2)}), flush=True)
    kept = read_curves(REPORT / CURVES_FILE)
    kept = {(row.plant, int(row.seed)): row.curve for row in kept[kept["tuner"] == "guided-bo"].itertuples()}
    tasks = [task for task in plan_batches(study, import_path=str(REPORT.parents[2]))
             if task.label == "guided-bo" and task.plant in args.plants and task.seed in args.seeds]
    for task in sorted(tasks, key=lambda t: (args.plants.index(t.plant), t.seed)):
        optima = plant_optima(task.env_id, task.env_kwargs, task.budget, study.resolution, cache=REPORT / "optima.json")
        load = os.getloadavg()[0]
        frame = run_batch(task)
        run = curves_from_results(frame, {task.plant: optima}, tasks={(task.plant, task.label, task.batch): task})
        run = run.iloc[0]
        before = kept.get((task.plant, task.seed))
        diff = None if before is None else float(np.max(np.abs(run.curve - before) / np.abs(before)))
        summary = json.loads(run.summary)
        print(json.dumps({"plant": task.plant, "seed": task.seed,
                          "tuner_cpu_s": round(float(run.cpu_seconds - run.plant_cpu_seconds), 2),
                          "cpu_s": round(float(run.cpu_seconds), 2),
                          "plant_cpu_s": round(float(run.plant_cpu_seconds), 2),
                          "wall_s": round(float(run.seconds), 2), "load": round(load, 2),
                          "effects": summary.get("effects"), "curve_max_rel_diff": diff}), flush=True)


if __name__ == "__main__":
    main()
