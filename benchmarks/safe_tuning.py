"""Safe tuning on three plants with limits: violations and data efficiency of the safe and constrained tuners.

The plants (:data:`PLANTS`) and their limits:

* ``DCMotor-v0``: overshoot <= 2 % and peak command <= 140 (issue 55's limits).
* ``DCMotorRig-v0``: the same limits on the rig (encoder-measured speed, friction and the other
  effects of :class:`gbo_envs.envs.rigs.DCMotorRigEnv`), where the twin is not the plant.
* ``LinearMotorCascade-v0`` (4 gains): overshoot <= 0.1 %, i.e. at most two counts of the 5 um
  encoder beyond the 10 mm target (10 um of clearance before an end stop), and peak current
  command <= 6.5 A, below the drive's 7 A current limit (a move that saturates the current loop is
  no longer the linear cascade the symmetric optimum designs, and its speed integrator winds
  against the clamp). Full velocity feed-forward drives the current into the limit, so the limit
  binds at the unconstrained optimum. The overshoot limit is two counts, not less: near its
  setpoint the quantised loop chatters by a count, so a reading of one count is no measured
  overshoot (the plant without its sensor's quantisation does not overshoot there by a tenth of a
  count, ``tests/agents/test_guided_bo_nd.py``), and a limit of half a count admitted only the gains
  of the safe start (30 seeds: guided-bo safe and bo safe missed 1.05 J*_c in 29 and 30 runs).

For every plant, tuner and seed (shared seeds, budget 35): the share of real experiments that
broke a constraint (``feasible`` false), the violations after the safe start, and the real
experiments until a *feasible* experiment's noise-free cost reaches ``ratio x J*_c``, ``J*_c``
the constrained ground truth (:func:`gbo_envs.ground_truth` with the same constraints on the
plant's grid, :data:`PLANTS`); a run that never reaches it counts as budget + 1 and as a miss
(the leaderboard's convention). Means with a 95 % bootstrap interval (2000 resamples of the
seeds, seed 0).

Runs go to ``OUT/runs.jsonl`` (one line per run, appended as they finish, resumed on a rerun),
the optima to ``OUT/optima.json``, the table to ``OUT/table.md``::

    PYTHONPATH=. nice python benchmarks/safe_tuning.py --plants DCMotor-v0 --seeds 30 --out out/safe_tuning
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from joblib import Parallel, delayed

import agents
import gbo_envs

#: plant -> (env id, limits, gains known to keep them, ground-truth grid points per gain)
PLANTS = {
    # safe start: overshoot 0 %, peak command 134.1
    "DCMotor-v0": ("gbo_envs/DCMotor-v0", {"overshoot_pct": 2.0, "peak_u": 140.0}, [[0.3, 1.0]], 100),
    # safe start: overshoot 0.21 %, peak command 139.2 (its ground truth computed live: 25 x 25 cells)
    "DCMotorRig-v0": ("gbo_envs/DCMotorRig-v0", {"overshoot_pct": 2.0, "peak_u": 140.0}, [[0.3, 1.0]], 25),
    # safe start: the nominal feedback gains without feed-forward (overshoot 0, peak current 3.9 A)
    "LinearMotorCascade-v0": ("gbo_envs/LinearMotorCascade-v0", {"overshoot_pct": 0.1, "peak_u": 6.5},
                              [[41.7, 26.7, 83.3, 0.0]], 16),
}
#: label -> (registry name, parameters, whether it takes the plant's safe start)
TUNERS = {
    "guided-bo safe": ("guided-bo", {"safe": True}, True),
    "bo safe": ("bo", {"safe": True}, True),
    "bo constrained": ("bo", {}, False),
    "safeopt": ("safeopt", {}, True),
    "optuna-gp constrained": ("optuna-gp", {"n_initial": 1}, False),
    "botorch constrained": ("botorch", {"n_initial": 1}, False),
}


def one_run(plant: str, label: str, seed: int, budget: int, optimum: float, ratio: float) -> dict:
    """One tuning run's violations and experiments to ``ratio x optimum`` (feasible experiments only)."""
    env_id, limits, start, _ = PLANTS[plant]
    name, params, takes_start = TUNERS[label]
    if takes_start:
        params = {**params, "safe_start": start}
    began = time.process_time()
    result = agents.make(name, **params).run(gym.make(env_id, constraints=limits), budget=budget, seed=seed)
    frame = result.to_pandas()
    feasible = frame["feasible"].astype(bool).to_numpy()
    kept = frame["true_cost"].where(frame["feasible"].astype(bool))
    reached = np.flatnonzero(kept.cummin().to_numpy() <= ratio * optimum)
    first = len(start) if takes_start else 0
    return {"plant": plant, "tuner": label, "seed": seed, "budget": budget, "violations": int(result.violations),
            "violations_after_start": int(np.sum(~feasible[first:])), "experiments": int(len(frame)),
            "to_target": int(reached[0] + 1) if reached.size else None,
            "best_feasible_true_cost": float(kept.min()) if kept.notna().any() else None,
            "cpu_seconds": round(time.process_time() - began, 1)}


def bootstrap_mean(values: np.ndarray, n: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """Mean and 95 % percentile bootstrap interval of the mean."""
    rng = np.random.default_rng(seed)
    means = values[rng.integers(0, values.size, size=(n, values.size))].mean(axis=1)
    return float(values.mean()), *(float(q) for q in np.quantile(means, [0.025, 0.975]))


def table(plant: str, runs: list[dict], budget: int, ratio: float, optimum: float) -> list[str]:
    """The markdown table of one plant's runs."""
    env_id, limits, start, resolution = PLANTS[plant]
    lines = [f"### {plant}", "", f"Constraints {limits}, safe start {start}, budget {budget}; J*_c = {optimum:.4f} "
             f"({resolution} points per gain), target {ratio} x J*_c on feasible experiments.", "",
             "| tuner | runs | experiments breaking a constraint | runs without a violation after the start | "
             f"experiments to {ratio} J*_c (mean [95 % bootstrap]) | misses | CPU s/run |",
             "|---|---|---|---|---|---|---|"]
    for label in TUNERS:
        mine = [r for r in runs if r["tuner"] == label and r["plant"] == plant]
        if not mine:
            continue
        broken = sum(r["violations"] for r in mine) / sum(r["experiments"] for r in mine)
        clean = sum(r["violations_after_start"] == 0 for r in mine)
        counts = np.array([r["to_target"] if r["to_target"] is not None else budget + 1 for r in mine], float)
        mean, low, high = bootstrap_mean(counts)
        misses = sum(r["to_target"] is None for r in mine)
        seconds = np.mean([r["cpu_seconds"] for r in mine])
        lines.append(f"| {label} | {len(mine)} | {100 * broken:.1f} % | {clean} of {len(mine)} | "
                     f"{mean:.1f} [{low:.1f}, {high:.1f}] | {misses} | {seconds:.0f} |")
    return lines + [""]


def constrained_optimum(plant: str, out: Path) -> float:
    """``J*_c`` of a plant (:data:`PLANTS`' grid), cached in ``OUT/optima.json``."""
    path = out / "optima.json"
    optima = json.loads(path.read_text()) if path.exists() else {}
    if plant not in optima:
        env_id, limits, _, resolution = PLANTS[plant]
        truth = gbo_envs.ground_truth(env_id, constraints=limits, resolution=resolution, n_jobs=1,
                                      **({"method": "grid"} if len(PLANTS[plant][2][0]) > 2 else {}))
        optima[plant] = {"cost": float(truth.cost), "gains": np.asarray(truth.gains).tolist(), "resolution": resolution}
        path.write_text(json.dumps(optima, indent=1) + "\n")
    return float(optima[plant]["cost"])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plants", nargs="*", default=list(PLANTS), choices=list(PLANTS))
    parser.add_argument("--seeds", type=int, default=30)
    parser.add_argument("--first-seed", type=int, default=0, help="run the seeds from this one (split a study)")
    parser.add_argument("--budget", type=int, default=35)
    parser.add_argument("--ratio", type=float, default=1.05)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--tuners", nargs="*", default=list(TUNERS), choices=list(TUNERS))
    parser.add_argument("--out", type=Path, default=Path("out") / "safe_tuning")
    parser.add_argument("--table-only", action="store_true", help="write the table of the runs so far, run nothing")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    log = args.out / "runs.jsonl"
    runs = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    done = {(r["plant"], r["tuner"], r["seed"]) for r in runs if r["budget"] == args.budget}
    optima = {} if args.table_only else {plant: constrained_optimum(plant, args.out) for plant in args.plants}
    # plant by plant, seed by seed, every tuner of a seed before the next seed
    seeds = range(args.first_seed, args.seeds)
    tasks = [(plant, label, seed) for plant in args.plants for seed in seeds for label in args.tuners
             if (plant, label, seed) not in done and not args.table_only]
    for run in Parallel(n_jobs=args.jobs, return_as="generator_unordered")(
            delayed(one_run)(plant, label, seed, args.budget, optima[plant], args.ratio)
            for plant, label, seed in tasks):
        runs.append(run)
        with log.open("a") as handle:
            handle.write(json.dumps(run) + "\n")
    kept = [r for r in runs if r["budget"] == args.budget and r["seed"] < args.seeds]
    lines = [line for plant in PLANTS if plant in {r["plant"] for r in kept}
             for line in table(plant, kept, args.budget, args.ratio, json.loads((args.out / "optima.json").read_text())
                               [plant]["cost"])]
    (args.out / "table.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
