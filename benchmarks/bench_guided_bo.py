"""Cost of one BO iteration on the digital twin (issue 16: median under 10 ms; the paper: 0.09 s), and of a run.

One iteration is what Algorithm 1 (``guidance="iterations"``) repeats while the
twin is active (lines 10-14): evaluate the twin at ``theta+``, add the noisy
estimate to ``D``, refit the GP (hyperparameters by marginal likelihood,
warm-started) and maximise EI over the 100 x 100 grid. Measured after 10 and 30
real experiments on DCMotor-v0 with 15 twin iterations each, single-threaded as in
``ask()``; the median wall time is the figure of merit, the median process CPU time
(``median_cpu_s``) is reported too, since on a shared machine wall time also counts
other processes. Also the wall and CPU time of whole runs with each guidance (the
default ``"prior"`` simulates the twin on the 10^4-point grid once per fitted twin), by
default one on DCMotor-v0, and the real experiments they needed to ratio 1.05, with the twin
simulations a run made (``twin_evaluations``: the prior's simulated gains and the twin iterations).
In three gains and more (``--env DCMotorPID-v0 --budget 50``, the study guided_bo_nd's setting) the
twin prior is simulated wherever the multistart optimizer evaluates EI, and the CPU seconds of a run
are the figure of merit there. Prints one JSON object::

    python benchmarks/bench_guided_bo.py
    python benchmarks/bench_guided_bo.py --runs-only --env DCMotorRig-v0 --guidance prior --seeds 0 1
    python benchmarks/bench_guided_bo.py --runs-only --env DCMotorPID-v0 --budget 50 --guidance prior
"""

from __future__ import annotations

import argparse
import json
import os
import time

import gymnasium as gym
import numpy as np

import agents
import gbo_envs  # noqa: F401
from agents.guided_bo import GuidedBO
from agents.thread_limits import single_thread


def iteration_times(n_plant: int, n_twin: int = 15, seed: int = 0) -> tuple[list[float], list[float]]:
    """Wall and CPU times (s) of ``n_twin`` twin iterations after ``n_plant`` plant experiments."""
    env = gym.make("gbo_envs/DCMotor-v0")
    tuner = GuidedBO(guidance="iterations", eta2=1e-12)  # no activation while the plant data are gathered
    tuner.setup(agents.GainSpace.from_env(env), seed=seed, env=env)
    env.reset(seed=seed)
    for _ in range(n_plant):
        gains = tuner.ask()
        info = env.step(np.asarray(gains))[4]
        tuner.tell(gains, info["cost"], info)
    twin_env = tuner.twin_env()  # eta2 gates only the activation, not the twin's fit
    gains, _, _ = tuner.propose()
    times, cpu_times = [], []
    with single_thread():  # as GuidedBO.ask()
        for _ in range(n_twin):
            start, cpu_start = time.perf_counter(), time.process_time()
            cost = float(twin_env.evaluate(gains[None, :])[1][0]) + tuner.sigma_eps * tuner.rng.standard_normal()
            tuner.add_data(gains, cost, source="twin")
            gains, _, _ = tuner.propose()
            times.append(time.perf_counter() - start)
            cpu_times.append(time.process_time() - cpu_start)
    return times, cpu_times


def full_runs(env_label: str, guidance: str, seeds: list[int], budget: int | None = None) -> dict:
    """Wall and CPU seconds of guided-BO runs of ``budget`` experiments (default: an episode), their data efficiency.

    ``experiments_to_1.05``: real experiments until the best evaluated gains reach 1.05 times
    the ground-truth optimum (budget + 1 if never; :func:`evaluation.curves.experiments_to_target`).
    """
    from evaluation.curves import experiments_to_target
    from gbo_envs import ground_truth

    best = ground_truth(f"gbo_envs/{env_label}", resolution=100).cost
    runs = []
    for seed in seeds:
        env = gym.make(f"gbo_envs/{env_label}")
        start, cpu_start = time.perf_counter(), time.process_time()
        run = GuidedBO(guidance=guidance).run(env, budget=budget or env.spec.max_episode_steps, seed=seed,
                                              progress=False)
        ratios = (run.min_true_cost_curve() / best).tolist()
        runs.append({"seed": seed, "seconds": time.perf_counter() - start,
                     "cpu_seconds": time.process_time() - cpu_start, "twin_evaluations": run.info["twin_evaluations"],
                     "activations": run.info["activations"], "experiments_to_1.05": experiments_to_target(ratios, 1.05),
                     "final_ratio": ratios[-1]})
    return {"runs": runs, "median_cpu_seconds": float(np.median([r["cpu_seconds"] for r in runs])),
            "median_twin_evaluations": float(np.median([r["twin_evaluations"] for r in runs]))}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="DCMotor-v0", help="env of the whole runs (default DCMotor-v0)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds of the whole runs (default 0)")
    parser.add_argument("--guidance", nargs="+", default=["prior", "iterations"], choices=["prior", "iterations"])
    parser.add_argument("--budget", type=int, default=None, help="experiments per run (default: the episode length)")
    parser.add_argument("--runs-only", action="store_true", help="only the whole runs, no twin-iteration timing")
    args = parser.parse_args(argv)
    result = {}
    for n_plant in () if args.runs_only else (10, 30):
        times, cpu_times = iteration_times(n_plant)
        result[f"after_{n_plant}_experiments"] = {"median_s": float(np.median(times)),
                                                   "p90_s": float(np.percentile(times, 90)),
                                                   "median_cpu_s": float(np.median(cpu_times))}
    for guidance in args.guidance:
        result[f"full_runs_{args.env}_{guidance}"] = full_runs(args.env, guidance, args.seeds, args.budget)
    result["target_median_s"] = 0.010
    result["load_avg_1min"] = os.getloadavg()[0]
    result["paper_s"] = 0.09
    return result


if __name__ == "__main__":
    print(json.dumps(main()))
