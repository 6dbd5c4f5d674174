"""Speed of the digital twin: SRIVC fits and twin experiments.

Prints one JSON object:

* ``fit_s``: wall time of ``LinearTwin().fit`` on 1, 5 and 35 noise-free
  DCMotor-v0 records (2501 samples each, delay searched), for the full records
  and for ``n_samples=100`` (the paper's sampling length), and of a warm-started
  refit after adding the 35th record (``warm_start=True``, as guided BO refits);
* ``twin_experiment_s``: median time of one twin experiment (one gain pair,
  ``TwinEnv.evaluate``: simulation, metrics, cost);
* ``twin_batch_1000_s``: median time of ``TwinEnv.evaluate`` on 1000 gain pairs;
* ``greybox_twin_experiment_s``: median time of one experiment of a grey-box
  twin with saturation (``GreyBoxTwin(effects=["saturation"])`` fitted on the
  bundled ``examples/data/dc_rig.csv``), as guided BO builds it for
  DCMotorRig-v0 (``make_twin_env``): the loop is stepped sample by sample and
  the rig's measured noise is averaged over the twin's draws;
* ``fidelity``: parameter errors (%) and the max twin-vs-plant cost error (%)
  on a 20 x 20 grid of the feasible set for the 35-record fits.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from timing import median_time

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin import GreyBoxTwin, IdentifyOptions, LinearTwin, SrivcOptions, TwinEnv, make_twin_env
from agents.twin.csvio import read_csv
from gbo_envs.gain_grid import grid_axes, grid_points

TRUE = np.array([9.544, 4.145, 4.199])
#: the bundled workbench data (examples/data/make_dc_rig.py)
RIG_CSV = Path(__file__).resolve().parents[1] / "examples" / "data" / "dc_rig.csv"



def _records(env, n: int, seed: int = 0) -> list[dict]:
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    low, high = env.action_space.low, env.action_space.high
    return [env.step(rng.uniform(low, high))[4] for _ in range(n)]


def main() -> dict:
    env = gym.make("gbo_envs/DCMotor-v0", noise=False)
    records = _records(env, 35)
    low, high = env.action_space.low, env.action_space.high
    grid = grid_points(grid_axes(low, high, 20))
    plant_cost = env.unwrapped.evaluate(grid)[1]

    fit_s, fidelity, twins = {}, {}, {}
    for label, n_samples in (("full", None), ("n100", 100)):
        fit_s[label] = {}
        for n in (1, 5, 35):
            start = time.perf_counter()
            twin = LinearTwin(IdentifyOptions(solver=SrivcOptions(n_samples=n_samples))).fit(records[:n])
            fit_s[label][str(n)] = time.perf_counter() - start
        twins[label] = twin
        warm = LinearTwin(IdentifyOptions(solver=SrivcOptions(n_samples=n_samples)), warm_start=True)
        warm.fit(records[:34])
        start = time.perf_counter()
        warm.fit(records)
        fit_s[label]["35_warm_start"] = time.perf_counter() - start
        twin_cost = TwinEnv(env, twin).evaluate(grid)[1]
        fidelity[label] = {
            "param_error_pct": (100 * (twin.params_ - TRUE) / TRUE).tolist(),
            "delay_s": twin.delay_,
            "rmse": twin.rmse_,
            "max_cost_error_pct": float(100 * np.max(np.abs(twin_cost - plant_cost) / plant_cost)),
            "median_cost_error_pct": float(100 * np.median(np.abs(twin_cost - plant_cost) / plant_cost)),
        }

    twin_env = TwinEnv(env, twins["full"])
    one = np.array([[0.54, 1.16]])
    batch = np.random.default_rng(1).uniform(low, high, size=(1000, 2))
    greybox = GreyBoxTwin(effects=["saturation"]).fit(read_csv(RIG_CSV))
    greybox_env = make_twin_env(gym.make("gbo_envs/DCMotorRig-v0"), greybox)
    return {
        "fit_s": fit_s,
        "twin_experiment_s": median_time(lambda: twin_env.evaluate(one), 200),
        "twin_batch_1000_s": median_time(lambda: twin_env.evaluate(batch), 5),
        "greybox_twin_experiment_s": median_time(lambda: greybox_env.evaluate(one), 20),
        "fidelity": fidelity,
    }


if __name__ == "__main__":
    print(json.dumps(main()))
