"""Speed of ``gbo twin diagnose``: 12 experiments of 2,501 samples (issue 15, point 4).

Prints one JSON object per case: the wall time and the CPU time (``time.process_time``:
this process, all its threads) of :func:`agents.twin.workbench.diagnose` (every catalogued
effect tried, ranked by 4-fold cross-validation over experiments) with the data's size,
the named effect, the ranking and the RMSEs (rad/s). Cases:

* ``dcmotor_saturation``: DCMotor-v0 with a hidden saturation (limit 150) and sensor
  noise 0.3 rad/s, 12 experiments at random gains;
* ``dcmotor_rig``: 12 experiments of DCMotorRig-v0 (saturation 160, Coulomb friction 5,
  speed encoder; no speed reversal, so friction acts as a constant load).

The issue's target is at most 15 s per case on the project machine (2 cores), goal 5 s::

    python benchmarks/bench_diagnose.py            # both cases, once
    python benchmarks/bench_diagnose.py --repeat 3  # the median of 3 runs per case
    python benchmarks/bench_diagnose.py --command --repeat 3   # the gbo command a user runs

``--command`` writes each case's records to a CSV and times the whole ``gbo twin diagnose
FILE --quiet`` process (start-up, reading, the diagnosis, the advice): its wall time and,
from the child's ``getrusage``, its system time, minor page faults and peak resident size.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.csvio import records_from_loop, write_csv
from agents.twin.data import GreyData
from agents.twin.workbench import diagnose

CASES = {
    "dcmotor_saturation": ("gbo_envs/DCMotor-v0", {"effects": {"saturation": {"limit": 150.0}},
                                                   "output_noise_std": 0.3}),
    "dcmotor_rig": ("gbo_envs/DCMotorRig-v0", {}),
}


def case_records(case: str, n_experiments: int = 12, seed: int = 0) -> tuple[list, tuple[str, ...]]:
    """The records of ``case`` at ``n_experiments`` random gains (uniform on the env's action space), and
    the env's gain names."""
    env_id, kwargs = CASES[case]
    env = gym.make(env_id, **kwargs)
    low, high = env.action_space.low, env.action_space.high
    gains = np.random.default_rng(seed).uniform(low, high, size=(n_experiments, low.size))
    return records_from_loop(env.unwrapped.loop, gains, rng=np.random.default_rng(seed)), env.unwrapped.gain_names


def case_data(case: str, n_experiments: int = 12, seed: int = 0) -> GreyData:
    """:func:`case_records` as the workbench's data."""
    return GreyData.from_records(case_records(case, n_experiments, seed)[0])


def main(case: str = "dcmotor_saturation", n_experiments: int = 12, seed: int = 0, repeat: int = 1) -> dict:
    data = case_data(case, n_experiments, seed)
    times, cpu = [], []
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        result = diagnose(data)
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    out = result.to_dict()
    top = out["candidates"][0] if out["candidates"] else None
    return {"benchmark": "diagnose", "case": case, "n_experiments": data.n_records,
            "n_samples_per_experiment": int(data.u.shape[1]), "n_candidates": len(out["candidates"]),
            "time_s": round(float(np.median(times)), 2), "times_s": [round(t, 2) for t in times], "target_s": 15.0,
            "cpu_s": round(float(np.median(cpu)), 2), "cpus_s": [round(t, 2) for t in cpu],
            "best": out["best"], "ranking": [c["effect"] for c in out["candidates"]],
            "rmse": out["rmse"], "heldout_rmse": out["heldout_rmse"],
            "top_candidate": None if top is None else top["effect"],
            "rmse_top": None if top is None else top["train_rmse"],
            "heldout_rmse_top": None if top is None else top["rmse"], "noise_rmse": out["noise_rmse"]}


def command(case: str = "dcmotor_saturation", n_experiments: int = 12, seed: int = 0, repeat: int = 1) -> dict:
    """``gbo twin diagnose`` on the records of ``case`` as a user runs it, timed as a whole process."""
    records, gain_names = case_records(case, n_experiments, seed)
    runs = []
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"{case}.csv"
        write_csv(records, path, gain_names=gain_names)
        for _ in range(repeat):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            start = time.perf_counter()
            done = subprocess.run([sys.executable, "-m", "evaluation.cli", "twin", "diagnose", str(path), "--quiet"],
                                  capture_output=True, text=True, check=True)
            wall = time.perf_counter() - start
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            runs.append({"wall_s": round(wall, 2), "system_s": round(after.ru_stime - before.ru_stime, 2),
                         "minor_faults": after.ru_minflt - before.ru_minflt,
                         "largest_peak_rss_mb": round(after.ru_maxrss / 1024)})  # of all children so far
    best = next((line for line in done.stdout.splitlines() if line.startswith("best:")), None)
    return {"benchmark": "diagnose_command", "case": case, "n_experiments": n_experiments,
            "time_s": float(np.median([r["wall_s"] for r in runs])), "target_s": 15.0, "runs": runs, "best": best}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=[*CASES, "all"], default="all")
    parser.add_argument("--experiments", type=int, default=12)
    parser.add_argument("--repeat", type=int, default=1, help="runs per case; the median time is printed")
    parser.add_argument("--command", action="store_true", help="time the gbo twin diagnose command instead")
    args = parser.parse_args()
    for name in CASES if args.case == "all" else [args.case]:
        run = command if args.command else main
        print(json.dumps(run(name, args.experiments, repeat=args.repeat)), flush=True)
