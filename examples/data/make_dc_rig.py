"""Write ``dc_rig.csv``: the bundled example data of the twin workbench (docs/workbench.md, ``gbo twin``).

Four closed-loop step experiments (245 -> 306 rad/s) of ``gbo_envs/DCMotorRig-v0``
at gains drawn uniformly from its feasible set (seed 1), kept at every 5th
sample (dt 10 ms), in the workbench CSV format (``experiment,t,r,u,y`` plus the
gains ``gain0,gain1``, ``source`` and ``cost``). ``y`` is the encoder's speed in
rad/s, ``u`` the commanded input. The rig has a command limit, Coulomb friction
and a quantizing encoder that a linear model lacks: ``gbo twin diagnose`` finds
the limit.

Run: ``python examples/data/make_dc_rig.py`` (a few seconds; the file is committed).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.csvio import records_from_env, write_csv

STRIDE = 5  # every 5th of the rig's 2 ms samples
#: where the data goes: beside this script
DATA = Path(__file__).with_name("dc_rig.csv")


def main(path: Path = DATA) -> Path:
    env = gym.make("gbo_envs/DCMotorRig-v0")
    low, high = env.action_space.low, env.action_space.high
    gains = np.random.default_rng(1).uniform(low, high, size=(4, low.size))
    records = [r.replace(t=r.t[::STRIDE], r=r.r[::STRIDE], u=r.u[::STRIDE], y=r.y[::STRIDE])
               for r in records_from_env(env, gains, seed=1)]
    return write_csv(records, path)


if __name__ == "__main__":
    print(f"wrote {main()}")
