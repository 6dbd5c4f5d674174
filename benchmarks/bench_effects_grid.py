"""Speed of the sample-by-sample simulator: the ground-truth grid of a DC motor with effects.

Prints one JSON object:

* ``grid_100x100_s``: wall time of ``gbo_envs.ground_truth(env, resolution=100)``
  (10 000 experiments of 2501 samples, stepped through the effect blocks) for
  ``gym.make("gbo_envs/DCMotor-v0", effects={"saturation": {"limit": 150.0},
  "coulomb_friction": {"torque": 20.0}})`` (target < 10 s);
* ``experiments_per_s``: the same figure as a throughput;
* ``grid_optimum``: the optimum found, and ``linear_grid_100x100_s``, the
  effect-free grid on the linear fast path, for comparison.
"""

from __future__ import annotations

import json
import time

import gymnasium as gym

import gbo_envs

EFFECTS = {"saturation": {"limit": 150.0}, "coulomb_friction": {"torque": 20.0}}
RESOLUTION = 100


def _timed_grid(env) -> tuple[float, gbo_envs.GroundTruth]:
    start = time.perf_counter()
    truth = gbo_envs.ground_truth(env, resolution=RESOLUTION)
    return time.perf_counter() - start, truth


def main() -> dict:
    env = gym.make("gbo_envs/DCMotor-v0", noise=False, effects=EFFECTS).unwrapped
    seconds, truth = _timed_grid(env)
    linear_seconds, _ = _timed_grid(gym.make("gbo_envs/DCMotor-v0", noise=False).unwrapped)
    return {
        "benchmark": "effects_grid",
        "effects": EFFECTS,
        "grid_100x100_s": seconds,
        "experiments_per_s": RESOLUTION**2 / seconds,
        "grid_optimum": {"Kp": float(truth.gains[0]), "Ki": float(truth.gains[1]), "cost": truth.cost},
        "linear_grid_100x100_s": linear_seconds,
        "targets": {"grid_max_s": 10.0},
    }


if __name__ == "__main__":
    print(json.dumps(main()))
