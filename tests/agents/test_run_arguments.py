"""Budgets, seeds and told gains of the tuning loop: integers in a named range, never truncated or coerced
(issue 57: ``budget=2.5`` ran 2 experiments, ``seed=-1`` gave numpy's "expected non-negative integer")."""

from __future__ import annotations

import gymnasium as gym
import pytest

import agents
import gbo_envs  # noqa: F401  (registers the envs)
from agents.space import GainSpace
from evaluation.sessions import TuningSession

ENV = "gbo_envs/DCMotor-v0"


@pytest.mark.parametrize("budget", [2.5, 2.0, True, 0, -1, 10**20, "3"])
def test_budget_must_be_an_integer_in_range(budget):
    with pytest.raises(ValueError, match=r"budget: must be an integer from 1 to 1000000 \(plant experiments\)"):
        agents.make("random").run(gym.make(ENV, noise=False), budget, seed=0)


@pytest.mark.parametrize("seed", [-1, 2.5, True, 2**32, "0"])
def test_seed_must_be_none_or_an_integer_in_range_naming_it(seed):
    with pytest.raises(ValueError, match=r"seed: must be None or an integer from 0 to 4294967295"):
        agents.make("random").run(gym.make(ENV, noise=False), 2, seed=seed)
    with pytest.raises(ValueError, match="seed: must be None"):
        agents.make("random").setup(GainSpace.from_env(gym.make(ENV)), seed=seed)


def test_a_session_refuses_a_bad_budget_or_seed_before_the_database_exists(tmp_path):
    for kwargs in ({"budget": 2.5}, {"budget": 2, "seed": -1}):
        with pytest.raises(ValueError, match="budget|seed"):
            TuningSession(tmp_path / "runs.sqlite", ENV, "random", **kwargs)
    assert not (tmp_path / "runs.sqlite").exists()


@pytest.mark.parametrize("gains", [[True, True], (0.5, True)])
def test_told_gains_must_not_be_booleans(gains):
    tuner = agents.make("random")
    tuner.setup(GainSpace.from_env(gym.make(ENV)), seed=0)
    with pytest.raises(TypeError, match=r"tell\(gains\): must be real numbers, got the boolean"):
        tuner.tell(gains, 1.0)


def test_setup_takes_the_envs_action_space_as_run_does_and_names_a_wrong_space():
    env = gym.make(ENV)
    by_box, by_space = agents.make("bo"), agents.make("bo")
    by_box.setup(env.action_space, seed=3, env=env)  # was AttributeError: 'Box' object has no attribute 'dim'
    by_space.setup(GainSpace.from_env(env), seed=3, env=env)
    assert by_box.space.names == ("Kp", "Ki") and by_box.ask() == by_space.ask()
    anonymous = agents.make("random")
    anonymous.setup(gym.spaces.Box(0.0, 1.0, shape=(3,)), seed=0)
    assert anonymous.space.names == ("gain_0", "gain_1", "gain_2")
    with pytest.raises(TypeError, match="space: expected a GainSpace .* got list"):
        agents.make("random").setup([0.0, 1.0], seed=0)
