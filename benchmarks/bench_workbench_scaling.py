"""Cost of the twin workbench against the amount of data (issue 19): ``gbo twin compare`` and ``resid``.

For 10, 100 and 1,000 experiments of 2,501 samples of DCMotor-v0 (sensor
noise 0.3 rad/s, uniformly random gains, one vectorised closed-loop simulation of
all experiments) a workbench CSV is written (:func:`agents.twin.csvio.write_csv`)
and each command runs in its own process,
``python -m evaluation.cli twin COMMAND DATA.csv --json``. Its CPU time (user +
system, all threads, from the child's ``rusage``), wall time and peak resident
memory (``ru_maxrss``) are printed as a Markdown table, then as JSON lines. The
issue's target at 1,000 experiments: under 500 MB and 30 s.

A child gets an address-space limit (``--memory-limit``, default 8 GB) so that a
command whose memory grows faster than the data fails with ``MemoryError``
(reported as ``failed``) instead of exhausting the machine::

    python benchmarks/bench_workbench_scaling.py                       # 10, 100, 1000; compare and resid
    python benchmarks/bench_workbench_scaling.py --sizes 10 100 --commands compare
    python benchmarks/bench_workbench_scaling.py --tree /path/to/main    # the same data, another checkout
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.csvio import write_csv
from gbo_envs import Experiment

ROOT = Path(__file__).resolve().parents[1]
NOISE = 0.3  # rad/s, the sensor noise of bench_diagnose.py


def write_data(n_experiments: int, path: Path, seed: int = 0) -> Path:
    """A workbench CSV of ``n_experiments`` DCMotor-v0 experiments at random gains (sensor noise ``NOISE``)."""
    env = gym.make("gbo_envs/DCMotor-v0", output_noise_std=NOISE)
    loop, rng = env.unwrapped.loop, np.random.default_rng(seed)
    low, high = env.action_space.low, env.action_space.high
    gains = rng.uniform(low, high, size=(n_experiments, low.size))
    res = loop.simulate(gains, rng=rng)
    records = [Experiment(gains=g, t=res.t, r=res.r, u=res.u[k], y=res.y[k], index=k) for k, g in enumerate(gains)]
    return write_csv(records, path)


def run_command(command: str, data: Path, memory_limit: float, tree: Path = ROOT) -> dict:
    """Run ``gbo twin COMMAND DATA --json`` in a child process; its CPU s, wall s, peak MB and exit status."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (int(memory_limit), int(memory_limit)))

    env = dict(os.environ, PYTHONPATH=str(tree) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "evaluation.cli", "twin", command, str(data), "--json"],
                                stdout=out, stderr=err, cwd=tree, env=env, preexec_fn=limit)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read().decode(), err.read().decode()
    row = {"command": command, "cpu_s": round(usage.ru_utime + usage.ru_stime, 2), "wall_s": round(wall, 2),
           "peak_mb": round(usage.ru_maxrss / 1024, 1), "exit": proc.returncode}
    if proc.returncode == 0:
        payload = json.loads(stdout)
        row["result"] = (f"RMSE {payload['rmse']:.5g}" if command == "compare" else
                         f"99 % band {payload['band']:.4g}, white {payload['white']}" if command == "resid" else
                         f"best {payload['best']}")
    else:
        row["failed"] = (stderr.strip().splitlines() or ["(no message)"])[-1][:200]
    return row


def main(sizes=(10, 100, 1000), commands=("compare", "resid"), memory_limit: float = 8e9,
         tree: Path = ROOT) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for n in sizes:
            start = time.process_time()
            data = write_data(n, Path(folder) / f"data_{n}.csv")
            generate = time.process_time() - start
            for command in commands:
                row = {"n_experiments": n, "n_samples": 2501, "csv_mb": round(data.stat().st_size / 1e6, 1),
                       "generate_cpu_s": round(generate, 2), **run_command(command, data, memory_limit, tree)}
                rows.append(row)
                print(json.dumps(row), file=sys.stderr, flush=True)
    return rows


def table(rows: list[dict]) -> str:
    """Markdown table of the rows."""
    lines = ["| experiments | CSV MB | command | CPU s | wall s | peak MB | result |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        result = r.get("result") or f"failed: {r.get('failed', '')}"
        lines.append(f"| {r['n_experiments']} | {r['csv_mb']} | {r['command']} | {r['cpu_s']} | {r['wall_s']} | "
                     f"{r['peak_mb']} | {result} |")
    return "\n".join(lines)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10, 100, 1000], help="numbers of experiments")
    parser.add_argument("--commands", nargs="+", choices=("compare", "resid", "diagnose"),
                        default=["compare", "resid"])
    parser.add_argument("--memory-limit", type=float, default=8e9, help="address-space limit of a child, bytes")
    parser.add_argument("--tree", type=Path, default=ROOT,
                        help="source tree whose gbo runs (default this one; e.g. a checkout of main for 'before')")
    args = parser.parse_args()
    result = main(args.sizes, args.commands, args.memory_limit, args.tree.resolve())
    print(table(result))
    for row in result:
        print(json.dumps(row))
