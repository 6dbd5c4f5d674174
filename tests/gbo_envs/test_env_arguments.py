"""The env's arguments that used to be accepted silently, and wrong: ``noise="no"`` taken as true, a negative
``unstable_cost`` (an unstable loop scoring better than the optimum), boolean gains run at 1.0 (issue 57)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs  # noqa: F401  (registers the envs)

ENV = "gbo_envs/DCMotor-v0"


@pytest.mark.parametrize("noise", ["no", "false", 0, 1, None])
def test_noise_must_be_a_bool(noise):
    with pytest.raises(TypeError, match=f"noise: must be True or False, got {noise!r}"):
        gym.make(ENV, noise=noise)


def test_noise_accepts_numpy_bools():
    assert gym.make(ENV, noise=np.bool_(False)).unwrapped.noise is False


@pytest.mark.parametrize("cost", [-1.0, 0.0, math.inf, math.nan, True, "10"])
def test_unstable_cost_must_be_finite_and_positive_naming_the_range(cost):
    with pytest.raises(ValueError, match=r"unstable_cost: must be a finite number > 0"):
        gym.make(ENV, unstable_cost=cost)


@pytest.mark.parametrize("action", [[True, True], np.array([True, True]), [True, 1.2], (0.5, np.bool_(True))])
def test_boolean_gains_are_refused_not_run_at_one(action):
    env = gym.make(ENV, noise=False)
    env.reset(seed=0)
    with pytest.raises(TypeError, match="action: gains .* must be real numbers, got the boolean value"):
        env.step(action)
