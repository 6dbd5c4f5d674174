"""Cost of one BO iteration on the digital twin (issue 16: median under 10 ms; the paper: 0.09 s), and of a run.

One iteration is what Algorithm 1 (``guidance="iterations"``) repeats while the
twin is active (lines 10-14): evaluate the twin at ``theta+``, add the noisy
estimate to ``D``, refit the GP (hyperparameters by marginal likelihood,
warm-started) and maximise EI over the 100 x 100 grid. Measured after 10 and 30
real experiments on DCMotor-v0 with 15 twin iterations each, single-threaded as in
``ask()``; the median wall time is the figure of merit, the median process CPU time
(``median_cpu_s``) is reported too, since on a shared machine wall time also counts
other processes. Also the wall and CPU time of one 35-experiment run with each
guidance (the default ``"prior"`` simulates the twin on the 10^4-point grid once per
fitted twin). Prints one JSON object.
"""

from __future__ import annotations

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
    tuner.eta2 = None
    twin_env = tuner._current_twin_env()
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


def main() -> dict:
    result = {}
    for n_plant in (10, 30):
        times, cpu_times = iteration_times(n_plant)
        result[f"after_{n_plant}_experiments"] = {"median_s": float(np.median(times)),
                                                   "p90_s": float(np.percentile(times, 90)),
                                                   "median_cpu_s": float(np.median(cpu_times))}
    for guidance in ("prior", "iterations"):
        start, cpu_start = time.perf_counter(), time.process_time()
        run = GuidedBO(guidance=guidance).run(gym.make("gbo_envs/DCMotor-v0"), budget=35, seed=0, progress=False)
        result[f"full_run_35_experiments_{guidance}"] = {"seconds": time.perf_counter() - start,
                                                         "cpu_seconds": time.process_time() - cpu_start,
                                                         "twin_evaluations": run.info["twin_evaluations"],
                                                         "activations": run.info["activations"]}
    result["target_median_s"] = 0.010
    result["load_avg_1min"] = os.getloadavg()[0]
    result["paper_s"] = 0.09
    return result


if __name__ == "__main__":
    print(json.dumps(main()))
