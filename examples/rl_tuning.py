"""Tune the DC motor's PI gains with reinforcement learning (SAC), on the plant and trained on a model.

Every action the agent takes on the plant is a real experiment and a row of
the result; in train-on-twin mode the policy first learns on the noise-free
nominal model (those model experiments are reported apart, not counted).

Run: ``python examples/rl_tuning.py`` (about half a minute on a laptop CPU).
"""

from __future__ import annotations

import gymnasium as gym

import gbo_envs
from agents.rl import RLTuner

ENV_ID = "gbo_envs/DCMotor-v0"
BUDGET = 20  # plant experiments per run


def main() -> None:
    optimum = gbo_envs.ground_truth(ENV_ID, resolution=40).cost
    runs = {
        "SAC on the plant": RLTuner(algorithm="sac", mode="plant", gradient_steps=16),
        "SAC trained on the nominal model": RLTuner(algorithm="sac", mode="twin", pretrain_steps=600,
                                                    gradient_steps=16, progress=None),
    }
    for label, tuner in runs.items():
        result = tuner.run(gym.make(ENV_ID), budget=BUDGET, seed=0, progress=None)  # bars when on a terminal
        ratio = result.best_true_cost_curve() / optimum
        gains = ", ".join(f"{name} = {value:.3f}" for name, value in zip(result.gain_names, result.best_gains))
        print(f"{label}: {result.n_experiments} plant experiments "
              f"(+ {result.info['model_experiments']} model experiments), best {gains}, "
              f"optimality ratio after 1 / {BUDGET} experiments: {ratio[0]:.3f} / {ratio[-1]:.3f}")


if __name__ == "__main__":
    main()
