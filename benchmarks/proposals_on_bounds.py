"""Where tuners propose: the share of proposed gain values on a bound of the feasible set, against where J* lies.

On a plant whose optimum sits on faces of the box, a tuner whose acquisition search ends on the
faces gets there first. For each tuner and seed (shared seeds), the proposals after the first
experiment (the initial design is the same for all) are read from the result table, and a gain
value counts as on a bound when it is within 1e-6 of the gain's range from its lower or upper
bound. It prints one Markdown row per tuner, after the plant's J* gains and which of them are on
a bound::

    python benchmarks/proposals_on_bounds.py --env gbo_envs/LinearMotorCascadeRig-v0 --seeds 6 --budget 12
"""

from __future__ import annotations

import argparse
import json
import warnings

import gymnasium as gym
import numpy as np
from tqdm import tqdm

import agents
import gbo_envs
from evaluation.suite import load_suite

__all__ = ["main", "on_bounds"]

#: A gain value this close to a bound (a fraction of the gain's range) is on it.
ATOL = 1e-6


def on_bounds(gains: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Boolean array of ``gains``' shape (m, n_gains): whether each value is on its lower or upper bound."""
    tolerance = ATOL * (high - low)
    return (np.abs(gains - low) <= tolerance) | (np.abs(gains - high) <= tolerance)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="gbo_envs/LinearMotorCascadeRig-v0", help="registered env id")
    parser.add_argument("--tuners", nargs="+", default=["bo", "optuna-gp", "guided-bo"], help="registry names")
    parser.add_argument("--tuner-kwargs", type=json.loads, default=None,
                        help="JSON {name: kwargs} (default: each tuner's in the standard suite)")
    parser.add_argument("--seeds", type=int, default=6, help="seeds 0 .. N-1 (default 6)")
    parser.add_argument("--budget", type=int, default=12, help="experiments per run (default 12)")
    args = parser.parse_args(argv)
    if args.tuner_kwargs is None:
        args.tuner_kwargs = {entry.name: entry.params for entry in load_suite("standard").tuners}
    if args.seeds < 1 or args.budget < 2:
        parser.error(f"--seeds >= 1 and --budget >= 2, got {args.seeds} and {args.budget}")
    env = gym.make(args.env)
    low, high = env.action_space.low.astype(float), env.action_space.high.astype(float)
    names = list(env.unwrapped.gain_names)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # an uncertified ground truth warns; its gains are what is shown
        truth = np.asarray(gbo_envs.ground_truth(args.env).gains, dtype=float)
    on_face = on_bounds(truth[None, :], low, high)[0]
    print(f"{args.env}: J* at {dict(zip(names, np.round(truth, 3).tolist()))}; on a bound: "
          f"{', '.join(n for n, at in zip(names, on_face) if at) or 'none'}")
    print(f"\n| tuner | gain values on a bound (experiments 2-{args.budget}, {args.seeds} seeds) |")
    print("|---|---|")
    for name in args.tuners:
        shares = []
        for seed in tqdm(range(args.seeds), desc=name, unit="run", leave=False):
            tuner = agents.make(name, **args.tuner_kwargs.get(name, {}))
            frame = tuner.run(gym.make(args.env), budget=args.budget, seed=seed).to_pandas()
            shares.append(on_bounds(frame[names].to_numpy(float)[1:], low, high).mean())
        print(f"| {name} | {100 * np.mean(shares):.0f} % |")


if __name__ == "__main__":
    main()
