"""Time-varying plants: documented parameter schedules, exact change points, reset, fixed normalisers."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs  # noqa: F401  (registers the ids)
from gbo_envs.envs.time_varying import AbruptChange, GradualDrift

DC_GAINS = np.array([0.6, 1.2])
LM_GAINS = np.array([5400.0, 49.0])


def _run(env, gains, n, seed=0):
    env.reset(seed=seed)
    return [env.step(gains)[4] for _ in range(n)]


@pytest.mark.parametrize(
    ("env_id", "gains", "expected"),
    [
        # L_k = 9.544 (1 - 0.10 (1 - exp(-k / 20))), the rest fixed
        ("gbo_envs/DCMotorDrift-v0", DC_GAINS,
         lambda k: {"gain": 9.544 * (1 - 0.10 * (1 - np.exp(-k / 20))), "tau1": 4.145, "tau2": 4.199,
                    "delay": 0.002}),
        # gain -6 %, damping -25 % at equilibrium, time constant 10 experiments
        ("gbo_envs/LinearMotorDrift-v0", LM_GAINS,
         lambda k: {"gain": 0.44262 * (1 - 0.06 * (1 - np.exp(-k / 10))), "inertia": 0.070983,
                    "damping": 0.8 * (1 - 0.25 * (1 - np.exp(-k / 10))), "delay": 0.001}),
    ],
)
def test_drift_follows_the_documented_schedule(env_id, gains, expected):
    env = gym.make(env_id, noise=False)
    infos = _run(env, gains, 12)
    for k, info in enumerate(infos):
        assert info["experiment_index"] == k
        assert info["plant_params"].keys() == expected(k).keys()
        for name, value in expected(k).items():
            assert info["plant_params"][name] == pytest.approx(value, rel=1e-12)
    # documented figures: DC gain 3.9 % lower at experiment 10; LM damping 15.8 % lower
    first, tenth = infos[0]["plant_params"], infos[10]["plant_params"]
    changed = "gain" if "tau1" in first else "damping"
    drop = {"gain": 0.039, "damping": 0.158}[changed]
    assert 1 - tenth[changed] / first[changed] == pytest.approx(drop, abs=5e-4)
    # the cost of the same gains moves with the plant
    assert infos[11]["true_cost"] != pytest.approx(infos[0]["true_cost"], abs=1e-6)


@pytest.mark.parametrize(
    ("env_id", "gains", "new"),
    [
        ("gbo_envs/DCMotorStep-v0", DC_GAINS, {"gain": 7.0, "tau2": 3.5}),
        ("gbo_envs/LinearMotorStep-v0", LM_GAINS, {"inertia": 0.09}),
    ],
)
def test_step_change_happens_exactly_at_the_given_experiment(env_id, gains, new):
    env = gym.make(env_id, noise=False, change_at=3, new_params=new)
    infos = _run(env, gains, 6)
    initial = infos[0]["plant_params"]
    for k, info in enumerate(infos):
        params = info["plant_params"]
        if k < 3:
            assert params == initial
        else:
            assert params == {**initial, **new}
    costs = [info["true_cost"] for info in infos]
    assert costs[0] == costs[1] == costs[2]
    assert costs[3] == costs[4] == costs[5]
    assert abs(costs[3] - costs[2]) > 1e-3
    # evaluate() at an experiment index sees the plant of that experiment
    plant_env = env.unwrapped
    assert plant_env.evaluate(gains[None, :], experiment_index=2)[1][0] == pytest.approx(costs[2])
    assert plant_env.evaluate(gains[None, :], experiment_index=4)[1][0] == pytest.approx(costs[4])


def test_default_step_changes():
    dc = gym.make("gbo_envs/DCMotorStep-v0").unwrapped
    assert dc.schedule.at == 15
    assert dc.plant_params_at(15) == pytest.approx({"gain": 9.544 / 1.25, "tau1": 4.145, "tau2": 4.199 / 1.25,
                                                    "delay": 0.002})
    lm = gym.make("gbo_envs/LinearMotorStep-v0").unwrapped
    assert lm.schedule.at == 10
    assert lm.plant_params_at(9)["inertia"] == 0.070983
    assert lm.plant_params_at(10)["inertia"] == pytest.approx(0.070983 * 1.3)


@pytest.mark.parametrize("env_id", ["gbo_envs/DCMotorDrift-v0", "gbo_envs/DCMotorStep-v0",
                                    "gbo_envs/LinearMotorDrift-v0", "gbo_envs/LinearMotorStep-v0"])
def test_reset_restores_the_initial_plant_and_normalisers_stay_fixed(env_id):
    static_id = env_id.replace("Drift", "").replace("Step", "")
    env = gym.make(env_id, change_at=2) if "Step" in env_id else gym.make(env_id)
    gains = DC_GAINS if "DC" in env_id else LM_GAINS
    normalizers = env.unwrapped.normalizers.copy()
    np.testing.assert_array_equal(normalizers, gym.make(static_id).unwrapped.normalizers)
    first = _run(env, gains, 5, seed=7)
    assert first[4]["plant_params"] != first[0]["plant_params"]
    again = _run(env, gains, 2, seed=7)
    assert again[0]["plant_params"] == first[0]["plant_params"]
    assert again[0]["cost"] == first[0]["cost"] and again[1]["cost"] == first[1]["cost"]
    np.testing.assert_array_equal(env.unwrapped.normalizers, normalizers)
    # experiment 0 of a time-varying env is the static env's plant
    static = gym.make(static_id)
    static.reset(seed=7)
    assert static.step(gains)[4]["true_cost"] == first[0]["true_cost"]


def test_schedules_validate_their_arguments():
    with pytest.raises(ValueError, match="unknown plant parameter"):
        gym.make("gbo_envs/DCMotorDrift-v0", drift={"mass": -0.1})
    with pytest.raises(ValueError, match="relative change"):
        GradualDrift(rel_change={"gain": -1.5})
    with pytest.raises(ValueError, match="drift_time_constant"):
        GradualDrift(rel_change={"gain": -0.1}, time_constant=0.0)
    with pytest.raises(ValueError, match="change_at"):
        gym.make("gbo_envs/DCMotorStep-v0", change_at=0)
    with pytest.raises(ValueError, match="new_params"):
        AbruptChange(at=3, new={"gain": "high"})
    with pytest.raises(ValueError, match="damping"):
        gym.make("gbo_envs/LinearMotorStep-v0", new_params={"damping": -1.0})


def test_gradual_drift_formula():
    drift = GradualDrift(rel_change={"gain": -0.1}, time_constant=20.0)
    assert drift.progress(0) == 0.0
    assert drift.progress(20) == pytest.approx(1 - np.exp(-1))
    params = drift.params({"gain": 10.0, "tau1": 4.0}, 10**6)
    assert params == pytest.approx({"gain": 9.0, "tau1": 4.0})


def test_plant_side_effects_apply_on_top_of_the_schedule():
    env = gym.make("gbo_envs/DCMotorStep-v0", change_at=2, new_params={"gain": 8.0},
                   effects={"time_delay": {"delay": 0.002}}).unwrapped
    before, after = env.loop_for_experiment(1).current_plant, env.loop_for_experiment(2).current_plant
    assert before.delay == pytest.approx(0.004) and after.delay == pytest.approx(0.004)
    assert before.num == (9.544,) and after.num == (8.0,)
