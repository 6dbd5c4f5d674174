"""The settling time from the error envelope (agents.settling) and its use by BO."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from scipy.special import ndtr
from sklearn.gaussian_process import GaussianProcessRegressor

import agents
import gbo_envs  # noqa: F401  (registers the envs)
from agents.settling import SettlingTimeModel, _normal_cdf, error_envelope
from agents.surrogate import GPSurrogate, _neg_log_marginal_likelihood, squared_differences
from gbo_envs.metrics import step_metrics

T = np.linspace(0.0, 5.0, 2501)
R1, R2 = 245.0, 306.0


def _response(damping: float, frequency: float, creep: float = 0.0) -> np.ndarray:
    """A damped oscillation towards R2, plus a slow bump of height ``creep`` at 3 s (which makes T_s jump)."""
    error = np.exp(-damping * T) * np.cos(frequency * T) + creep * (T / 3.0) * np.exp(1.0 - T / 3.0)
    return R2 - (R2 - R1) * error


def test_envelope_is_the_largest_remaining_error_and_decides_the_settling_time():
    rng = np.random.default_rng(0)
    times = np.linspace(0.05, 5.0, 100)
    for _ in range(20):
        y = _response(rng.uniform(0.5, 4.0), rng.uniform(0.0, 8.0), rng.uniform(0.0, 0.04))
        envelope = error_envelope(T, y, R1, R2, times)
        error = np.abs(y - R2) / (R2 - R1)
        index = np.searchsorted(T, times - 1e-9)
        np.testing.assert_allclose(envelope, [error[i:].max() for i in index])
        assert np.all(np.diff(envelope) <= 0)
        # eq. (Ts): T_s <= t_k exactly when the envelope at t_k is inside the 2 % band
        settling = step_metrics(T, y, R1, R2)[1]
        # (at t_K = T, eq. (Ts) caps T_s at T even when the response never settled)
        np.testing.assert_array_equal(envelope[:-1] <= 0.02, settling <= times[:-1] + 1e-12)
    # a first-order response: E(t) = exp(-t / tau)
    tau = 0.7
    first_order = R2 - (R2 - R1) * np.exp(-T / tau)
    np.testing.assert_allclose(error_envelope(T, first_order, R1, R2, times), np.exp(-times / tau), rtol=1e-9)
    with pytest.raises(ValueError, match="r1, r2"):
        error_envelope(T, first_order, R2, R2, times)
    with pytest.raises(ValueError, match="t, y"):
        error_envelope(T[:-1], first_order, R1, R2, times)


def test_normal_cdf_approximation_is_within_1_5e_4():
    z = np.linspace(-30.0, 30.0, 120001)
    assert np.max(np.abs(_normal_cdf(z.copy()) - ndtr(z))) < 1.5e-4


def test_shared_kernel_gp_of_several_outputs_equals_sklearn():
    rng = np.random.default_rng(1)
    X = rng.uniform(size=(25, 2))
    Y = np.column_stack([np.sin(4 * X[:, 0]), X[:, 1] ** 2 + X[:, 0], 3.0 + np.cos(3 * X[:, 1])])
    gp = GPSurrogate(min_fit_points=1).fit(X, Y, seed=0)
    np.testing.assert_allclose(gp.y_mean_, Y.mean(axis=0))
    Y_std = (Y - gp.y_mean_) / gp.y_scale_
    reference = GaussianProcessRegressor(gp.kernel_, alpha=1e-8, optimizer=None).fit(X, Y_std)
    grid = rng.uniform(size=(1500, 2))
    mean, std = gp.predict(grid)
    ref_mean, ref_std = reference.predict(grid, return_std=True)
    assert mean.shape == std.shape == (1500, 3)
    np.testing.assert_allclose(mean, gp.y_mean_ + gp.y_scale_ * ref_mean, atol=1e-10)
    white = gp.kernel_.k2.noise_level
    np.testing.assert_allclose(std, gp.y_scale_ * np.sqrt(np.maximum(ref_std**2 - white, 1e-18)), rtol=1e-5)
    # the likelihood is the sum over the outputs (scikit-learn's multi-output likelihood)
    pairwise = squared_differences(X)
    value, grad = _neg_log_marginal_likelihood(gp.kernel_.theta + 0.2, pairwise, Y_std, 1e-8, True)
    ref, ref_grad = reference.log_marginal_likelihood(gp.kernel_.theta + 0.2, eval_gradient=True)
    assert -value == pytest.approx(ref, rel=1e-9)
    np.testing.assert_allclose(-grad, ref_grad, rtol=1e-6, atol=1e-9)
    with pytest.raises(ValueError, match="several outputs"):
        GPSurrogate(noise_std=0.1).fit(X, Y)


def _family(X: np.ndarray) -> list[np.ndarray]:
    """Responses whose settling time jumps where the creep crosses the band (x1 = 0.5)."""
    return [_response(2.0 + 2.0 * x0, 3.0 + 2.0 * x0, 0.01 + 0.02 * x1) for x0, x1 in X]


def test_settling_model_recovers_the_settling_time_and_its_jump():
    rng = np.random.default_rng(2)
    times = np.linspace(0.05, 5.0, 100)
    X = rng.uniform(size=(40, 2))
    model = SettlingTimeModel(times, normalizer=2.0, min_fit_points=1)
    model.fit(X, [error_envelope(T, y, R1, R2, times) for y in _family(X)], seed=0)
    probabilities = model.distribution(X)
    assert np.all(probabilities >= 0) and np.allclose(probabilities.sum(axis=1), 1.0)
    mean, std = model.predict(X)
    truth = np.array([step_metrics(T, y, R1, R2)[1] for y in _family(X)])
    # at the training points: the true T_s within the 0.05 s time resolution (and the normalizer)
    assert np.max(np.abs(2.0 * mean - truth)) < 0.06 and np.all(std >= 0)
    # across the jump (x1 = 0.5 in this family) the model keeps it a jump of about the true size
    test = np.array([[0.5, 0.3], [0.5, 0.7]])
    jump = np.diff([step_metrics(T, y, R1, R2)[1] for y in _family(test)])[0]
    assert jump > 1.0
    assert 2.0 * np.diff(model.predict(test)[0])[0] == pytest.approx(jump, rel=0.15)
    with pytest.raises(ValueError, match="times"):
        SettlingTimeModel([1.0, 0.5])
    with pytest.raises(ValueError, match="envelopes"):
        model.fit(X, np.ones((40, 3)))


def test_bo_models_the_settling_time_from_the_envelope_and_falls_back_to_a_gp():
    env = gym.make("gbo_envs/DCMotor-v0")
    bo = agents.BayesianOptimization(grid_points=20, settling_model="envelope")
    bo.run(env, budget=7, seed=0)
    model = bo.fit_surrogate()
    assert isinstance(model.models[1], SettlingTimeModel)
    assert bo.envelope_training_set().shape == (7, 100)
    # without trajectories in the records, the settling time gets its own GP
    bare = agents.BayesianOptimization(grid_points=20, settling_model="envelope")
    bare.setup(agents.GainSpace.from_env(env), seed=0, env=env)
    for gains in ([0.3, 1.0], [0.6, 1.5], [0.9, 2.0]):
        info = env.step(np.asarray(gains))[4]
        bare.tell(gains, info["cost"], {"metrics": info["metrics"]})
    bare.ask()
    assert bare.envelope_training_set() is None and not isinstance(bare.fit_surrogate().models[1], SettlingTimeModel)
    gp_only = agents.BayesianOptimization(grid_points=20)  # the default: a GP on the settling time
    gp_only.run(env, budget=6, seed=0)
    assert not isinstance(gp_only.fit_surrogate().models[1], SettlingTimeModel)
    with pytest.raises(ValueError, match="settling_model"):
        agents.BayesianOptimization(settling_model="envelopes")


def test_the_envelope_model_starts_with_the_hyperparameter_fits_and_bo_does_not_remeasure_its_incumbent():
    env = gym.make("gbo_envs/LinearMotor-v0")
    # below the GPs' min_fit_points the settling time has a GP of its own (no envelope model yet)
    early = agents.BayesianOptimization(settling_model="envelope")
    early.run(env, budget=4, seed=57)
    assert not isinstance(early.fit_surrogate().models[1], SettlingTimeModel) and not early.fit_surrogate().derived
    # seeds 57 and 29 measured the corner (Kp_min, Kd_min) four times in a row with the envelope model
    # on the first points and the measured settling time as the incumbent's
    for seed in (57, 29):
        result = agents.BayesianOptimization(settling_model="envelope").run(env, budget=8, seed=seed)
        gains = result.to_pandas()[["Kp", "Kd"]].round(6)
        assert gains.value_counts().max() <= 2, gains
    # the incumbent takes the envelope model's settling time, so that at the measured gains the
    # model promises nothing the measurement did not show
    bo = agents.BayesianOptimization(settling_model="envelope")
    bo.run(env, budget=8, seed=57)
    model = bo.fit_surrogate()
    assert model.derived == (1,)
    X, metrics, _ = bo.metric_training_set()
    observed = bo.metric_surrogate.observed_cost(model, X, metrics)
    mean = model.predict_metrics(X)[0]
    np.testing.assert_allclose(observed, np.column_stack(
        [metrics[:, 0] / bo.metric_surrogate.normalizers[0], mean[:, 1],
         metrics[:, 2:] / bo.metric_surrogate.normalizers[2:]]) @ bo.metric_surrogate.weights)
    assert bo.incumbent() == pytest.approx(observed.min())
