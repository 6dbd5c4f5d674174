"""The nominal baseline: a PI controller from phase and gain margins (the paper's PGM design).

A control engineer's first controller, before any tuning: pick a phase margin
``Phi_m`` and a gain margin ``A_m`` and compute the PI gains from a
first-order-plus-dead-time (FOPDT) model of the plant (Ho, Hang and Cao 1995;
paper, subsec. nominal_tuning). The script prints, for DCMotor-v0:

* the paper's two nominal controllers (60 and 75 deg at 46 dB) from the FOPDT the
  env declares for its nominal design, which reproduce the paper's table;
* the same margins on the FOPDT of the identified model of Table I
  (``fopdt="identified"``), whose gains fall outside the feasible set;
* a design on your own FOPDT (here: gain 1.0 rad/s per unit, 1.2 s, 15 ms, as a
  step test on your rig might give) with a larger gain margin, 50 dB;

each with its optimality ratio ``J / J*`` on the noise-free env. Tuners should beat
these ratios in a handful of real experiments.

Run: ``python examples/nominal_pgm.py`` (about 5 s).
"""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np

import agents
import gbo_envs

DESIGNS = [
    ("paper, 60 deg / 46 dB", {"phase_margin_deg": 60.0}),
    ("paper, 75 deg / 46 dB", {"phase_margin_deg": 75.0}),
    ("identified model, 60 deg / 46 dB", {"fopdt": "identified"}),
    ("your FOPDT, 60 deg / 50 dB", {"gain_margin_db": 50.0, "fopdt": {"gain": 1.0, "tau": 1.2, "delay": 0.015}}),
]


def main() -> list[dict]:
    env_id = "gbo_envs/DCMotor-v0"
    optimum = gbo_envs.ground_truth(env_id, noise=False).cost
    quiet = gym.make(env_id, noise=False).unwrapped
    rows = []
    for label, kwargs in DESIGNS:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = agents.make("nominal", **kwargs).run(gym.make(env_id), budget=1, seed=0, progress=False)
        gains = np.asarray(result.best_gains)
        ratio = float(quiet.evaluate(gains[None, :])[1][0]) / optimum
        rows.append({"design": label, "Kp": gains[0], "Ki": gains[1], "ratio": ratio,
                     "clipped": result.info["clipped"]})
        note = f"  (formulas gave {np.round(result.info['unclipped_gains'], 3).tolist()}, clipped)" if caught else ""
        print(f"{label:36s} Kp = {gains[0]:.3f}, Ki = {gains[1]:.3f} 1/s, J / J* = {ratio:.2f}{note}")
    return rows


if __name__ == "__main__":
    main()
