"""Speed of ``gbo twin diagnose``: 10 experiments of 2,501 samples with a hidden effect.

Prints one JSON object: the wall time of :func:`agents.twin.workbench.diagnose`
(every catalogued effect fitted, ranked by 4-fold cross-validation over
experiments) on DCMotor-v0 data with a hidden saturation (limit 150) and
sensor noise 0.3 rad/s, with the data's size, the named effect and the RMSEs.
The issue's target is under 60 s on the project machine.
"""

from __future__ import annotations

import json
import time

import gymnasium as gym
import numpy as np

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.csvio import records_from_loop
from agents.twin.greybox import GreyData
from agents.twin.workbench import diagnose


def main(n_experiments: int = 10, seed: int = 0) -> dict:
    env = gym.make("gbo_envs/DCMotor-v0", effects={"saturation": {"limit": 150.0}}, output_noise_std=0.3)
    low, high = env.action_space.low, env.action_space.high
    gains = np.random.default_rng(seed).uniform(low, high, size=(n_experiments, low.size))
    records = records_from_loop(env.unwrapped.loop, gains, rng=np.random.default_rng(seed))
    data = GreyData.from_records(records)
    start = time.perf_counter()
    result = diagnose(data)
    elapsed = time.perf_counter() - start
    out = result.to_dict()
    return {"benchmark": "diagnose", "n_experiments": data.n_records, "n_samples_per_experiment": int(data.u.shape[1]),
            "n_candidates": len(out["candidates"]), "time_s": round(elapsed, 2), "target_s": 60.0,
            "best": out["best"], "rmse_linear": out["rmse"],
            "rmse_best": out["candidates"][0]["train_rmse"] if out["candidates"] else None,
            "noise_rmse": out["noise_rmse"]}


if __name__ == "__main__":
    print(json.dumps(main()))
