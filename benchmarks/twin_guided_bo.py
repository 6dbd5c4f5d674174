"""Guided BO on DCMotorRig-v0 with the linear twin against the twin with the diagnosed effects.

1. Diagnosis: 10 experiments at random gains on the rig, ``error_ladder`` (the
   workbench's greedy diagnose -> add -> diagnose) names the effects and their
   parameters.
2. For a few seeds, :class:`agents.guided_bo.GuidedBO` with the default linear
   SRIVC twin and with ``GreyBoxTwin(effects=<diagnosed>)`` (the fitted effect
   blocks go into the twin's closed loop through ``effects_``), 35 plant
   experiments each, same seeds.

Prints one JSON object: the ladder, and per variant the mean twin RMSE
(normalised, the ``eta2`` test's quantity, and in rad/s), the mean number of
activations and the real experiments to optimality ratio 1.05 (minimum observed
noise-free cost over the rig's ground-truth optimum; ``null`` if never reached).

Usage: ``python benchmarks/twin_guided_bo.py [n_seeds]`` (default 3).
"""

from __future__ import annotations

import json
import sys
import time

import gymnasium as gym
import numpy as np

import gbo_envs  # noqa: F401  (registers the envs)
from agents.guided_bo import GuidedBO
from agents.twin import GreyBoxTwin
from agents.twin.csvio import records_from_env
from agents.twin.data import GreyData
from agents.twin.workbench import error_ladder
from gbo_envs import ground_truth

ENV_ID = "gbo_envs/DCMotorRig-v0"
BUDGET = 35
RATIO = 1.05


def diagnosed_effects(seed: int = 100) -> tuple[dict, list[dict]]:
    """Effects and parameters the workbench finds on 10 rig experiments."""
    env = gym.make(ENV_ID)
    low, high = env.action_space.low, env.action_space.high
    gains = np.random.default_rng(seed).uniform(low, high, size=(10, low.size))
    data = GreyData.from_records(records_from_env(env, gains, seed=seed))
    rungs, diagnoses = error_ladder(data, max_steps=3)
    return dict(diagnoses[-1].current.effect_params), rungs


def run_variant(twin: GreyBoxTwin | None, seeds: list[int], optimum: float) -> dict:
    to_ratio, activations, rmse, rmse_abs, seconds = [], [], [], [], []
    for seed in seeds:
        env = gym.make(ENV_ID)
        tuner = GuidedBO(twin=twin) if twin is not None else GuidedBO()
        start = time.perf_counter()
        result = tuner.run(env, budget=BUDGET, seed=seed)
        seconds.append(time.perf_counter() - start)
        curve = result.min_true_cost_curve() / optimum
        hit = np.flatnonzero(curve <= RATIO)
        to_ratio.append(int(hit[0]) + 1 if hit.size else None)
        activations.append(tuner.activations_)
        if tuner.twin_ is not None:
            rmse.append(float(tuner.twin_.rmse_))
            rmse_abs.append(float(tuner.twin_.rmse_abs_))
    reached = [n for n in to_ratio if n is not None]
    return {"experiments_to_ratio": to_ratio, "mean_experiments_to_ratio": float(np.mean(reached)) if reached else None,
            "never_reached": to_ratio.count(None), "activations": activations,
            "mean_activations": float(np.mean(activations)), "twin_rmse_normalised": float(np.mean(rmse)),
            "twin_rmse_rad_s": float(np.mean(rmse_abs)), "seconds_per_run": float(np.mean(seconds))}


def main(n_seeds: int = 3) -> dict:
    effects, rungs = diagnosed_effects()
    optimum = float(ground_truth(ENV_ID, resolution=40).cost)
    seeds = list(range(n_seeds))
    linear = run_variant(None, seeds, optimum)
    grey = run_variant(GreyBoxTwin(effects=effects, n_samples=500), seeds, optimum)
    return {"env": ENV_ID, "budget": BUDGET, "ratio": RATIO, "seeds": seeds, "optimum": optimum,
            "diagnosed_effects": effects, "ladder": rungs, "linear_twin": linear, "diagnosed_twin": grey}


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)))
