"""One contract, every registered tuner (Optuna BaseSampler habit): bounds, plain floats, seeds, validation."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import agents
import gbo_envs  # noqa: F401

BUDGET = 6

#: Every tuner the package registers (test modules register theirs per test, through the
#: ``tuner_registry`` fixture, so none of them is here).
TUNERS = agents.registered_names()
#: Tuners whose full run fits a twin (a few seconds for BUDGET experiments): slow.
SLOW_TUNERS = ("guided-bo", "mf-bo")


def _make(name: str):
    try:
        return agents.make(name)
    except ImportError as exc:  # tuners with optional extras (e.g. rl) may be skipped, nothing else
        pytest.skip(f"{name}: optional dependency missing ({exc})")


def _session(name: str, seed: int = 3):
    env = gym.make("gbo_envs/DCMotor-v0")
    tuner = _make(name)
    tuner.setup(agents.GainSpace.from_env(env), seed=seed, env=env)
    env.reset(seed=seed)
    return env, tuner


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("name", TUNERS)
def test_proposals_are_plain_floats_inside_the_feasible_set(name):
    env, tuner = _session(name)
    low, high = env.unwrapped.action_space.low, env.unwrapped.action_space.high
    for _ in range(BUDGET):
        gains = tuner.ask()
        assert isinstance(gains, tuple) and len(gains) == 2
        assert all(type(g) is float and math.isfinite(g) for g in gains)
        assert np.all(np.asarray(gains) >= low) and np.all(np.asarray(gains) <= high)
        tuner.tell(gains, env.step(np.asarray(gains))[4]["cost"])


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_TUNERS else n for n in TUNERS])
def test_same_seed_reproduces_the_run(name):
    runs = [_make(name).run(gym.make("gbo_envs/DCMotor-v0"), budget=BUDGET, seed=11) for _ in range(2)]
    frames = [run.to_pandas() for run in runs]
    plant = [frame[frame["source"] == "plant"] for frame in frames]
    assert len(plant[0]) == BUDGET
    np.testing.assert_array_equal(plant[0][["Kp", "Ki"]].to_numpy(), plant[1][["Kp", "Ki"]].to_numpy())
    np.testing.assert_array_equal(plant[0]["cost"].to_numpy(), plant[1]["cost"].to_numpy())


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("name", TUNERS)
def test_tell_rejects_nan_and_out_of_bounds_input(name):
    _, tuner = _session(name)
    with pytest.raises(ValueError, match="Kp"):
        tuner.tell((float("nan"), 1.2), 0.5)
    with pytest.raises(ValueError, match="Ki"):
        tuner.tell((0.5, 5.0), 0.5)
    with pytest.raises(ValueError, match="Kp"):
        tuner.tell((-1.0, 1.2), 0.5)
    with pytest.raises(ValueError, match="cost"):
        tuner.tell((0.5, 1.2), float("nan"))
    with pytest.raises(ValueError, match="cost"):
        tuner.tell((0.5, 1.2), float("inf"))
    # the tuner still works after the rejected calls
    gains = tuner.ask()
    tuner.tell(gains, 0.5)


@pytest.mark.parametrize("name", TUNERS)
def test_constructor_is_keyword_only_and_params_are_stored(name):
    tuner = _make(name)
    params = tuner.get_params()
    assert isinstance(params, dict)
    rebuilt = agents.make(name, **{k: v for k, v in params.items() if k != "sampler"})
    assert rebuilt.get_params() == params
    if params:
        with pytest.raises(TypeError):
            type(tuner)(*params.values())


#: Keywords a tuner's constructor may take at most: beyond that, compose (``GuidedBO(guidance=TwinIterations(...))``).
MAX_KEYWORDS = 12


@pytest.mark.parametrize("name", TUNERS)
def test_at_most_twelve_keywords(name):
    import inspect

    tuner = _make(name)
    keywords = [p.name for p in inspect.signature(type(tuner)).parameters.values() if p.kind is p.KEYWORD_ONLY]
    assert len(keywords) <= MAX_KEYWORDS, (name, keywords)
