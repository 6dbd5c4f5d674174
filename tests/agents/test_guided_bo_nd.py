"""Guided BO beyond two gains: the PID env (3 gains) and the position-speed cascade (4 gains)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import agents
import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.prior import TwinMetrics
from agents.twin_keeper import TwinKeeper

CASCADE = "gbo_envs/LinearMotorCascade-v0"
#: Gains of two cascade experiments: near the start of a run, and a corner with little feed-forward.
CASCADE_GAINS = ([34.37, 29.60, 77.11, 0.874], [33.3, 33.4, 104.2, 0.051])


def _keeper_told(env_id: str, gains) -> tuple[TwinKeeper, object]:
    env = gym.make(env_id)
    keeper = TwinKeeper()
    keeper.setup(agents.GainSpace.from_env(env), env.unwrapped)
    env.reset(seed=0)
    for g in gains:
        info = env.step(np.asarray(g, dtype=float))[4]
        keeper.tell(info["gains"], info["cost"], info)
    return keeper, env


def test_the_keeper_identifies_the_linmot_plant_from_cascade_records():
    """From the record's u (the current command) and y (the position), the plant u -> y: 0.44262 / (0.070983 s^2 +
    0.8 s) e^{-0.001 s} = 6.2356 / (s^2 + 11.270 s) e^{-0.001 s}, though a 3 ms decimation of the command misleads
    SRIVC (a_1 = 7.9 1/s)."""
    keeper, _ = _keeper_told(CASCADE, CASCADE_GAINS)
    assert keeper.twin_env() is not None and keeper.can_guide()
    twin = keeper.twin_
    b0, a1 = twin.params_
    assert b0 == pytest.approx(0.44262 / 0.070983, rel=1e-3)
    assert a1 == pytest.approx(0.8 / 0.070983, rel=1e-3)
    assert twin.delay_ == pytest.approx(0.001, abs=5e-5)
    assert twin.rmse_ <= keeper.explained_rmse_


def test_the_twin_of_a_quantized_sensor_rounds_as_the_encoder_does():
    """The LinMot's 5 um encoder shows no noise: the twin rounds its position to the quantum instead of adding white
    noise of std q / sqrt(12), and its costs at random gains are the plant's (median within 1 %; the noisy twin's:
    25 % high, its maxima above the reference make overshoot where the rounding makes none)."""
    keeper, env = _keeper_told(CASCADE, CASCADE_GAINS)
    assert keeper.sensor_quantum_ == pytest.approx(5e-6, rel=1e-6)
    twin_env = keeper.twin_env()
    assert twin_env.loop.output_noise_std == 0.0
    low, high = env.action_space.low, env.action_space.high
    gains = low + np.random.default_rng(1).random((16, low.size)) * (high - low)
    plant = env.unwrapped.evaluate(gains)[1]
    assert np.median(np.abs(twin_env.evaluate(gains)[1] / plant - 1.0)) <= 0.01


def test_a_noisy_sensor_keeps_the_white_noise_twin():
    """DCMotorRig-v0's speed noise is visible: no quantum, the twin simulates the records' noise floor."""
    keeper, _ = _keeper_told("gbo_envs/DCMotorRig-v0", ([0.3, 1.5], [0.6, 1.0]))
    assert keeper.sensor_quantum_ is None
    assert keeper.twin_env().loop.output_noise_std > 0.0


def _spied_run(env_id: str, budget: int):
    """A guided-bo run whose twin prior records every unit-box point it is evaluated at."""
    seen: list[np.ndarray] = []
    original = TwinMetrics.__call__

    def spy(self, X):
        seen.append(np.array(np.atleast_2d(X), dtype=float))
        return original(self, X)

    tuner = agents.make("guided-bo")
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(TwinMetrics, "__call__", spy)
        result = tuner.run(gym.make(env_id), budget=budget, seed=0)
    return tuner, result, seen


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ["gbo_envs/DCMotorPID-v0", CASCADE])
def test_guided_bo_runs_in_three_and_four_gains_with_the_prior_where_the_acquisition_looks(env_id):
    """Proposals inside the feasible set; the twin prior was evaluated at each proposal after the initial design,
    and at points off any grid of the unit box (the Sobol candidates and the multistart refinement's)."""
    budget = 3
    tuner, result, seen = _spied_run(env_id, budget)
    env = gym.make(env_id)
    low, high = env.action_space.low, env.action_space.high
    frame = result.to_pandas()
    names = list(tuner.space.names)
    gains = frame[names].to_numpy()
    assert gains.shape == (budget, len(low)) and len(low) >= 3
    assert np.all(gains >= low) and np.all(gains <= high)
    assert result.info["activations"] == budget - 1 and seen
    evaluated = np.vstack(seen)
    for proposal in tuner.space.to_unit(gains[1:]):
        assert np.any(np.all(np.abs(evaluated - proposal) <= 1e-12, axis=1))  # the prior at the very point proposed
    step = 1.0 / (tuner.grid_points - 1)  # the 2-gain grid's spacing in the unit box
    off_grid = np.any(np.abs(evaluated / step - np.round(evaluated / step)) > 1e-6, axis=1)
    assert off_grid.mean() > 0.9
