"""The RL comparison study: real experiments to optimality ratio 1.1 and 1.05, RL against (guided) BO.

For every env, method and seed, one tuning run through the common
``run(env, budget, seed)`` loop; the optimality ratio after ``k`` plant
experiments is ``phi_k = J_true(best measured gains) / J(theta*)``
(:meth:`~agents.result.TuningResult.best_true_cost_curve` over the grid
optimum of :func:`gbo_envs.ground_truth`). The figure reported for a
threshold is the first ``k`` with ``phi_k <= threshold``; a run that never
gets there is counted as ``budget + 1`` and the table says how many runs
reached the threshold at all.

Runs are appended to a JSON-lines checkpoint as they finish, so an
interrupted study resumes where it stopped.
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import agents
import gbo_envs

__all__ = ["Method", "default_methods", "experiments_to_ratio", "rl_comparison", "markdown_table",
           "nominal_dc_motor"]

#: Env ids of the study (an id that is not registered is skipped and reported).
STUDY_ENV_IDS = ("gbo_envs/DCMotor-v0", "gbo_envs/DCMotorRig-v0")


@dataclass(frozen=True)
class Method:
    """One tuner configuration of the study.

    Attributes
    ----------
    label : str
        Name in the table (``"rl-sac (plant)"``).
    tuner : str
        Registry name for :func:`agents.make`, or an entry point ``"module:Class"``.
    budget : int
        Plant experiments per run.
    kwargs : dict
        Constructor arguments.
    """

    label: str
    tuner: str
    budget: int
    kwargs: dict = field(default_factory=dict)


def nominal_dc_motor(plant_env: gym.Env) -> gym.Env:
    """The nominal identified DC motor model (noise-free ``DCMotor-v0``) with the plant's cost normalisers.

    The train-on-twin model of the study for both DC motor envs: what a
    practitioner has before any experiment on the rig.
    """
    normalizers = getattr(plant_env.unwrapped, "normalizers", None)
    return gym.make("gbo_envs/DCMotor-v0", noise=False, normalizers=normalizers)


def default_methods(budget: int = 50, rl_budget: int | None = None, pretrain_steps: int = 2000,
                    include_ppo: bool = False) -> list[Method]:
    """RL in both modes, BO and guided BO (by registry name, else by entry point if installed).

    Parameters
    ----------
    budget : int, default 50
        Plant experiments per run of the BO methods (and of RL unless ``rl_budget``).
    rl_budget : int, optional
        Plant experiments per RL run (35-100 is the range of the study).
    pretrain_steps : int, default 2000
        Model experiments of the train-on-twin RL before deployment.
    include_ppo : bool, default False
        Add PPO (plant mode) besides SAC.
    """
    rl_budget = budget if rl_budget is None else rl_budget
    methods = [
        Method("rl-sac (plant)", "rl", rl_budget, {"algorithm": "sac", "mode": "plant"}),
        Method("rl-sac (twin)", "rl", rl_budget, {"algorithm": "sac", "mode": "twin", "model_env": nominal_dc_motor,
                                                  "pretrain_steps": pretrain_steps}),
    ]
    if include_ppo:
        methods.append(Method("rl-ppo (plant)", "rl", rl_budget, {"algorithm": "ppo", "mode": "plant"}))
    registered = set(agents.registered_names())
    for name, entry_point in (("bo", "agents.bo:BayesianOptimization"), ("guided-bo", "agents.guided_bo:GuidedBO")):
        if name in registered:
            methods.append(Method(name, name, budget))
        elif importlib.util.find_spec(entry_point.partition(":")[0]) is not None:
            methods.append(Method(name, entry_point, budget))
    return methods


def experiments_to_ratio(ratios: np.ndarray, threshold: float) -> int | None:
    """First plant experiment (1-based) with ``phi <= threshold``, or ``None`` if never."""
    hits = np.flatnonzero(np.asarray(ratios, dtype=float) <= threshold)
    return int(hits[0]) + 1 if hits.size else None


def rl_comparison(
    env_ids: Sequence[str] = STUDY_ENV_IDS,
    seeds: Sequence[int] = (0, 1, 2),
    methods: Sequence[Method] | None = None,
    thresholds: Sequence[float] = (1.1, 1.05),
    checkpoint: str | Path | None = None,
    ground_truth_resolution: int = 100,
    progress: bool = True,
) -> dict[str, Any]:
    """Run the comparison and summarise it.

    Parameters
    ----------
    env_ids : sequence of str
        Envs to tune; ids that are not registered are skipped (listed under ``"skipped"``).
    seeds : sequence of int
        One run per seed, method and env.
    methods : sequence of Method, optional
        Default :func:`default_methods`.
    thresholds : sequence of float, default (1.1, 1.05)
        Optimality ratios to reach.
    checkpoint : path, optional
        JSON-lines file of finished runs: read to skip them, appended to as runs finish.
    ground_truth_resolution : int, default 100
        Grid points per gain of the ground-truth optimum.
    progress : bool, default True
        One line per finished run on stderr.

    Returns
    -------
    dict
        ``runs`` (one dict per run), ``summary`` (one dict per env and method),
        ``optimum`` (``J(theta*)`` per env), ``skipped`` and ``interrupted``.
        Ctrl-C stops the study and returns what finished.
    """
    methods = list(default_methods() if methods is None else methods)
    known = set(gym.registry)
    skipped = {env_id: "not registered" for env_id in env_ids if env_id not in known}
    env_ids = [env_id for env_id in env_ids if env_id in known]
    runs = _load_checkpoint(checkpoint)
    done = {(run["env_id"], run["method"], run["seed"], run["budget"]) for run in runs}
    optimum: dict[str, float] = {}
    interrupted = False
    try:
        for env_id in env_ids:
            optimum[env_id] = gbo_envs.ground_truth(env_id, resolution=ground_truth_resolution).cost
            for method in methods:
                for seed in seeds:
                    if (env_id, method.label, int(seed), method.budget) in done:
                        continue
                    run = _one_run(env_id, method, int(seed), optimum[env_id], thresholds)
                    runs.append(run)
                    _append_checkpoint(checkpoint, run)
                    if progress:
                        reached = ", ".join(f"phi<={t}: {run['to_ratio'][str(t)] or 'never'}" for t in thresholds)
                        print(f"[rl-study] {env_id} {method.label} seed {seed}: {reached}; final phi "
                              f"{run['final_ratio']:.3f} ({run['wall_time_s']:.0f} s)", file=sys.stderr, flush=True)
    except KeyboardInterrupt:
        interrupted = True
    runs = [run for run in runs if run["env_id"] in optimum]
    return {
        "thresholds": [float(t) for t in thresholds],
        "seeds": [int(s) for s in seeds],
        "optimum": optimum,
        "skipped": skipped,
        "interrupted": interrupted,
        "summary": _summarise(runs, methods, thresholds),
        "runs": runs,
    }


def _one_run(env_id: str, method: Method, seed: int, optimum: float, thresholds) -> dict[str, Any]:
    env = gym.make(env_id)
    if ":" in method.tuner:
        module, _, name = method.tuner.partition(":")
        tuner = getattr(importlib.import_module(module), name)(**method.kwargs)
    else:
        tuner = agents.make(method.tuner, **method.kwargs)
    start = time.perf_counter()
    result = tuner.run(env, budget=method.budget, seed=seed)
    wall = time.perf_counter() - start
    ratios = result.best_true_cost_curve() / optimum
    return {
        "env_id": env_id,
        "method": method.label,
        "tuner": method.tuner,
        "seed": seed,
        "budget": method.budget,
        "to_ratio": {str(t): experiments_to_ratio(ratios, t) for t in thresholds},
        "final_ratio": float(ratios[-1]),
        "ratio_curve": [float(r) for r in ratios],
        "model_experiments": int(result.info.get("model_experiments", 0)),
        "twin_evaluations": int(result.n_twin),
        "wall_time_s": float(wall),
    }


def _summarise(runs: list[dict], methods: Sequence[Method], thresholds) -> list[dict]:
    summary = []
    env_ids = list(dict.fromkeys(run["env_id"] for run in runs))
    for env_id in env_ids:
        for method in methods:
            mine = [run for run in runs if run["env_id"] == env_id and run["method"] == method.label
                    and run["budget"] == method.budget]
            if not mine:
                continue
            entry: dict[str, Any] = {"env_id": env_id, "method": method.label, "budget": method.budget,
                                     "n_runs": len(mine),
                                     "model_experiments": int(np.mean([r["model_experiments"] for r in mine])),
                                     "twin_evaluations": float(np.mean([r["twin_evaluations"] for r in mine])),
                                     "final_ratio_mean": float(np.mean([r["final_ratio"] for r in mine]))}
            for threshold in thresholds:
                hits = [r["to_ratio"][str(threshold)] for r in mine]
                counted = [method.budget + 1 if h is None else h for h in hits]
                entry[str(threshold)] = {
                    "mean": float(np.mean(counted)),
                    "median": float(np.median(counted)),
                    "reached": sum(h is not None for h in hits),
                    "per_seed": hits,
                }
            summary.append(entry)
    return summary


def markdown_table(study: dict[str, Any]) -> str:
    """The study's summary as a Markdown table, saying plainly when a threshold was never reached."""
    thresholds = study["thresholds"]
    header = ["env", "method", "plant budget", "model exps (RL pre-training) / twin evals (mean)"]
    header += [f"real exps to phi<={t} (mean / median, reached)" for t in thresholds] + ["final phi (mean)"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for entry in study["summary"]:
        cells = [entry["env_id"].split("/")[-1], entry["method"], str(entry["budget"]),
                 f"{entry['model_experiments']} / {entry.get('twin_evaluations', 0.0):.0f}"]
        for threshold in thresholds:
            stats = entry[str(threshold)]
            if stats["reached"] == 0:
                cells.append(f"never within {entry['budget']} (0/{entry['n_runs']}; counted as {entry['budget'] + 1})")
            else:
                note = "" if stats["reached"] == entry["n_runs"] else f"; misses counted as {entry['budget'] + 1}"
                reached = f"{stats['reached']}/{entry['n_runs']}{note}"
                cells.append(f"{stats['mean']:.1f} / {stats['median']:.0f} ({reached})")
        cells.append(f"{entry['final_ratio_mean']:.3f}")
        lines.append("| " + " | ".join(cells) + " |")
    notes = [f"J(theta*) {env.split('/')[-1]} = {cost:.4f}" for env, cost in study["optimum"].items()]
    notes += [f"{env.split('/')[-1]} skipped: {why}" for env, why in study["skipped"].items()]
    if study.get("interrupted"):
        notes.append("study interrupted: the table holds the finished runs")
    return "\n".join(lines) + ("\n\n" + "; ".join(notes) if notes else "")


def _load_checkpoint(path) -> list[dict]:
    if path is None or not Path(path).exists():
        return []
    with open(path) as handle:
        return [json.loads(line) for line in handle if line.strip()]


def _append_checkpoint(path, run: dict) -> None:
    if path is None:
        return
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as handle:
        handle.write(json.dumps(run) + "\n")
