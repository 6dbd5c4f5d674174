"""CPU of guided BO's in-loop diagnosis: one :func:`agents.twin.selection.diagnosed_twin` call (issue 15, point 4).

The call ``GuidedBO(twin="auto")`` makes after its initial design: the workbench's error
ladder on the plant's records decimated to ``n_samples`` samples each. Records: the first
``n_records`` experiments of LinearMotorRig-v0 (seed 0) at gains uniform on its action space.
Prints one JSON object: CPU seconds (``time.process_time``, this process) of each repeat and
their median, the twin's effects, parameters and RMSE::

    python benchmarks/bench_diagnosed_twin.py                    # 4 records of 100 samples, 3 repeats
    python benchmarks/bench_diagnosed_twin.py --records 4 --samples 0   # the whole records
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np

import gbo_envs  # noqa: F401  (registers the envs)
from agents.jsonable import jsonable
from agents.twin.model import ModelSpec
from agents.twin.selection import diagnosed_twin

ENV_ID = "gbo_envs/LinearMotorRig-v0"


def records(n_records: int, seed: int = 0) -> tuple[list, ModelSpec]:
    """``n_records`` experiments of :data:`ENV_ID` at random gains, and the twin's linear structure."""
    env = gym.make(ENV_ID)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    low, high = env.action_space.low, env.action_space.high
    out = [env.step(low + rng.random(low.size) * (high - low))[4]["experiment"] for _ in range(n_records)]
    return out, ModelSpec(n_poles=2, n_integrators=1, output=env.unwrapped.loop.plant.output)


def main(n_records: int = 4, n_samples: int | None = 100, repeat: int = 3) -> dict:
    recs, spec = records(n_records)
    cpu = []
    for _ in range(repeat):
        start = time.process_time()
        twin, rungs = diagnosed_twin(recs, spec, n_samples=n_samples)
        cpu.append(time.process_time() - start)
    return {"benchmark": "diagnosed_twin", "env": ENV_ID, "n_records": n_records, "n_samples": n_samples,
            "cpu_s": round(float(np.median(cpu)), 3), "cpus_s": [round(t, 3) for t in cpu],
            "effects": jsonable(twin.effect_params_, finite=True), "params": np.round(twin.params_, 4).tolist(),
            "rmse": float(twin.rmse_), "rungs": [r["model"] for r in rungs]}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=4)
    parser.add_argument("--samples", type=int, default=100, help="samples kept per record; 0: the whole records")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    print(json.dumps(main(args.records, args.samples or None, args.repeat)), flush=True)
