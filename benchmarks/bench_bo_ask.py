"""Speed of ``BayesianOptimization.ask()`` with 50 observations (median over repeats); prints JSON.

The tuner is fed 50 experiments on ``--env`` (default DCMotor-v0; random gains,
measured costs), then ``ask()`` is timed ``--repeats`` times, each after telling
one more experiment (so every timed ask refits the GPs, as in a tuning run:
warm-started hyperparameters, then EI maximised: on the precomputed 100 x 100
unit grid for two gains, by Sobol candidates and multistart L-BFGS-B from three
gains up, ``optimizer_in_use``). The default tuner models the four metrics (four
GPs); ``--bo-kwargs '{"model": "cost"}'`` times the single cost GP. Wall time
is the figure of merit (target: :data:`TARGET_MS` by the number of gains);
``median_cpu_ms`` (process CPU time) is reported too, because on a shared
machine wall time also counts other processes.

    python benchmarks/bench_bo_ask.py
    python benchmarks/bench_bo_ask.py --env gbo_envs/LinearMotorCascade-v0    # 4 gains
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import gymnasium as gym
import numpy as np

import agents
import gbo_envs  # noqa: F401  (registers the envs)

__all__ = ["TARGET_MS", "main"]

#: Target median wall time of one ask, ms: two gains (the grid), more gains (the multistart optimizer).
TARGET_MS = {"grid": 50.0, "multistart": 150.0}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="gbo_envs/DCMotor-v0", help="registered env id")
    parser.add_argument("--observations", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=21)
    parser.add_argument("--grid-points", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--bo-kwargs", type=json.loads, default={},
                        help='JSON kwargs for BayesianOptimization, e.g. \'{"model": "metrics"}\'')
    args = parser.parse_args(argv)

    env = gym.make(args.env)
    env.reset(seed=args.seed)
    tuner = agents.BayesianOptimization(**{"grid_points": args.grid_points, **args.bo_kwargs})
    tuner.setup(agents.GainSpace.from_env(env), seed=args.seed, env=env)
    rng = np.random.default_rng(args.seed)
    for _ in range(args.observations):
        gains = rng.uniform(tuner.space.low, tuner.space.high)
        info = env.step(gains)[4]
        tuner.tell(gains, info["cost"], info)  # the record carries the metrics (model="metrics")
    times, cpu_times = [], []
    for _ in range(args.repeats):
        start, cpu_start = time.perf_counter(), time.process_time()
        gains = tuner.ask()
        times.append(time.perf_counter() - start)
        cpu_times.append(time.process_time() - cpu_start)
        info = env.step(np.asarray(gains))[4]
        tuner.tell(gains, info["cost"], info)
    ms = np.asarray(times) * 1e3
    optimizer = tuner.optimizer_in_use
    report = {"benchmark": "bo_ask", "env": args.env, "gains": tuner.space.dim, "optimizer_in_use": optimizer,
              "observations": args.observations, "repeats": args.repeats,
              "grid_points": args.grid_points ** tuner.space.dim if optimizer == "grid" else None,
              "bo_kwargs": args.bo_kwargs, "model_in_use": tuner.model_in_use, "median_ms": float(np.median(ms)),
              "p90_ms": float(np.percentile(ms, 90)), "max_ms": float(ms.max()),
              "median_cpu_ms": float(np.median(cpu_times) * 1e3), "target_median_ms": TARGET_MS[optimizer],
              "cpus": os.cpu_count(), "load_avg_1min": os.getloadavg()[0], "python": platform.python_version()}
    print(json.dumps(report, indent=2))
    return report


if __name__ == "__main__":
    main()
