"""The peer-library adapters (BoTorch, scikit-optimize, bayesian-optimization, Optuna GP); their study is
``evaluation/studies/peers.toml`` (tables: tests/evaluation/test_comparison.py)."""

from __future__ import annotations

import sys

import gymnasium as gym
import numpy as np
import pytest

import agents
import gbo_envs  # noqa: F401

#: (registry name, keywords) of every peer row; each starts from BO's initial design with n_initial
PEERS = [("botorch", {}), ("botorch", {"acquisition": "logei"}), ("skopt", {}), ("bayes-opt", {}),
         ("optuna-gp", {"n_initial": 1})]

#: import name of the library behind each adapter
LIBRARIES = {"botorch": "botorch", "skopt": "skopt", "bayes-opt": "bayes_opt"}


def _make(name: str, **kwargs):
    try:
        return agents.make(name, **kwargs)
    except ImportError as exc:
        pytest.skip(f"{name}: optional dependency missing ({exc})")


@pytest.mark.filterwarnings("ignore")
@pytest.mark.parametrize(("name", "kwargs"), PEERS)
def test_each_peer_runs_three_experiments_inside_the_feasible_set(name, kwargs):
    env = gym.make("gbo_envs/DCMotor-v0")
    frame = _make(name, **kwargs).run(env, budget=3, seed=0).to_pandas()
    gains = frame[["Kp", "Ki"]].to_numpy()
    assert gains.shape == (3, 2) and np.all(np.isfinite(frame["cost"]))
    assert np.all(gains >= env.unwrapped.action_space.low) and np.all(gains <= env.unwrapped.action_space.high)
    assert len({tuple(g) for g in gains}) == 3  # the library proposed after the one design point


@pytest.mark.filterwarnings("ignore")
@pytest.mark.parametrize(("name", "kwargs"), PEERS)
def test_first_asks_are_bos_latin_hypercube_design_for_the_same_seed(name, kwargs):
    space = agents.GainSpace.from_env(gym.make("gbo_envs/DCMotor-v0"))
    tuners = [agents.make("bo", n_initial=3), _make(name, **{**kwargs, "n_initial": 3})]
    asked = []
    for tuner in tuners:
        tuner.setup(space, seed=7)
        gains = []
        for cost in (3.0, 2.0, 1.0):
            gains.append(tuner.ask())
            tuner.tell(gains[-1], cost)
        asked.append(np.array(gains))
    np.testing.assert_array_equal(asked[1], asked[0])
    assert len({tuple(g) for g in asked[0]}) == 3


@pytest.mark.parametrize("name", sorted(LIBRARIES))
def test_missing_library_raises_an_import_error_naming_the_extra(name, monkeypatch):
    monkeypatch.setitem(sys.modules, LIBRARIES[name], None)  # `import botorch` now raises ImportError
    with pytest.raises(ImportError, match=r'pip install "gbo-envs\[peers\]"'):
        agents.make(name)


def test_bad_botorch_options_raise_value_errors_naming_the_parameter():
    pytest.importorskip("botorch")
    with pytest.raises(ValueError, match=r"acquisition: must be one of \('qlognei', 'logei'\)"):
        agents.make("botorch", acquisition="ei")
    with pytest.raises(ValueError, match=r"n_initial: must be an int in \[1, inf\)"):
        agents.make("skopt", n_initial=0)


@pytest.mark.filterwarnings("ignore")
@pytest.mark.parametrize(("name", "kwargs"), [("botorch", {}), ("optuna-gp", {"n_initial": 1}), ("bo", {})])
def test_peers_and_bo_tune_the_3_gain_pid_through_the_same_api(name, kwargs):
    env = gym.make("gbo_envs/DCMotorPID-v0")
    names = list(env.unwrapped.gain_names)
    frame = _make(name, **kwargs).run(env, budget=6, seed=0).to_pandas()
    gains = frame[names].to_numpy()
    assert len(names) == 3 and gains.shape == (6, 3) and np.all(np.isfinite(frame["cost"]))
    assert np.all(gains >= env.unwrapped.action_space.low) and np.all(gains <= env.unwrapped.action_space.high)
    assert len({tuple(g) for g in gains}) == 6
    # the first gains are BO's Latin hypercube design, in 3 gains as in 2
    first = agents.make("bo").run(gym.make("gbo_envs/DCMotorPID-v0"), budget=1, seed=0).to_pandas()[names]
    np.testing.assert_array_equal(gains[0], first.to_numpy()[0])
