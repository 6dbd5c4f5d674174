"""BO vs guided BO on the rig stand-in DCMotorRig-v0 (issue 5): real experiments to optimality ratios.

The rig has a command limit, Coulomb friction and encoder quantisation that the
twin's linear model lacks. Ratio = lowest noise-free cost observed / the rig's
ground-truth optimum. Prints a Markdown table and one JSON line. Not part of
``make bench`` (about 3 minutes on 2 cores): ``python benchmarks/rig_comparison.py``.
"""

from __future__ import annotations

import argparse
import json

import gymnasium as gym
import numpy as np
from joblib import Parallel, delayed

import agents
import gbo_envs

THRESHOLDS = (1.1, 1.05)


def run_one(env_id: str, tuner: str, seed: int, budget: int, optimum: float, kwargs: dict) -> dict:
    import gbo_envs  # noqa: F401  (registers the envs in a fresh worker)

    result = agents.make(tuner, **kwargs).run(gym.make(env_id), budget=budget, seed=seed)
    ratios = result.min_true_cost_curve() / optimum
    return {"tuner": tuner, "seed": seed, "ratios": ratios.tolist(),
            "activations": result.info.get("activations", 0), "twin_rmse": result.info.get("twin_rmse")}


def first_reach(ratios, threshold: float) -> int:
    hits = np.flatnonzero(np.asarray(ratios) <= threshold)
    return int(hits[0]) + 1 if hits.size else len(ratios) + 1


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="gbo_envs/DCMotorRig-v0")
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--budget", type=int, default=35)
    parser.add_argument("--guided-kwargs", type=json.loads, default={}, help="JSON kwargs for guided-bo")
    args = parser.parse_args(argv)
    optimum = gbo_envs.ground_truth(args.env, resolution=100).cost
    jobs = [(tuner, seed, args.guided_kwargs if tuner == "guided-bo" else {})
            for tuner in ("bo", "guided-bo") for seed in range(args.seeds)]
    runs = Parallel(n_jobs=2)(delayed(run_one)(args.env, t, s, args.budget, optimum, k) for t, s, k in jobs)
    table = {}
    print(f"| tuner | {' | '.join(f'to {t} (never)' for t in THRESHOLDS)} | activations | twin RMSE |")
    print("|---|" + "---|" * (len(THRESHOLDS) + 2))
    for tuner in ("bo", "guided-bo"):
        mine = [r for r in runs if r["tuner"] == tuner]
        row = {}
        for threshold in THRESHOLDS:
            counts = np.array([first_reach(r["ratios"], threshold) for r in mine])
            row[str(threshold)] = {"mean": float(counts.mean()), "never": int((counts > args.budget).sum())}
        row["activations"] = float(np.mean([r["activations"] for r in mine]))
        rmses = [r["twin_rmse"] for r in mine if r["twin_rmse"] is not None]
        row["twin_rmse"] = float(np.mean(rmses)) if rmses else None
        table[tuner] = row
        cells = " | ".join(f"{row[str(t)]['mean']:.2f} ({row[str(t)]['never']})" for t in THRESHOLDS)
        rmse = f"{row['twin_rmse']:.4f}" if row["twin_rmse"] is not None else "-"
        print(f"| {tuner} | {cells} | {row['activations']:.1f} | {rmse} |")
    out = {"env": args.env, "optimum": optimum, "seeds": args.seeds, "budget": args.budget, "table": table}
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
