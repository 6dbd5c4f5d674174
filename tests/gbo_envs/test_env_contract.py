"""Gymnasium conventions, checked on every registered id (later envs are covered automatically)."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.wrappers import RescaleAction

import gbo_envs


@pytest.fixture(params=gbo_envs.ENV_IDS)
def env_id(request):
    return request.param


def test_env_ids_are_exactly_the_registered_ids():
    registered = [env_id for env_id in gym.registry if env_id.startswith("gbo_envs/")]
    assert sorted(gbo_envs.ENV_IDS) == sorted(registered) and len(set(gbo_envs.ENV_IDS)) == len(gbo_envs.ENV_IDS)


def test_check_env_passes(env_id):
    check_env(gym.make(env_id).unwrapped, skip_render_check=True)


def test_same_seed_same_run(env_id):
    def run(seed):
        env = gym.make(env_id)
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(3)
        trace = [obs]
        for _ in range(3):
            action = env.action_space.low + rng.random(env.action_space.shape) * (env.action_space.high
                                                                                  - env.action_space.low)
            obs, reward, _, _, info = env.step(action)
            trace += [obs, [reward], info["y"]]
        return np.concatenate([np.ravel(x) for x in trace])

    np.testing.assert_array_equal(run(11), run(11))


def test_pickle_round_trip_continues_identically(env_id):
    env = gym.make(env_id)
    env.reset(seed=5)
    action = (env.action_space.low + env.action_space.high) / 2
    env.step(action)
    clone = pickle.loads(pickle.dumps(env))
    a = env.step(action)
    b = clone.step(action)
    assert a[1] == b[1]
    np.testing.assert_array_equal(a[4]["y"], b[4]["y"])


def test_vector_env_batches_the_record(env_id):
    venv = gym.make_vec(env_id, num_envs=4)
    venv.reset(seed=0)
    _, rewards, _, _, info = venv.step(venv.action_space.sample())
    n_steps = gym.make(env_id).unwrapped.loop.n_steps
    assert rewards.shape == (4,)
    for key in ("t", "u", "y"):
        assert info[key].shape == (4, n_steps)
    assert info["metrics"]["itae"].shape == (4,)
    venv.close()


def test_rescale_action_maps_unit_box_onto_feasible_set(env_id):
    env = RescaleAction(gym.make(env_id), min_action=-1.0, max_action=1.0)
    env.reset(seed=0)
    plant = env.unwrapped
    for corner, bound in ((-1.0, plant.action_space.low), (1.0, plant.action_space.high)):
        info = env.step(np.full(plant.action_space.shape, corner))[4]
        np.testing.assert_allclose(info["gains"], bound)
