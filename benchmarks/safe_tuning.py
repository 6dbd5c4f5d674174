"""Safe tuning on DCMotor-v0 with overshoot <= 2 % and peak command <= 140: violations and data efficiency.

For every tuner and seed (shared seeds, budget 35): the share of real experiments that broke a
constraint (``feasible`` false), and the real experiments until a *feasible* experiment's
noise-free cost reaches ``ratio x J*_c``, ``J*_c`` the constrained ground truth
(:func:`gbo_envs.ground_truth` with the same constraints, 100 x 100 grid); a run that never
reaches it counts as budget + 1 and as a miss (the leaderboard's convention). Means with a 95 %
bootstrap interval (2000 resamples of the seeds, seed 0).

Runs go to ``OUT/runs.jsonl`` (one line per run, appended as they finish, resumed on a rerun);
the table to ``OUT/table.md``::

    PYTHONPATH=. nice python benchmarks/safe_tuning.py --seeds 30 --jobs 2 --out out/safe_tuning
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
from joblib import Parallel, delayed

import agents
import gbo_envs

ENV_ID = "gbo_envs/DCMotor-v0"
LIMITS = {"overshoot_pct": 2.0, "peak_u": 140.0}
#: Gains known to keep both limits (overshoot 0 %, peak command 134.1).
SAFE_START = [[0.3, 1.0]]
#: label -> (registry name, parameters)
TUNERS = {
    "bo safe": ("bo", {"safe": True, "safe_start": SAFE_START}),
    "bo constrained": ("bo", {}),
    "safeopt": ("safeopt", {"safe_start": SAFE_START}),
    "optuna-gp constrained": ("optuna-gp", {"n_initial": 1}),
}


def one_run(label: str, seed: int, budget: int, optimum: float, ratio: float) -> dict:
    """One tuning run's violations and experiments to ``ratio x optimum`` (feasible experiments only)."""
    name, params = TUNERS[label]
    env = gym.make(ENV_ID, constraints=LIMITS)
    result = agents.make(name, **params).run(env, budget=budget, seed=seed)
    frame = result.to_pandas()
    kept = frame["true_cost"].where(frame["feasible"].astype(bool))
    reached = np.flatnonzero(kept.cummin().to_numpy() <= ratio * optimum)
    return {"tuner": label, "seed": seed, "budget": budget, "violations": int(result.violations),
            "experiments": int(len(frame)), "to_target": int(reached[0] + 1) if reached.size else None,
            "best_feasible_true_cost": float(kept.min()) if kept.notna().any() else None}


def bootstrap_mean(values: np.ndarray, n: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """Mean and 95 % percentile bootstrap interval of the mean."""
    rng = np.random.default_rng(seed)
    means = values[rng.integers(0, values.size, size=(n, values.size))].mean(axis=1)
    return float(values.mean()), *(float(q) for q in np.quantile(means, [0.025, 0.975]))


def table(runs: list[dict], budget: int, ratio: float, optimum: float) -> list[str]:
    """The markdown table of the runs."""
    lines = [f"DCMotor-v0, constraints {LIMITS}, budget {budget}; J*_c = {optimum:.4f} (100 x 100 grid), "
             f"target {ratio} x J*_c on feasible experiments.", "",
             "| tuner | runs | experiments breaking a constraint | runs without a violation | "
             f"experiments to {ratio} J*_c (mean [95 % bootstrap]) | misses |", "|---|---|---|---|---|---|"]
    for label in TUNERS:
        mine = [r for r in runs if r["tuner"] == label]
        if not mine:
            continue
        broken = sum(r["violations"] for r in mine) / sum(r["experiments"] for r in mine)
        clean = sum(r["violations"] == 0 for r in mine)
        counts = np.array([r["to_target"] if r["to_target"] is not None else budget + 1 for r in mine], float)
        mean, low, high = bootstrap_mean(counts)
        misses = sum(r["to_target"] is None for r in mine)
        lines.append(f"| {label} | {len(mine)} | {100 * broken:.1f} % | {clean} of {len(mine)} | "
                     f"{mean:.1f} [{low:.1f}, {high:.1f}] | {misses} |")
    return lines


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=30)
    parser.add_argument("--budget", type=int, default=35)
    parser.add_argument("--ratio", type=float, default=1.05)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--tuners", nargs="*", default=list(TUNERS), choices=list(TUNERS))
    parser.add_argument("--out", type=Path, default=Path("out") / "safe_tuning")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    log = args.out / "runs.jsonl"
    runs = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    done = {(r["tuner"], r["seed"]) for r in runs if r["budget"] == args.budget}
    optimum = gbo_envs.ground_truth(ENV_ID, constraints=LIMITS, n_jobs=1).cost
    # the safe tuners first, seed by seed; the slower peer (Optuna's GP sampler) after them
    order = sorted(args.tuners, key=lambda label: TUNERS[label][0].startswith("optuna"))
    tasks = sorted(((label, seed) for seed in range(args.seeds) for label in order if (label, seed) not in done),
                   key=lambda task: (TUNERS[task[0]][0].startswith("optuna"), task[1]))
    for run in Parallel(n_jobs=args.jobs, return_as="generator_unordered")(
            delayed(one_run)(label, seed, args.budget, optimum, args.ratio) for label, seed in tasks):
        runs.append(run)
        with log.open("a") as handle:
            handle.write(json.dumps(run) + "\n")
    lines = table([r for r in runs if r["budget"] == args.budget and r["seed"] < args.seeds], args.budget,
                  args.ratio, optimum)
    (args.out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
