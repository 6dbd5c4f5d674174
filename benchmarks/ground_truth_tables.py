"""Compute the ground-truth tables shipped with gbo_envs (``gbo_envs/data/ground_truth/<env>.npz``).

``gbo_envs.ground_truth(id)`` of a rig at its default kwargs and
``resolution=100`` reads this table instead of simulating ``100 x 100 x K``
experiments (``K = expectation_draws``, 56 on ``DCMotorRig-v0`` and 256 on
``LinearMotorRig-v0``: a minute or more of CPU each); of an env with three or
more gains (:data:`SEARCH_ENVS`) at its default kwargs and search settings, it
reads the certified search's result (optimum, tolerance, the second search's
answer, their disagreement) instead of simulating tens of thousands of gains. Run this script
after any change to a rig's physics, cost or default kwargs; the tests
(``tests/gbo_envs/test_ground_truth_tables.py``) fail until the tables match the
live expectation again. Each row of the grid (one value of the first gain) is
kept in ``benchmarks/results/ground_truth_tables_parts/`` as it is done, so an
interrupted run resumes; the parts are removed once the table is written.
Prints the CPU time of the live computation::

    python benchmarks/ground_truth_tables.py                 # every table, about 4 min of CPU
    python benchmarks/ground_truth_tables.py --env gbo_envs/DCMotorRig-v0
    python benchmarks/ground_truth_tables.py --env gbo_envs/DCMotorPID-v0
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm import tqdm

import gbo_envs
from gbo_envs.gain_grid import grid_axes, grid_points
from gbo_envs.ground_truth import search_settings
from gbo_envs.ground_truth_tables import fingerprint, save_search_table, save_table

#: Envs whose default 100 x 100 ground truth is shipped (live: well over the 3 s target).
GRID_ENVS = ("gbo_envs/DCMotorRig-v0", "gbo_envs/LinearMotorRig-v0")
#: Envs with three or more gains whose default certified search is shipped.
SEARCH_ENVS = ("gbo_envs/DCMotorPID-v0", "gbo_envs/LinearMotorCascade-v0", "gbo_envs/LinearMotorCascadeRig-v0")
TABLE_ENVS = GRID_ENVS + SEARCH_ENVS
RESOLUTION = 100
RESULTS = Path(__file__).resolve().parent / "results" / "ground_truth_tables.json"
PARTS = RESULTS.parent / "ground_truth_tables_parts"


def build_search(env_id: str) -> dict:
    """Run the default certified search of ``env_id`` at its default kwargs live and write its table.

    What ``gbo_envs.ground_truth(env_id, use_table=False)`` computes; reports its wall and CPU time.
    """
    env = gym.make(env_id)
    search = search_settings(env.unwrapped.action_space.shape[0])
    start, cpu = time.perf_counter(), time.process_time()
    truth = gbo_envs.ground_truth(env, use_table=False, progress=True)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    result = {"gains": truth.gains, "cost": truth.cost, "tolerance": truth.tolerance, "check_gains": truth.check_gains,
              "check_cost": truth.check_cost, "disagreement": truth.disagreement, "evaluations": truth.evaluations}
    path = save_search_table(env, search, result)
    return {"env": env_id, "search": search, "expectation_draws": env.unwrapped.expectation_draws,
            "wall_s_this_run": round(wall, 1), "cpu_s_this_run": round(cpu, 1), "J*": truth.cost,
            "gains": dict(zip(truth.gain_names, truth.gains.tolist())), "tolerance": truth.tolerance,
            "check_J": truth.check_cost, "check_gains": dict(zip(truth.gain_names, truth.check_gains.tolist())),
            "disagreement": truth.disagreement, "certified": truth.certified, "evaluations": truth.evaluations,
            "table": path.name, "table_bytes": path.stat().st_size}


def build(env_id: str) -> dict:
    """Compute the live grid of ``env_id`` at its default kwargs, row by row, and write its table.

    Each cell is ``env.evaluate`` at its gains, what ``gbo_envs.ground_truth(..., use_table=False)`` computes.
    """
    env = gym.make(env_id)
    plant = env.unwrapped
    stamp = json.dumps(fingerprint(env, RESOLUTION), sort_keys=True)
    parts = PARTS / f"{env_id.split('/')[-1]}-{hashlib.sha256(stamp.encode()).hexdigest()[:12]}"
    parts.mkdir(parents=True, exist_ok=True)
    axes = grid_axes(plant.action_space.low, plant.action_space.high, RESOLUTION)
    cpu = 0.0
    rows = []
    for i in tqdm(range(RESOLUTION), desc=env_id, unit="row"):
        part = parts / f"{i:04d}.npy"
        if not part.exists():
            start = time.process_time()
            costs = plant.evaluate(grid_points((axes[0][i : i + 1], *axes[1:])), experiment_index=0)[1]
            cpu += time.process_time() - start
            np.save(part, costs)
        rows.append(np.load(part))
    costs = np.stack(rows).reshape([axis.size for axis in axes])
    path = save_table(env, axes, costs)
    shutil.rmtree(parts)
    best = np.unravel_index(int(np.argmin(costs)), costs.shape)
    return {"env": env_id, "resolution": RESOLUTION, "expectation_draws": plant.expectation_draws,
            "cpu_s_this_run": round(cpu, 1), "J*": float(costs[best]), "optimum_cell": list(map(int, best)),
            "table": path.name, "table_bytes": path.stat().st_size}


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", action="append", help=f"env id (repeatable; default: {', '.join(TABLE_ENVS)})")
    args = parser.parse_args(argv)
    rows = [build(env_id) if gym.make(env_id).unwrapped.action_space.shape[0] <= 2 else build_search(env_id)
            for env_id in (args.env or TABLE_ENVS)]
    previous = json.loads(RESULTS.read_text()) if RESULTS.exists() else []
    merged = {r["env"]: r for r in previous} | {r["env"]: r for r in rows}
    RESULTS.write_text(json.dumps(list(merged.values()), indent=1) + "\n")
    for row in rows:
        print(json.dumps(row))
    return rows


if __name__ == "__main__":
    main()
