"""Tuners behind one API: ``ask`` / ``tell`` and a shared ``run(env, budget, seed)`` loop.

>>> import gymnasium as gym, gbo_envs, agents
>>> env = gym.make("gbo_envs/DCMotor-v0")
>>> result = agents.make("random").run(env, budget=5, seed=0)
>>> result.to_pandas().shape[0]
5

Tuner classes load lazily, so optional dependencies (Optuna, stable-baselines3)
are imported only when their tuner is used. The peer libraries (BoTorch,
scikit-optimize, bayesian-optimization) install with ``pip install "gbo-envs[peers]"``.
"""

from __future__ import annotations

import importlib

from agents.base import Tuner, TuningInterrupted, TuningStopped
from agents.registry import make, register, registered_names
from agents.result import TuningResult
from agents.space import GainSpace

#: Public tuner classes and helpers -> the module that defines them (loaded on first access).
_LAZY = {
    "RLTuner": "agents.rl",
    "BayesianOptimization": "agents.bo",
    "GPSurrogate": "agents.surrogate",
    "ExpectedImprovement": "agents.acquisition",
    "expected_improvement": "agents.acquisition",
    "GridSearch": "agents.baselines",
    "RandomSearch": "agents.baselines",
    "NominalPGM": "agents.nominal",
    "pgm_pi_gains": "agents.nominal",
    "OptunaTuner": "agents.optuna_tuner",
    "OptunaGP": "agents.optuna_tuner",
    "OptunaTPE": "agents.optuna_tuner",
    "estimate_noise": "agents.cost_noise",
    "GuidedBO": "agents.guided_bo",
    "TwinIterations": "agents.guidance",
    "TwinPrior": "agents.guidance",
    "MultiFidelityBO": "agents.mf_bo",
    "BoTorchTuner": "agents.peers.botorch_tuner",
    "SkoptTuner": "agents.peers.skopt_tuner",
    "BayesOptTuner": "agents.peers.bayes_opt_tuner",
    "SafeOpt": "agents.safeopt",
}

#: Registry name -> entry point.
_TUNERS = {
    "rl": "agents.rl:RLTuner",
    "bo": "agents.bo:BayesianOptimization",
    "random": "agents.baselines:RandomSearch",
    "grid": "agents.baselines:GridSearch",
    "nominal": "agents.nominal:NominalPGM",
    "optuna-gp": "agents.optuna_tuner:OptunaGP",
    "optuna-tpe": "agents.optuna_tuner:OptunaTPE",
    "guided-bo": "agents.guided_bo:GuidedBO",
    "mf-bo": "agents.mf_bo:MultiFidelityBO",
    "botorch": "agents.peers.botorch_tuner:BoTorchTuner",
    "skopt": "agents.peers.skopt_tuner:SkoptTuner",
    "bayes-opt": "agents.peers.bayes_opt_tuner:BayesOptTuner",
    "safeopt": "agents.safeopt:SafeOpt",
}

for _name, _entry in _TUNERS.items():
    register(_name, _entry)

__all__ = ["GainSpace", "Tuner", "TuningInterrupted", "TuningResult", "TuningStopped", "make", "register",
           "registered_names", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'agents' has no attribute {name!r}")
