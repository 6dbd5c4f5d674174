"""Data efficiency of every tuner on DCMotor-v0: experiments needed to reach an optimality ratio.

For each tuner and seed, one tuning run of ``--budget`` experiments on
``gbo_envs/DCMotor-v0`` (default noise, N0 = 1 for BO). After every experiment
the tuner's choice (the gains with the lowest *measured* cost so far) is judged
by its noise-free cost: ``phi_n = J_true(best measured gains) / J(theta*)``
with ``J(theta*)`` from :func:`gbo_envs.ground_truth` (100 x 100 grid). The
number of experiments to reach ``phi <= 1.1`` (and 1.05) is averaged over the
seeds; a run that never reaches it counts as ``budget + 1``.

Not a test: prints JSON and a Markdown table. Seeds run in parallel (joblib).

    python benchmarks/data_efficiency.py                      # 30 seeds, all tuners
    python benchmarks/data_efficiency.py --tuners bo random --seeds 10
    python benchmarks/data_efficiency.py --tuners bo random --seeds 30 --seed0 30   # check range 30-59
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import gymnasium as gym
import numpy as np
from joblib import Parallel, delayed

import agents
import gbo_envs
from gbo_envs import ground_truth

__all__ = ["experiments_to_reach", "run_one", "main"]

TUNERS = ("bo", "bo-envelope", "bo-cost-gp", "random", "grid", "nominal", "optuna-gp", "optuna-tpe")
#: Rows that are a registered tuner with other options: label -> (registry name, kwargs).
VARIANTS = {"bo-envelope": ("bo", {"settling_model": "envelope"}),  # settling time from the error envelope
            "bo-cost-gp": ("bo", {"model": "cost"})}  # one GP on the cost (the paper's BO, as in the studies)
THRESHOLDS = (1.1, 1.05)


def experiments_to_reach(ratios: np.ndarray, threshold: float) -> int:
    """1-based index of the first experiment with ``ratio <= threshold``; ``len(ratios) + 1`` if never."""
    hits = np.flatnonzero(np.asarray(ratios) <= threshold)
    return int(hits[0]) + 1 if hits.size else len(ratios) + 1


def run_one(tuner: str, seed: int, budget: int, optimum: float, tuner_kwargs: dict | None = None) -> dict:
    """One run: the optimality-ratio curve and wall time of ``tuner`` with ``seed``."""
    from agents.thread_limits import single_thread

    gbo_envs.__name__  # noqa: B018  (registers the envs in a fresh worker)
    env = gym.make("gbo_envs/DCMotor-v0")
    start = time.perf_counter()
    with warnings.catch_warnings(), single_thread(user_api=None):
        warnings.simplefilter("ignore")
        name, options = VARIANTS.get(tuner, (tuner, {}))
        result = agents.make(name, **{**options, **(tuner_kwargs or {})}).run(env, budget=budget, seed=seed)
    # issue 4: ratio = best observed noise-free cost / ground-truth optimum (the paper's minimum observed ratio)
    ratios = result.min_true_cost_curve() / optimum
    incumbent = result.best_true_cost_curve() / optimum  # stricter: true cost of the best-measured gains
    return {"tuner": tuner, "seed": seed, "ratios": ratios.tolist(), "incumbent_ratios": incumbent.tolist(),
            "seconds": time.perf_counter() - start}


def summarise(runs: list[dict], budget: int) -> dict:
    """Per tuner: mean experiments to each threshold, how many runs never reached it, final ratio."""
    table: dict[str, dict] = {}
    for tuner in dict.fromkeys(run["tuner"] for run in runs):
        mine = [run for run in runs if run["tuner"] == tuner]
        row: dict = {"runs": len(mine)}
        for threshold in THRESHOLDS:
            counts = np.array([experiments_to_reach(run["ratios"], threshold) for run in mine])
            row[f"mean_experiments_to_{threshold}"] = float(counts.mean())
            row[f"median_experiments_to_{threshold}"] = float(np.median(counts))
            row[f"never_reached_{threshold}"] = int(np.sum(counts > budget))
            strict = np.array([experiments_to_reach(run["incumbent_ratios"], threshold) for run in mine])
            row[f"mean_experiments_to_{threshold}_incumbent"] = float(strict.mean())
        row["mean_final_ratio"] = float(np.mean([run["ratios"][-1] for run in mine]))
        row["mean_seconds_per_run"] = float(np.mean([run["seconds"] for run in mine]))
        table[tuner] = row
    return table


def markdown(table: dict, budget: int, n_seeds: int) -> str:
    """The summary as a Markdown table."""
    lines = [f"Experiments to reach optimality ratio (mean over {n_seeds} seeds; never reached counts as "
             f"{budget + 1})", "",
             "| tuner | to 1.1 | never 1.1 | to 1.05 | never 1.05 | final ratio | s/run |",
             "|---|---|---|---|---|---|---|"]
    for tuner, row in table.items():
        lines.append(f"| {tuner} | {row['mean_experiments_to_1.1']:.1f} | {row['never_reached_1.1']} | "
                     f"{row['mean_experiments_to_1.05']:.1f} | {row['never_reached_1.05']} | "
                     f"{row['mean_final_ratio']:.3f} | {row['mean_seconds_per_run']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tuners", nargs="+", default=list(TUNERS))
    parser.add_argument("--seeds", type=int, default=30, help="number of seeds")
    parser.add_argument("--seed0", type=int, default=0, help="first seed (seeds seed0 .. seed0 + seeds - 1)")
    parser.add_argument("--budget", type=int, default=35)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--bo-kwargs", type=json.loads, default={}, help="JSON kwargs for the 'bo' tuner")
    parser.add_argument("--out", help="also write the JSON here")
    args = parser.parse_args(argv)

    truth = ground_truth("gbo_envs/DCMotor-v0", resolution=100)
    jobs = [(tuner, seed) for tuner in args.tuners for seed in range(args.seed0, args.seed0 + args.seeds)]
    runs = Parallel(n_jobs=args.jobs, verbose=5)(
        delayed(run_one)(tuner, seed, args.budget, truth.cost, args.bo_kwargs if tuner == "bo" else None)
        for tuner, seed in jobs)
    table = summarise(runs, args.budget)
    report = {"env": "gbo_envs/DCMotor-v0", "budget": args.budget, "n_initial": 1, "seeds": args.seeds,
              "seed0": args.seed0,
              "optimum_cost": truth.cost, "optimum_gains": truth.gains.tolist(), "bo_kwargs": args.bo_kwargs,
              "table": table}
    if "bo" in table and "random" in table:
        report["bo_over_random_to_1.1"] = table["bo"]["mean_experiments_to_1.1"] / \
            table["random"]["mean_experiments_to_1.1"]
    print(json.dumps(report, indent=2))
    print()
    print(markdown(table, args.budget, args.seeds))
    if args.out:
        with open(args.out, "w") as handle:
            json.dump({**report, "runs": runs}, handle)
    return report


if __name__ == "__main__":
    main()
