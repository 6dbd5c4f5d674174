"""The peer libraries against the default BO: same envs, seeds, budget and initial design (issue 16, point 4).

For each env and tuner row, over the same seeds: one tuning run with the env's episode
length as budget (35 on the DC motors, 25 on the linear motor), every tuner starting from
``agents.make("bo")``'s Latin hypercube initial design (N0 = 1), and the real experiments
until the best evaluated gains reach an optimality ratio ``J / J*`` (``J``: the env's
expected cost, ``info["true_cost"]``; ``J*``: its minimum on the 100 x 100 ground-truth
grid, :func:`gbo_envs.ground_truth`, cached in ``benchmarks/results/ground_truth.json``).
A run that never reaches a ratio counts as ``budget + 1`` and as a miss. Means with 95 %
Student-t intervals, the ratio of each mean to ``bo``'s, and seconds per run (one worker
is one core: BLAS and torch run single-threaded).

Rows (:data:`ROWS`): ``bo`` (the reference), ``bo-envelope`` (``settling_model="envelope"``, the
stronger BO on the DC motors), ``guided-bo``, ``optuna-gp`` (Optuna's
GPSampler), ``botorch`` (qLogNEI), ``botorch-logei``, ``skopt`` (gp_minimize's setup) and
``bayes-opt``. A row whose library is not installed is skipped with a note
(``pip install "gbo-envs[peers]"``). The rows are compared on the seeds all of them ran; a
row that ran fewer seeds is summarised on the seeds it shares with ``bo``, against ``bo``
on those seeds (its own seed count in the table).

The ``guided-bo`` and ``bo, envelope settling`` runs of ``guided_bo_ablation.py`` (same envs,
seeds, budget and initial design; its ``bo`` runs are those of this study, bit for bit) count
as this study's ``guided-bo`` and ``bo-envelope``: ``--summary`` pulls them from
``benchmarks/results/guided_bo_ablation_runs.jsonl`` where this study has not run that seed itself.

Each finished run is appended to ``benchmarks/results/peers_runs.jsonl`` and skipped when
the command is run again (an interrupted study resumes). Writes
``benchmarks/results/peers.md`` and ``benchmarks/results/peers.csv``::

    python benchmarks/peers.py --seeds 30                                  # every env and row, seeds 0-29
    python benchmarks/peers.py --envs DCMotor-v0 --rows bo skopt --seeds 5 --workers 1
    python benchmarks/peers.py --summary                                   # tables from the runs so far
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
from run_log import append_runs, load_runs

RESULTS = Path(__file__).resolve().parent / "results"
RUNS = RESULTS / "peers_runs.jsonl"
#: The ablation study's run log, whose guided-bo and envelope-BO runs on these envs are this study's too.
ABLATION_RUNS = RESULTS / "guided_bo_ablation_runs.jsonl"
#: ablation variant -> the row of this study it is
ABLATION_ROWS = {"guided-bo": "guided-bo", "bo, envelope settling": "bo-envelope"}

#: row label -> (registry name, constructor keywords): every row starts from BO's N0 = 1 design.
ROWS: dict[str, tuple[str, dict]] = {
    "bo": ("bo", {}),
    "bo-envelope": ("bo", {"settling_model": "envelope"}),
    "guided-bo": ("guided-bo", {}),
    "optuna-gp": ("optuna-gp", {"n_initial": 1}),
    "botorch": ("botorch", {"n_initial": 1, "acquisition": "qlognei"}),
    "botorch-logei": ("botorch", {"n_initial": 1, "acquisition": "logei"}),
    "skopt": ("skopt", {"n_initial": 1}),
    "bayes-opt": ("bayes-opt", {"n_initial": 1}),
}

#: env label -> the optimality ratios reported
ENVS: dict[str, tuple[float, ...]] = {
    "DCMotor-v0": (1.1, 1.05),
    "DCMotorRig-v0": (1.1, 1.05),
    "LinearMotor-v0": (1.05, 1.01),
}

REFERENCE = "bo"


def available(row: str) -> bool:
    """Whether the row's tuner can be built; prints a note when its library is missing."""
    import agents

    name, kwargs = ROWS[row]
    try:
        agents.make(name, **kwargs)
    except ImportError as exc:
        print(f"note: skipping {row}: {exc}")
        return False
    return True


def run_one(env_label: str, row: str, seed: int, best: float) -> dict:
    """One tuning run of ``row`` on ``env_label`` with ``seed``: its minimum-observed optimality-ratio curve."""
    import agents
    import gbo_envs  # noqa: F401  (registers the envs in a fresh worker)
    from agents.thread_limits import single_thread

    try:
        import torch
    except ImportError:
        pass
    else:
        torch.set_num_threads(1)
    name, kwargs = ROWS[row]
    env = gym.make(f"gbo_envs/{env_label}")
    start = time.perf_counter()
    with warnings.catch_warnings(), single_thread(user_api=None):
        warnings.simplefilter("ignore")
        result = agents.make(name, **kwargs).run(env, budget=env.spec.max_episode_steps, seed=seed)
    return {"env": env_label, "row": row, "seed": seed, "ratios": (result.min_true_cost_curve() / best).tolist(),
            "seconds": round(time.perf_counter() - start, 2)}


def ablation_runs(runs: list[dict]) -> list[dict]:
    """``guided_bo_ablation.py``'s runs of :data:`ABLATION_ROWS` on :data:`ENVS` at seeds ``runs`` lacks, as runs
    of this study."""
    have = {(r["env"], r["row"], r["seed"]) for r in runs}
    return [{"env": r["plant"], "row": ABLATION_ROWS[r["variant"]], "seed": r["seed"], "ratios": r["ratios"],
             "seconds": r["seconds"], "source": ABLATION_RUNS.name}
            for r in load_runs(ABLATION_RUNS) if r["variant"] in ABLATION_ROWS and r["plant"] in ENVS
            and (r["plant"], ABLATION_ROWS[r["variant"]], r["seed"]) not in have]


def summarise(runs: list[dict]) -> pd.DataFrame:
    """One line per env, ratio and row, on the seeds every row of that env has run.

    A row that lacks some of those seeds is summarised on the seeds it shares with bo, and
    its ``vs_bo`` is against bo on the same seeds.

    Columns: env, ratio, row, seeds, mean, ci_low, ci_high (real experiments to the ratio,
    95 % Student-t), misses, vs_bo (mean / bo's mean on the row's seeds; NaN without a bo
    row), seconds (mean per run).
    """
    lines = []
    for env_label, ratios in ENVS.items():
        mine = {row: {r["seed"]: r for r in runs if r["env"] == env_label and r["row"] == row} for row in ROWS}
        rows = [row for row in ROWS if mine[row]]
        if not rows:
            continue
        # the rows that ran every seed bo ran (every row without a bo row), on the seeds they share;
        # a row that ran fewer: on the seeds it shares with bo
        reference = set(mine[REFERENCE])
        full = [row for row in rows if set(mine[row]) >= reference]
        shared = set.intersection(*(set(mine[row]) for row in full)) if full else set()
        seeds_of = {row: sorted(shared if row in full else set(mine[row]) & reference) for row in rows}
        for threshold in ratios:
            for row in rows:
                seeds = seeds_of[row]
                if len(seeds) < 2:
                    continue
                mean, low, high, misses = _reach(mine[row], seeds, threshold)
                bo_mean = _reach(mine[REFERENCE], seeds, threshold)[0] if reference else float("nan")
                lines.append({"env": env_label, "ratio": threshold, "row": row, "seeds": len(seeds), "mean": mean,
                              "ci_low": low, "ci_high": high, "misses": misses, "vs_bo": mean / bo_mean,
                              "seconds": float(np.mean([mine[row][s]["seconds"] for s in seeds]))})
    columns = ["env", "ratio", "row", "seeds", "mean", "ci_low", "ci_high", "misses", "vs_bo", "seconds"]
    return pd.DataFrame(lines, columns=columns)


def _reach(runs_of: dict[int, dict], seeds: list[int], threshold: float) -> tuple[float, float, float, int]:
    """Mean [95 % CI] real experiments to ``threshold`` over ``seeds``, and the misses."""
    from data_efficiency import experiments_to_reach
    from effect_aware_guided_bo import interval

    curves = [runs_of[s]["ratios"] for s in seeds]
    counts = np.array([experiments_to_reach(curve, threshold) for curve in curves])
    return (*interval(counts), int(sum(c > len(curve) for c, curve in zip(counts, curves))))


def markdown(table: pd.DataFrame) -> str:
    """The summary as one Markdown table per env and ratio."""
    parts = []
    for (env_label, threshold), group in table.groupby(["env", "ratio"], sort=False):
        parts.append(f"### {env_label}, ratio {threshold} ({int(group['seeds'].max())} seeds)\n")
        parts.append("| tuner | experiments to ratio, mean [95 % CI] (misses) | / bo (same seeds) | seeds | s/run |")
        parts.append("|---|---|---|---|---|")
        for line in group.itertuples():
            parts.append(f"| {line.row} | {line.mean:.1f} [{line.ci_low:.1f}, {line.ci_high:.1f}] ({line.misses}) | "
                         f"{line.vs_bo:.2f} | {line.seeds} | {line.seconds:.1f} |")
        parts.append("")
    return "\n".join(parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=list(ENVS), choices=list(ENVS))
    parser.add_argument("--rows", nargs="+", default=list(ROWS), choices=list(ROWS))
    parser.add_argument("--seeds", type=int, default=30, help="seeds 0..N-1 (default 30)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--summary", action="store_true", help="only write and print the tables of the runs so far")
    args = parser.parse_args()
    runs = load_runs(RUNS)
    pulled = ablation_runs(runs)  # the ablation's runs at seeds this study lacks: done, and summarised
    if not args.summary:
        from effect_aware_guided_bo import optimum

        rows = [row for row in args.rows if available(row)]
        optima = {env_label: optimum(env_label)["cost"] for env_label in args.envs}
        done = {(r["env"], r["row"], r["seed"]) for r in runs + pulled}
        todo = [(e, r, s, optima[e]) for e in args.envs for s in range(args.seeds) for r in rows
                if (e, r, s) not in done]
        runs += append_runs(RUNS, run_one, todo, args.workers)
    table = summarise(runs + pulled)
    table.round(4).to_csv(RESULTS / "peers.csv", index=False)
    text = markdown(table)
    (RESULTS / "peers.md").write_text(
        "Real experiments to each optimality ratio, mean [95 % CI] (misses; a miss counts as budget + 1), the "
        "ratio of the mean to bo's on the same seeds, and seconds per run; the same N0 = 1 Latin hypercube start "
        "for every tuner, the seeds every tuner ran (a row with fewer: the seeds it shares with bo; guided-bo's "
        "and bo-envelope's runs are guided_bo_ablation.py's) (benchmarks/peers.py).\n\n" + text)
    print(text)


if __name__ == "__main__":
    main()
