"""RLTuner (stable-baselines3) through the common tuner API, with tiny budgets."""

from __future__ import annotations

import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

import agents  # noqa: E402
import gbo_envs  # noqa: E402, F401
from agents.rl import RLTuner, TuningMDPEnv, TuningObserver, rescaled  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]

ENV_ID = "gbo_envs/DCMotor-v0"
# tiny settings: a handful of gradient steps, a few model experiments
FAST = {"gradient_steps": 2, "algorithm_kwargs": {"batch_size": 8, "learning_starts": 3}}


def _check_env(env) -> None:
    from stable_baselines3.common.env_checker import check_env

    check_env(env, warn=True)


def _gains(result) -> np.ndarray:
    return np.array([[row[name] for name in result.gain_names] for row in result.plant_rows])


def test_sb3_sees_float32_actions_without_the_dtype_warning():
    from stable_baselines3.common.env_checker import check_env

    for env in (rescaled(gym.make(ENV_ID)), TuningMDPEnv(gym.make(ENV_ID), horizon=5)):
        assert env.action_space.dtype == np.float32
        with warnings.catch_warnings():
            warnings.filterwarnings("error", message=".*dtype.*")
            check_env(env, warn=True)
        env.reset(seed=0)
        info = env.step(np.ones(env.action_space.shape, dtype=np.float32))[4]
        assert info["gains"].dtype == np.float64
        np.testing.assert_allclose(info["gains"], gym.make(ENV_ID).action_space.high)


def test_sb3_check_env_passes_on_rescaled_plant_and_on_tuning_mdp():
    wrapped = rescaled(gym.make(ENV_ID))
    assert np.all(wrapped.action_space.low == -1.0) and np.all(wrapped.action_space.high == 1.0)
    _check_env(wrapped)
    _check_env(TuningMDPEnv(gym.make(ENV_ID), horizon=5))


def test_rescale_action_maps_the_unit_box_onto_the_feasible_set():
    env = gym.make(ENV_ID)
    plant = env.unwrapped
    wrapped = rescaled(env)
    np.testing.assert_allclose(wrapped.action(np.array([-1.0, -1.0])), plant.action_space.low)
    np.testing.assert_allclose(wrapped.action(np.array([1.0, 1.0])), plant.action_space.high)
    observer = TuningObserver.for_env(env)
    centre = (plant.action_space.low + plant.action_space.high) / 2
    np.testing.assert_allclose(observer.to_action(centre), [0.0, 0.0], atol=1e-12)


def test_tuning_mdp_reward_is_minus_cost_and_episodes_truncate_without_resetting_the_plant():
    mdp = TuningMDPEnv(gym.make(ENV_ID), horizon=3)
    observation, _ = mdp.reset(seed=0)
    assert observation.shape == (9,) and np.all(observation == 0.0)
    for k in range(1, 4):
        observation, reward, terminated, truncated, info = mdp.step(np.array([0.1, -0.2], dtype=np.float32))
        assert reward == pytest.approx(-info["cost"])
        assert not terminated and truncated == (k == 3)
        assert observation[-1] == pytest.approx(k / 3)
        assert mdp.observation_space.contains(observation)
    mdp.reset()  # a new agent episode: the plant's experiment counter goes on
    _, _, _, _, info = mdp.step(np.zeros(2, dtype=np.float32))
    assert info["experiment_index"] == 3


@pytest.mark.slow
def test_run_returns_budget_plant_rows_with_in_bounds_plain_float_gains():
    env = gym.make(ENV_ID)
    result = RLTuner(**FAST).run(env, budget=6, seed=0)
    assert result.n_experiments == 6 and result.n_twin == 0
    low, high = env.unwrapped.action_space.low, env.unwrapped.action_space.high
    for row in result.plant_rows:
        for name, lo, hi in zip(result.gain_names, low, high):
            assert type(row[name]) is float and lo <= row[name] <= hi
    assert result.info["plant_experiments"] == 6 and result.info["model_experiments"] == 0
    assert result.info["transitions_learned"] == 6 and result.info["policy_updates"] > 0


def test_same_seed_same_gains_and_other_seed_other_gains():
    def gains(seed):
        return _gains(RLTuner(**FAST).run(gym.make(ENV_ID), budget=6, seed=seed))

    np.testing.assert_array_equal(gains(3), gains(3))
    assert not np.array_equal(gains(3), gains(4))


def test_global_random_state_is_left_alone():
    import torch

    torch.manual_seed(123)
    np.random.seed(123)
    expected_torch, expected_np = torch.rand(1).item(), np.random.rand()
    torch.manual_seed(123)
    np.random.seed(123)
    RLTuner(**FAST).run(gym.make(ENV_ID), budget=4, seed=0)
    assert torch.rand(1).item() == expected_torch and np.random.rand() == expected_np


def test_twin_mode_counts_only_plant_experiments_and_logs_model_experiments():
    model = gym.make(ENV_ID, noise=False)
    tuner = RLTuner(mode="twin", model_env=model, pretrain_steps=12, **FAST)
    result = tuner.run(gym.make(ENV_ID), budget=4, seed=0)
    assert result.n_experiments == 4 and len(result.rows) == 4
    assert result.info["model_experiments"] == 12 and result.info["plant_experiments"] == 4
    assert result.info["mode"] == "twin" and result.info["transitions_learned"] == 16


def test_twin_mode_accepts_an_env_id_and_builds_the_nominal_model_by_default():
    by_id = RLTuner(mode="twin", model_env=ENV_ID, model_kwargs={"noise": False}, pretrain_steps=5, **FAST)
    default = RLTuner(mode="twin", pretrain_steps=5, **FAST)
    a = by_id.run(gym.make(ENV_ID), budget=2, seed=0)
    b = default.run(gym.make(ENV_ID), budget=2, seed=0)
    np.testing.assert_array_equal(_gains(a), _gains(b))  # same noise-free nominal model, same seed


def test_ppo_is_selectable_and_updates_after_a_rollout():
    tuner = RLTuner(algorithm="ppo", algorithm_kwargs={"n_steps": 4, "batch_size": 4, "n_epochs": 2})
    result = tuner.run(gym.make(ENV_ID), budget=6, seed=0)
    assert result.n_experiments == 6
    assert result.info["algorithm"] == "ppo" and result.info["policy_updates"] == 1


def test_registry_and_lazy_import():
    assert "rl" in agents.registered_names()
    assert isinstance(agents.make("rl", algorithm="ppo"), agents.RLTuner)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="algorithm"):
        RLTuner(algorithm="dqn")
    with pytest.raises(ValueError, match="mode"):
        RLTuner(mode="sim")
    with pytest.raises(TypeError):
        RLTuner("sac")  # keyword-only
    with pytest.raises(ValueError, match=r"pretrain_steps: must be an int in \[0, inf\)"):
        RLTuner(pretrain_steps=-1)
    with pytest.raises(ValueError, match=r"algorithm_kwargs\['batch_size'\]"):
        RLTuner(algorithm_kwargs={"batch_size": 0})
    with pytest.raises(ValueError, match="model_env"):
        RLTuner(mode="twin", model_env=3.5)


def test_twin_mode_on_a_rig_needs_an_explicit_nominal_model():
    if "gbo_envs/DCMotorRig-v0" not in gym.registry:
        pytest.skip("rig env not registered")
    with pytest.raises(ValueError, match="model_env"):
        RLTuner(mode="twin", pretrain_steps=2, **FAST).run(gym.make("gbo_envs/DCMotorRig-v0"), budget=1, seed=0)


def test_pretraining_bar_follows_the_run_progress(capsys):
    tuner = RLTuner(algorithm="sac", mode="twin", pretrain_steps=4, **FAST)
    tuner.run(gym.make(ENV_ID), budget=1, seed=0)
    assert "rl pre-training" not in capsys.readouterr().err  # the library is quiet by default
    tuner.run(gym.make(ENV_ID), budget=1, seed=0, progress=True)
    err = capsys.readouterr().err
    assert "rl pre-training on gbo_envs/DCMotor-v0" in err and "4/4" in err
