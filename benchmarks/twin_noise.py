"""Why guided BO's twin simulates the plant's measurement noise: the optimum of a noise-free twin on DCMotorRig-v0.

The twin here is the rig's exact plant with its command limit and friction but
without its encoder (what a perfect identification could give), run by
:class:`agents.twin.TwinEnv` with white output noise of std ``sigma`` and the
expected cost over ``K = 8`` fixed draws. For each ``sigma``, the twin's optimum
on a 50 x 50 grid is judged on the rig's ground truth (expected cost over the
encoder noise): the optimality ratio ``J(theta_twin) / J*``.

The rig's speed noise floor, read from its records (:func:`agents.twin.noise_floor.noise_floor`),
is about 0.09 rad/s; the 2 % settling band is 1.22 rad/s.

Prints one JSON object per ``sigma``::

    python benchmarks/twin_noise.py
"""

from __future__ import annotations

import json
import time

import gymnasium as gym
import numpy as np

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin import make_twin_env
from gbo_envs import ground_truth

ENV_ID = "gbo_envs/DCMotorRig-v0"
SIGMAS = (0.0, 0.03, 0.06, 0.1, 0.2)  # rad/s


def main(resolution: int = 50, draws: int = 8) -> list[dict]:
    truth = ground_truth(ENV_ID, resolution=resolution)
    rig = gym.make(ENV_ID, noise=False).unwrapped
    grid = np.stack(np.meshgrid(*truth.axes, indexing="ij"), axis=-1).reshape(-1, len(truth.axes))
    exact = rig.loop.plant
    rows = []
    for sigma in SIGMAS:
        twin = make_twin_env(rig, exact, measurement_noise_std=sigma, draws=draws)
        # the rig's actuator effects, not its encoder: the noise stands for the measurement chain
        twin.loop = twin.loop.replace(effects=tuple(b for b in rig.loop.effects if b.side != "sensor"))
        start = time.perf_counter()
        cost = twin.evaluate(grid)[1]
        best = grid[int(np.argmin(cost))]
        ratio = float(rig.evaluate(best[None, :])[1][0] / truth.cost)
        rows.append({"sigma_rad_s": sigma, "twin_optimum": best.round(4).tolist(), "rig_ratio": round(ratio, 3),
                     "grid_seconds": round(time.perf_counter() - start, 1)})
        print(json.dumps(rows[-1]), flush=True)
    return rows


if __name__ == "__main__":
    main()
