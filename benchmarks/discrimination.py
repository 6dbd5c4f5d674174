"""Which benchmark envs tell tuners apart: random vs bo vs guided-bo on every registered env (issue 14).

For each env and tuner, over the same seeds: real experiments until the best
evaluated gains reach an optimality ratio ``J / J*`` of 1.1 and 1.05 (and
1.01 on the linear motors), ``J`` being the ground truth (expected cost over
the measurement noise, ``info["true_cost"]``) and ``J*`` its minimum on the
100 x 100 grid. A run that never reaches a ratio counts as ``budget + 1``
experiments and as a miss. The 95 % interval of the mean is Student's t. An
env and ratio where the intervals of random and bo overlap is marked "does not
discriminate".

Each finished run is appended to ``benchmarks/results/discrimination_runs.jsonl``
and skipped when the command is run again, so an interrupted study resumes.
Writes ``benchmarks/results/discrimination.md`` and ``.csv``::

    python benchmarks/discrimination.py                 # 8 envs x 3 tuners x 20 seeds, about 25 min on 2 cores
    python benchmarks/discrimination.py --env gbo_envs/DCMotorRig-v0 --seeds 30
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
from data_efficiency import experiments_to_reach
from joblib import Parallel, delayed
from scipy import stats
from tqdm import tqdm

import gbo_envs

RESULTS = Path(__file__).resolve().parent / "results"
TUNERS = ("random", "bo", "guided-bo")


def thresholds(env_id: str) -> tuple[float, ...]:
    """Ratios reported for ``env_id``: 1.01 only on the linear motors, as in the paper."""
    return (1.1, 1.05, 1.01) if "LinearMotor" in env_id else (1.1, 1.05)


def run_one(env_id: str, tuner: str, seed: int, optimum: float) -> dict:
    """One tuning session; returns its minimum-observed optimality-ratio curve."""
    import agents
    import gbo_envs  # noqa: F401  (registers the envs in a fresh worker)
    from agents.thread_limits import single_thread

    start = time.perf_counter()
    env = gym.make(env_id)
    with single_thread(user_api=None):
        result = agents.make(tuner).run(env, budget=env.spec.max_episode_steps, seed=seed)
    ratios = result.min_true_cost_curve() / optimum
    return {"env": env_id, "tuner": tuner, "seed": seed, "optimum": optimum, "ratios": ratios.tolist(),
            "seconds": round(time.perf_counter() - start, 2)}


def interval(counts: np.ndarray) -> tuple[float, float, float]:
    """Mean and its 95 % Student-t interval."""
    mean = float(np.mean(counts))
    half = float(stats.t.ppf(0.975, counts.size - 1) * np.std(counts, ddof=1) / np.sqrt(counts.size))
    return mean, mean - half, mean + half


def summarise(runs: list[dict], seeds: list[int]) -> pd.DataFrame:
    rows = []
    for env_id in dict.fromkeys(r["env"] for r in runs):
        budget = gym.spec(env_id).max_episode_steps
        for threshold in thresholds(env_id):
            found = {}
            for tuner in TUNERS:
                mine = [r for r in runs if r["env"] == env_id and r["tuner"] == tuner and r["seed"] in seeds]
                if len(mine) < 2:
                    continue
                counts = np.array([experiments_to_reach(r["ratios"], threshold) for r in mine])
                mean, low, high = interval(counts)
                found[tuner] = (low, high)
                rows.append({"env": env_id.split("/")[-1], "ratio": threshold, "tuner": tuner, "seeds": len(mine),
                             "mean_experiments": round(mean, 2), "ci95_low": round(low, 2),
                             "ci95_high": round(high, 2), "misses": int(np.sum(counts > budget)), "budget": budget})
            if "random" in found and "bo" in found:
                (r_low, r_high), (b_low, b_high) = found["random"], found["bo"]
                overlap = r_low <= b_high and b_low <= r_high
                for row in rows[-len(found):]:
                    row["random_vs_bo"] = "does not discriminate" if overlap else "discriminates"
    return pd.DataFrame(rows)


def markdown(table: pd.DataFrame) -> str:
    lines = ["| env | ratio | random | bo | guided-bo | bo / random | random vs bo |", "|---|---|---|---|---|---|---|"]
    for (env, ratio), group in table.groupby(["env", "ratio"], sort=False):
        cells = {}
        for _, row in group.iterrows():
            cells[row["tuner"]] = (f"{row['mean_experiments']:.1f} [{row['ci95_low']:.1f}, {row['ci95_high']:.1f}]"
                                   f" ({row['misses']} misses)")
        means = dict(zip(group["tuner"], group["mean_experiments"]))
        ratio_bo = f"{means['bo'] / means['random']:.2f}" if {"bo", "random"} <= means.keys() else "-"
        verdict = group["random_vs_bo"].iloc[0] if "random_vs_bo" in group else "-"
        lines.append(f"| {env} | {ratio} | {cells.get('random', '-')} | {cells.get('bo', '-')} | "
                     f"{cells.get('guided-bo', '-')} | {ratio_bo} | {verdict} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> pd.DataFrame:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", action="append", help="env id (repeatable; default: every registered env)")
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", default=str(RESULTS), help="directory of the runs file and the tables")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log = out / "discrimination_runs.jsonl"
    done = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    env_ids = args.env or list(gbo_envs.ENV_IDS)
    seeds = list(range(args.seeds))
    optima = {}
    for env_id in tqdm(env_ids, desc="ground truths", unit="env"):
        known = [r["optimum"] for r in done if r["env"] == env_id]
        optima[env_id] = known[0] if known else gbo_envs.ground_truth(env_id, resolution=100).cost
    have = {(r["env"], r["tuner"], r["seed"]) for r in done}
    jobs = [(e, t, s) for e in env_ids for s in seeds for t in TUNERS if (e, t, s) not in have]
    with log.open("a") as sink:
        for run in tqdm(Parallel(n_jobs=args.jobs, return_as="generator_unordered")(
                delayed(run_one)(e, t, s, optima[e]) for e, t, s in jobs), total=len(jobs), desc="runs", unit="run"):
            sink.write(json.dumps(run) + "\n")
            sink.flush()
            done.append(run)
    table = summarise([r for r in done if r["env"] in env_ids], seeds)
    table.to_csv(out / "discrimination.csv", index=False)
    text = (f"Real experiments to reach each optimality ratio, mean [95 % CI] (misses) over {len(seeds)} shared "
            "seeds; a miss counts as budget + 1.\n\n" + markdown(table) + "\n")
    (out / "discrimination.md").write_text(text)
    print(text)
    return table


if __name__ == "__main__":
    main()
