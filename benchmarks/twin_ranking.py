"""How well guided BO's twin ranks gains: its expected cost against the plant's, after some experiments.

A twin guides BO only as far as it orders gains as the plant does. For each seed, ``guided-bo``
runs ``--experiments`` plant experiments on ``--env``; then the twin it holds
(``GuidedBO.keeper_.twin_env().evaluate``: its expected cost, the noise it simulates included;
``unstable_cost`` where it diverges) and the
plant's ground truth (``env.unwrapped.evaluate``: the expected cost over the plant's noise) are
evaluated at every measured gain and at ``J*``'s gains. It prints one Markdown row per seed:

* the twin's mean error ``J~ - J`` and its RMS over those gains (cost units);
* Spearman's rank correlation of ``J~`` and ``J`` over them (1: the twin orders them as the plant);
* the share of measured gains that the twin puts below its cost at ``J*``'s gains, though the
  plant puts all of them above ``J*`` (those are the gains the twin leads BO to instead);
* the twin's effects.

::

    python benchmarks/twin_ranking.py --env gbo_envs/LinearMotorCascadeRig-v0 --seeds 0 1 4 --experiments 12
"""

from __future__ import annotations

import argparse
import warnings

import gymnasium as gym
import numpy as np
from scipy.stats import spearmanr
from tqdm import tqdm

import agents
import gbo_envs
from agents.base import MAX_BUDGET
from agents.thread_limits import single_thread
from gbo_envs.optimum_search import SearchDisagreement


def twin_against_plant(env_id: str, seed: int, experiments: int) -> dict:
    """Run guided-bo for ``experiments`` on ``env_id`` with ``seed``; the twin's and the plant's costs at its gains.

    Returns
    -------
    dict
        ``twin`` and ``plant``: expected costs at the measured gains, the last entry at ``J*``'s gains
        (cost units); ``effects``: the twin's effects.
    """
    env = gym.make(env_id, max_episode_steps=experiments)
    plant = env.unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SearchDisagreement)  # an uncertified table still has J*'s gains
        optimum = np.asarray(gbo_envs.ground_truth(env_id).gains, dtype=float)
    tuner = agents.make("guided-bo")
    with single_thread(user_api=None):
        result = tuner.run(env, budget=experiments, seed=seed)
    rows = result.to_pandas()
    gains = np.vstack([rows[list(plant.gain_names)].to_numpy(dtype=float), optimum])
    keeper = tuner.keeper_
    twin_env = keeper.twin_env()
    if twin_env is None:
        raise SystemExit(f"seed {seed}: the records identified no twin after {experiments} experiments")
    twin = twin_env.evaluate(gains)[1]
    twin = np.where(np.isfinite(twin), twin, twin_env.unstable_cost)
    truth = plant.evaluate(gains)[1]
    return {"twin": twin, "plant": np.asarray(truth, dtype=float), "effects": keeper.describe().get("twin_effects", "")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="gbo_envs/LinearMotorCascadeRig-v0", help="registered env id")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="seeds (default: 0 1)")
    parser.add_argument("--experiments", type=int, default=12, help="plant experiments before the twin is read")
    args = parser.parse_args()
    if not 2 <= args.experiments <= MAX_BUDGET:
        parser.error(f"--experiments: must be in [2, {MAX_BUDGET}], got {args.experiments}")
    print(f"{args.env}, {args.experiments} experiments of guided-bo; costs at the measured gains and at J*'s\n")
    print("| seed | J~ - J, mean | RMS | Spearman | measured gains the twin puts below J*'s | J~ at J*'s / J* | twin |")
    print("|---|---|---|---|---|---|---|")
    for seed in tqdm(args.seeds, desc="seeds", unit="seed"):
        out = twin_against_plant(args.env, seed, args.experiments)
        twin, truth = out["twin"], out["plant"]
        error = twin - truth
        rho = spearmanr(twin, truth).statistic
        below = float(np.mean(twin[:-1] < twin[-1]))
        print(f"| {seed} | {error.mean():+.3f} | {np.sqrt(np.mean(error**2)):.3f} | {rho:.2f} | {below:.0%} | "
              f"{twin[-1]:.3f} / {truth[-1]:.3f} | {out['effects']} |")


if __name__ == "__main__":
    main()
