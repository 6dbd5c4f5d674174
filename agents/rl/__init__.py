"""Reinforcement-learning tuners over stable-baselines3, through the same ``run(env, budget, seed)`` API.

>>> import gymnasium as gym, gbo_envs
>>> from agents.rl import RLTuner
>>> env = gym.make("gbo_envs/DCMotor-v0")
>>> result = RLTuner(algorithm="sac").run(env, budget=6, seed=0)
>>> result.n_experiments
6

Needs the ``rl`` extra (stable-baselines3 and the CPU build of torch).
"""

from __future__ import annotations

from agents.rl.learners import IsolatedRNG, OffPolicyDriver, OnPolicyDriver
from agents.rl.mdp import TuningMDPEnv, TuningObserver, default_horizon, rescaled
from agents.rl.tuner import ALGORITHMS, MODES, RLTuner

__all__ = [
    "ALGORITHMS",
    "MODES",
    "IsolatedRNG",
    "OffPolicyDriver",
    "OnPolicyDriver",
    "RLTuner",
    "TuningMDPEnv",
    "TuningObserver",
    "default_horizon",
    "rescaled",
]
