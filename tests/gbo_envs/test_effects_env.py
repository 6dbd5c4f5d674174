"""Effects composed into an env through ``gym.make``, their specs, and the errors on bad parameters."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs  # noqa: F401  (registers the envs)
from gbo_envs.physics import (
    EFFECT_NAMES,
    CoulombFriction,
    Offset,
    Saturation,
    build_effect,
    build_effects,
)
from tests.support import U_REST

ISSUE_EFFECTS = {"saturation": {"limit": 150.0}, "coulomb_friction": {"torque": 20.0}}


def test_composition_through_gym_make():
    env = gym.make("gbo_envs/DCMotor-v0", noise=False, effects=ISSUE_EFFECTS)
    assert env.unwrapped.loop.effects == (Saturation(150.0), CoulombFriction(20.0))
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.array([0.54, 1.16]))
    assert np.isfinite(reward) and not info["unstable"]
    assert info["u"].shape == info["y"].shape == (2501,)
    # the drive limit comes first, then friction: at most 150 - 20 = 130 reaches the plant, which
    # holds the motor at 130 / U_REST * 245 rad/s, short of the 306 rad/s reference
    top_speed = (150.0 - 20.0) / U_REST * 245.0
    assert info["y"][-1] == pytest.approx(top_speed, abs=0.05)
    assert info["u"].max() > 150.0
    # in the other order friction is compensated before the limit, and the motor reaches 306 rad/s
    swapped = gym.make("gbo_envs/DCMotor-v0", noise=False,
                       effects=[("coulomb_friction", {"torque": 20.0}), ("saturation", {"limit": 150.0})])
    swapped.reset(seed=0)
    assert swapped.step(np.array([0.54, 1.16]))[4]["y"][-1] == pytest.approx(306.0, abs=0.5)


def test_env_with_effects_is_deterministic_and_pickles():
    env = gym.make("gbo_envs/DCMotor-v0", effects={"backlash": {"width": 1.0}, "quantization": {"step": 0.5}})
    env.reset(seed=3)
    first = env.step(np.array([0.6, 1.2]))[4]
    clone = pickle.loads(pickle.dumps(env))
    env.reset(seed=3)
    clone.reset(seed=3)
    a, b = env.step(np.array([0.6, 1.2]))[4], clone.step(np.array([0.6, 1.2]))[4]
    assert np.array_equal(a["y"], first["y"]) and np.array_equal(a["y"], b["y"]) and a["cost"] == b["cost"]


def test_drift_through_the_env():
    env = gym.make("gbo_envs/DCMotor-v0", noise=False, effects={"drift": {"parameter": "gain", "rate": -0.01}})
    plant_env = env.unwrapped
    assert plant_env.loop_for_experiment(0).current_plant.num == (9.544,)
    assert plant_env.loop_for_experiment(20).current_plant.num[0] == pytest.approx(9.544 * 0.8)
    gains = np.array([[0.54, 1.16]])
    _, cost0 = plant_env.evaluate(gains, experiment_index=0)
    _, cost20 = plant_env.evaluate(gains, experiment_index=20)
    assert cost20[0] != pytest.approx(cost0[0], rel=1e-3)
    env.reset(seed=0)
    costs = [env.step(gains[0])[4]["true_cost"] for _ in range(3)]
    assert costs[0] == pytest.approx(cost0[0]) and len(set(costs)) == 3
    # a new session starts on the nominal plant again
    env.reset(seed=0)
    assert env.step(gains[0])[4]["true_cost"] == pytest.approx(cost0[0])
    # the ground truth is that of experiment 0
    truth = gbo_envs.ground_truth(env, resolution=3)
    nominal = gbo_envs.ground_truth("gbo_envs/DCMotor-v0", resolution=3, noise=False)
    assert np.allclose(truth.costs, nominal.costs)


def test_spec_forms():
    block = Offset(2.0, on="sensor")
    assert build_effects(None) == ()
    assert build_effects(block) == (block,)
    assert build_effects([block, ("offset", {"value": 1.0})]) == (block, Offset(1.0))
    assert build_effects({"dead_zone": {"width": 1.0}, "stiction": {"breakaway": 2.0}})[1].side == "actuator"
    assert build_effect("time_delay", {"delay": 0.01}).side == "plant"
    assert build_effects({"quantization": {"step": 0.1}})[0].side == "sensor"
    for block in build_effects({"cogging": {"amplitude": 1.0, "period": 0.5}, "drift": {"rate": 0.1}}):
        assert build_effects([(block.name, block.params)]) == (block,)


@pytest.mark.parametrize(
    ("spec", "pattern"),
    [
        ({"friction": {"torque": 1.0}}, r"unknown effect 'friction'; the catalogue is \('time_delay'.*'compliance'\)"),
        ({"saturation": {"limit": -1.0}}, r"saturation: parameter 'limit' must be in \[0, 1e\+09\]"),
        ({"saturation": {"limit": "big"}},
         r"saturation: parameter 'limit' must be a real number in \[0, 1e\+09\].*str"),
        ({"saturation": {"limit": True}}, r"saturation: parameter 'limit' must be a real number"),
        ({"saturation": {"lim": 1.0}}, r"saturation: unknown parameter 'lim'; allowed parameters are \('limit',\)"),
        ({"saturation": {}}, r"saturation: parameter 'limit' is required"),
        ({"dead_zone": {"width": float("nan")}}, r"dead_zone: parameter 'width' must be in \[0, 1e\+09\]"),
        ({"coulomb_friction": {"torque": 1.0, "smoothing": -2.0}},
         r"coulomb_friction: parameter 'smoothing' must be in \[0, 1e\+09\]"),
        ({"viscous_friction": {"coefficient": -0.1}}, r"viscous_friction: parameter 'coefficient'"),
        ({"stiction": {"breakaway": -1.0}}, r"stiction: parameter 'breakaway'"),
        ({"backlash": {"width": [1.0]}}, r"backlash: parameter 'width' must be a real number"),
        ({"quantization": {"step": 0.1, "mode": "ceil"}},
         r"quantization: parameter 'mode' must be one of \('round', 'floor'\)"),
        ({"offset": {"value": 1.0, "on": "plant"}}, r"offset: parameter 'on' must be one of \('actuator', 'sensor'\)"),
        ({"cogging": {"amplitude": 1.0, "period": 0.0}}, r"cogging: parameter 'period' must be in \[1e-12, 1e\+09\]"),
        ({"time_delay": {"delay": -0.001}}, r"time_delay: parameter 'delay' must be in \[0, 1000\]"),
        ({"drift": {"rate": -2.0}}, r"drift: parameter 'rate' must be in \[-1, 10\]"),
        ({"compliance": {"frequency": 0.0}}, r"compliance: parameter 'frequency' must be in \[0.001, 1e\+09\]"),
        ({"compliance": {"frequency": 10.0, "measured": "shaft"}},
         r"compliance: parameter 'measured' must be one of \('load', 'motor'\)"),
        ({"drift": {"rate": 0.1, "parameter": "inertia"}}, r"drift: parameter 'parameter' must be .*'gain'"),
        ({"drift": {"rate": 0.1, "mode": "random"}}, r"drift: parameter 'mode' must be one of"),
        ({"drift": {"rate": 0.1, "start": -1}}, r"drift: parameter 'start' must be an integer"),
        ({"saturation": 150.0}, r"saturation: parameters must be a dict"),
        ("saturation", r"effects: expected a dict"),
        (["saturation"], r"needs its parameters"),
    ],
)
def test_bad_effect_parameters_raise_value_error(spec, pattern):
    with pytest.raises(ValueError, match=pattern):
        build_effects(spec)
    with pytest.raises(ValueError, match=pattern):
        gym.make("gbo_envs/DCMotor-v0", effects=spec)


def test_every_catalogue_name_builds_from_gym_make():
    required = {"saturation": {"limit": 1e3}, "dead_zone": {"width": 1.0}, "coulomb_friction": {"torque": 1.0},
                "viscous_friction": {"coefficient": 0.01}, "stiction": {"breakaway": 1.0},
                "backlash": {"width": 0.5}, "quantization": {"step": 0.1}, "offset": {"value": 1.0},
                "cogging": {"amplitude": 1.0}, "time_delay": {"delay": 0.001}, "drift": {"rate": -0.01},
                "compliance": {"frequency": 40.0}}
    assert set(required) == set(EFFECT_NAMES)
    env = gym.make("gbo_envs/DCMotor-v0", noise=False, effects=required)
    env.reset(seed=0)
    info = env.step(np.array([0.54, 1.16]))[4]
    assert not info["unstable"] and np.all(np.isfinite(info["y"]))
