"""Tuner CPU of whole guided-BO runs on the plants of ``guided_bo_ablation.py`` (issue 37).

Runs the default ``agents.make("guided-bo")`` on each plant and seed exactly as
``guided_bo_ablation.py`` does (:func:`guided_bo_ablation.run_one`: single-threaded, the env's
episode length as budget) and prints one JSON object per run: the tuner's CPU seconds (the
run's CPU time minus the plant steps', ``effect_aware_guided_bo.timed_result``), the wall
time, the twin's effects and the minimum-observed optimality-ratio curve, with ``same_curve``:
whether the curve equals the one logged for that plant and seed in
``benchmarks/results/guided_bo_ablation_runs.jsonl`` (``null`` if none is logged). Before the
runs, the compiled simulation is loaded (or compiled) once, its seconds printed apart as
``compile_s`` (none on a tree without it). Run it with another tree's packages first on the
path to compare trees::

    python benchmarks/guided_bo_tuner_cpu.py --seeds 0 1 2
    PYTHONPATH=/path/to/other/tree python benchmarks/guided_bo_tuner_cpu.py --seeds 0 1 2 --plants DCMotor-v0
"""

from __future__ import annotations

import argparse
import json
import os
import time

from effect_aware_guided_bo import PLANTS, optimum
from guided_bo_ablation import RUNS, run_one
from run_log import load_runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", nargs="+", choices=list(PLANTS), default=list(PLANTS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    args = parser.parse_args()
    try:
        from gbo_envs.physics.kernels import warm_up
    except ImportError:
        compile_s = None
    else:
        compile_s = round(warm_up(), 2)
    print(json.dumps({"compile_s": compile_s}), flush=True)
    logged = {(r["plant"], r["seed"]): r["ratios"] for r in load_runs(RUNS) if r["variant"] == "guided-bo"}
    for label in args.plants:
        best = optimum(label)["cost"]
        for seed in args.seeds:
            load = os.getloadavg()[0]
            start = time.perf_counter()
            run = run_one(label, "guided-bo", seed, best)
            ratios = logged.get((label, seed))
            print(json.dumps({"plant": label, "seed": seed, "tuner_cpu_s": round(run["cpu_seconds"]
                                                                                 - run["plant_cpu_seconds"], 2),
                              "cpu_s": run["cpu_seconds"], "plant_cpu_s": run["plant_cpu_seconds"],
                              "wall_s": round(time.perf_counter() - start, 2), "load": round(load, 2),
                              "effects": run["effects"], "activations": run["activations"],
                              "same_curve": None if ratios is None else ratios == run["ratios"],
                              "ratios": run["ratios"]}), flush=True)


if __name__ == "__main__":
    main()
