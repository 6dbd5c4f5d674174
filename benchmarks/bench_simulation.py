"""Speed of one closed-loop experiment against python-control, and of the ground-truth grid.

Prints one JSON object:

* ``experiment_s``: median wall time of one DCMotor-v0 experiment (simulation
  and the four metrics) through the vectorised simulator;
* ``python_control_s``: median time python-control needs for the same closed
  loop (continuous PI, plant, 5th-order Pade delay: higher orders overflow in
  python-control at 2 ms; ``step_response`` on the same 2501 time points),
  the simulation alone, without metrics;
* ``speedup``: their ratio (target >= 50);
* ``grid_100x100_s``: wall time of ``gbo_envs.ground_truth(env, resolution=100)`` (target < 2 s),
  with the optimum found.
"""

from __future__ import annotations

import json
import time

import control as ct
import gymnasium as gym
import numpy as np
from timing import median_time

import gbo_envs


def main() -> dict:
    env = gym.make("gbo_envs/DCMotor-v0", noise=False).unwrapped
    loop = env.loop
    gains = np.array([[0.54, 1.16]])
    ours = median_time(lambda: loop.metrics(loop.simulate(gains)), 300)

    plant = ct.tf([9.544], [1.0, 4.145, 4.199])
    pade = ct.tf(*ct.pade(0.002, 5))
    controller = ct.tf([0.54, 0.54 * 1.16], [1.0, 0.0])
    closed = ct.feedback(controller * plant * pade, 1)
    times = loop.time
    reference = median_time(lambda: ct.step_response(closed, times), 30)

    start = time.perf_counter()
    truth = gbo_envs.ground_truth(env, resolution=100)
    grid = time.perf_counter() - start
    return {
        "experiment_s": ours,
        "python_control_s": reference,
        "speedup": reference / ours,
        "grid_100x100_s": grid,
        "grid_optimum": {"Kp": float(truth.gains[0]), "Ki": float(truth.gains[1]), "cost": truth.cost},
        "targets": {"speedup_min": 50, "grid_max_s": 2.0},
    }


if __name__ == "__main__":
    print(json.dumps(main()))
