"""The twin workbench loop on DCMotorRig-v0 data: compare -> diagnose -> add -> compare again.

The rig stand-in has a command limit, Coulomb friction and a quantizing encoder
that the identified linear model lacks (see ``gbo_envs/envs/rigs.py``). Four
experiments at random gains, kept at every ``STRIDE``-th sample (the plant's
response takes seconds, so a coarser grid shows the same effects at a fraction
of the cost), are written to CSV (the format the ``gbo twin`` commands read),
the linear twin is compared with them, the workbench names the
missing effect, the effect is added, and the comparison is repeated until no
effect improves the held-out error (or ``max_effects`` are in): the error ladder,
each step in words and numbers.

Run: ``python examples/twin_workbench.py`` (under a minute). The same from the
shell: ``gbo twin compare data.csv``, ``gbo twin diagnose data.csv``,
``gbo twin compare data.csv --effects saturation``, ``gbo twin report data.csv --out out/twin``.
"""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.csvio import read_csv, records_from_env, write_csv
from agents.twin.ladder_text import advice, unobservable_lines
from agents.twin.records import Batch
from agents.twin.workbench import GreyBoxTwin, compare, diagnose
from gbo_envs.experiment import Experiment

STRIDE = 5  # keep every 5th sample of the rig's 2 ms records (dt 10 ms)


def decimated(record: Experiment, stride: int) -> Experiment:
    """A record at every ``stride``-th sample (the encoder's speed levels stay those of the 2 ms difference)."""
    return record.replace(t=record.t[::stride], r=record.r[::stride], u=record.u[::stride], y=record.y[::stride])


UNITS = {"y": "rad/s", "u": "V"}  # the rig's speed and command


def main(max_effects: int = 3) -> None:
    """Write the rig's data, then compare, diagnose and add effects, at most ``max_effects`` of them."""
    warnings.simplefilter("ignore")
    env = gym.make("gbo_envs/DCMotorRig-v0")
    low, high = env.action_space.low, env.action_space.high
    gains = np.random.default_rng(1).uniform(low, high, size=(4, low.size))
    path = write_csv([decimated(r, STRIDE) for r in records_from_env(env, gains, seed=1)],
                     Path(tempfile.mkdtemp()) / "rig.csv")
    records = read_csv(path)
    data = Batch.from_records(records)  # experiments numbered from 1, as in the CSV
    print(f"data: {path} ({data.n_records} experiments of {data.u.shape[1]} samples)")

    effects: list[str] = []
    current = GreyBoxTwin().fit(data).greybox_  # the linear model, fitted by simulation error
    res = compare(data, current)
    ladder = [f"{current.spec.label}: RMSE {res.rmse_all:.3g} rad/s, fit {res.fit_percent_all:.1f} %"]
    while True:
        res = compare(data, current)  # compare
        print(f"\ncompare {current.spec.label}: RMSE {res.rmse_all:.4g} rad/s, fit {res.fit_percent_all:.2f} %")
        result = diagnose(data, current=current, progress=None)  # diagnose (a bar when on a terminal)
        print(f"  {result.noise_label}: {result.noise_rmse:.3g} rad/s")
        print("  ranking (held-out RMSE in rad/s, delta BIC):")
        for c in result.candidates[:4]:
            print(f"    {c['effect']:>17}: {c['rmse']:.4g}  {c['delta_bic']:10.1f}  {c['evidence'][:90]}")
        if result.best is None:  # nothing improves: say why, and what would
            for line in unobservable_lines(result):
                print(f"  {line}")
            print(f"  {advice(result, effects, str(path), units=UNITS)}")
            break
        step = result.step(result.best, UNITS)
        if len(effects) >= max_effects:  # the best effect still improves the model: the cap stops the loop
            print(f"  {result.best} still improves the model ({step['text']}); stopping at {max_effects} effects")
            break
        effects.append(result.best)  # add
        current = result.fits[result.best]
        ladder.append(step["text"])
        print(f"  {step['text']}")

    print("\nerror ladder (RMSE and fit % of the fit to all data):")
    for line in ladder:
        print(f"  {line}")
    print(f"\nrig truth: saturation limit 160, Coulomb friction 5 (forward only: a constant load), "
          f"encoder step {2 * np.pi / (2048 * 0.002):.4g} rad/s (floor)")


if __name__ == "__main__":
    main()
