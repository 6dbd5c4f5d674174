"""DCMotor-v0: the paper's plant, feasible set, cost, noise, ground truth and error handling."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs

ID = "gbo_envs/DCMotor-v0"


@pytest.fixture(scope="module")
def truth():
    return gbo_envs.ground_truth(ID, resolution=100, noise=False)


def test_ground_truth_optimum_is_the_papers(truth):
    assert abs(truth.gains[0] - 0.54) <= 0.03
    assert abs(truth.gains[1] - 1.16) <= 0.03
    assert truth.costs.shape == (100, 100)
    assert truth.cost == pytest.approx(truth.costs.min())


def test_default_noise_is_about_four_percent_of_the_optimal_cost(truth):
    env = gym.make(ID)
    env.reset(seed=1)
    costs = [env.step(truth.gains)[4]["cost"] for _ in range(400)]
    relative = np.std(costs, ddof=1) / truth.cost
    assert 0.033 < relative < 0.045
    assert np.mean(costs) == pytest.approx(truth.cost, abs=0.003)


def test_noise_free_env_reports_its_true_cost(truth):
    env = gym.make(ID, noise=False)
    env.reset(seed=0)
    _, reward, terminated, truncated, info = env.step(truth.gains)
    assert info["cost"] == info["true_cost"] == pytest.approx(truth.cost)
    assert reward == -info["cost"]
    assert not terminated and not truncated


def test_info_carries_the_whole_record():
    env = gym.make(ID)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([0.54, 1.16]))
    for key in ("t", "r", "u", "y"):
        assert info[key].shape == (2501,)
    assert info["t"][-1] == pytest.approx(5.0)
    assert info["r"][0] == 306.0 and info["y"][0] == pytest.approx(245.0)
    assert set(info["metrics"]) == set(gbo_envs.METRIC_NAMES)
    assert info["experiment_index"] == 0 and info["unstable"] is False
    np.testing.assert_array_equal(info["gains"], [0.54, 1.16])


def test_normalisers_are_mean_metrics_over_five_diagonal_gains():
    env = gym.make(ID).unwrapped
    diagonal = np.linspace([0.11, 0.87], [1.10, 2.08], 5)
    metrics, _ = env.evaluate(diagonal)
    np.testing.assert_allclose(env.normalizers, metrics.mean(axis=0))
    _, cost = env.evaluate(diagonal)
    assert cost.mean() == pytest.approx(np.sum(env.weights), rel=0.5)


def test_episode_truncates_at_the_papers_budget():
    env = gym.make(ID)
    env.reset(seed=0)
    flags = [env.step(np.array([0.5, 1.0]))[3] for _ in range(35)]
    assert flags[-1] is True and not any(flags[:-1])


@pytest.mark.parametrize("action, match", [
    (np.array([np.nan, 1.0]), "Kp: gain must be finite"),
    (np.array([0.5, np.inf]), "Ki: gain must be finite"),
    (np.array([0.5, 1.0, 2.0]), r"expected shape \(2,\)"),
    (np.array([[0.5, 1.0]]), r"expected shape \(2,\)"),
    (np.array([1.5, 1.0]), r"Kp = 1.5 .* outside the feasible set \[0.11, 1.1\]"),
    (np.array([0.5, 0.1]), r"Ki = 0.1 .* outside the feasible set \[0.87, 2.08\]"),
    ("fast", "numeric gains"),
])
def test_bad_actions_raise_clear_errors(action, match):
    env = gym.make(ID)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        env.step(action)


def test_out_of_bounds_policies():
    clip = gym.make(ID, noise=False, out_of_bounds="clip")
    clip.reset(seed=0)
    assert clip.step(np.array([5.0, 1.0]))[4]["gains"][0] == 1.10
    allow = gym.make(ID, noise=False, out_of_bounds="allow")
    allow.reset(seed=0)
    assert allow.step(np.array([5.0, 1.0]))[4]["gains"][0] == 5.0
    with pytest.raises(ValueError, match="out_of_bounds"):
        gym.make(ID, out_of_bounds="ignore")


def test_unstable_gains_give_a_finite_documented_penalty():
    env = gym.make(ID, out_of_bounds="allow", unstable_cost=7.5)
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.array([1000.0, 1.0]))
    assert info["unstable"] is True
    assert info["cost"] == 7.5 and reward == -7.5
    assert np.all(np.isfinite(info["y"])) and np.all(np.isfinite(info["u"]))


def test_plant_parameters_are_make_kwargs():
    slow = gym.make(ID, noise=False, gain=4.0).unwrapped
    base = gym.make(ID, noise=False).unwrapped
    gains = np.array([[0.54, 1.16]])
    assert slow.evaluate(gains)[0][0, 2] > base.evaluate(gains)[0][0, 2]  # lower gain -> slower rise


def test_render_returns_an_image_of_the_last_response():
    env = gym.make(ID, render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.array([0.54, 1.16]))
    image = env.render()
    assert image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8
