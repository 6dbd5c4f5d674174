"""Guided BO beyond two gains: the PID env (3 gains) and the position-speed cascade (4 gains)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import agents
import agents.bo as bo_module
import gbo_envs  # noqa: F401  (registers the envs)
from agents import acquisition
from agents.guided_bo import PRIOR_STARTS
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


@pytest.mark.slow
def test_in_three_gains_the_twin_prior_is_refined_from_prior_starts_starts():
    """Under the twin prior EI's multistart refines from PRIOR_STARTS starts, each step simulating the twin at
    starts * (d + 1) gains; its Sobol candidates stay the default BO's (a new scramble every fit), and without the
    prior the default BO's n_starts."""
    env = gym.make("gbo_envs/DCMotorPID-v0")
    tuner = agents.make("guided-bo")
    tuner.setup(agents.GainSpace.from_env(env), seed=0, env=env)
    env.reset(seed=0)
    starts = []
    original = acquisition.maximize_multistart

    def spy(*args, **kwargs):
        starts.append((kwargs["n_starts"], tuner.metric_prior() is not None))
        return original(*args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(bo_module, "maximize_multistart", spy)
        for _ in range(3):
            gains = tuner.ask()
            info = env.step(np.asarray(gains))[4]
            tuner.tell(gains, info["cost"], info)
    assert starts and all(n == (PRIOR_STARTS if prior else tuner.n_starts) for n, prior in starts)
    assert any(prior for _, prior in starts) and PRIOR_STARTS < tuner.n_starts
    rng, _ = tuner.multistart_plan()
    default_rng, default_starts = bo_module.BayesianOptimization.multistart_plan(tuner)
    assert default_starts == tuner.n_starts and np.array_equal(rng.random(4), default_rng.random(4))


def test_the_cascade_overshoot_near_the_optimum_is_below_what_a_twin_can_identify():
    """GuidedBO's notes: near the cascade's optimum whether a response reads one encoder count above its final value
    changes with a 1e-5 relative change of the plant's gain at about 40 % of the gains (an overshoot of one count
    costs 0.10, a sixth of J*), and the plant without its quantized sensor does not overshoot there at all."""
    truth = gbo_envs.ground_truth(CASCADE)
    plant = gym.make(CASCADE, noise=False).unwrapped
    low, high = plant.action_space.low, plant.action_space.high
    offsets = np.random.default_rng(1).random((256, low.size)) - 0.5
    gains = np.clip(truth.gains + 0.2 * offsets * (high - low), low, high)
    metrics, cost = plant.evaluate(gains)
    counts = metrics[:, 0] > 0.0
    assert 0.3 < counts.mean() < 0.9
    one_count = 100.0 * 5e-6 / 0.01  # % of the 10 mm step
    assert plant.weights[0] * one_count / plant.normalizers[0] == pytest.approx(0.10)  # the normaliser is one count
    perturbed = gym.make(CASCADE, noise=False, gain=0.44262 * (1 + 1e-5)).unwrapped.evaluate(gains)[0]
    assert 0.3 < np.mean(counts != (perturbed[:, 0] > 0.0)) < 0.6
    unquantized = gym.make(CASCADE, noise=False, sensor_resolution=None).unwrapped.evaluate(gains)[0]
    assert np.all(unquantized[:, 0] < 0.1 * one_count)
