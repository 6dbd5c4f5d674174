"""Guided BO: Algorithm 1 (activation, twin rows), the twin prior, re-initialisation after a plant change."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import agents
import gbo_envs  # noqa: F401
from agents.bo import BayesianOptimization
from agents.guided_bo import GuidedBO
from tests.support import DC_MOTOR_PARAMS

FAST = {"grid_points": 40}
PAPER = {"guidance": "iterations", **FAST}  # the paper's Algorithm 1


def _drive(tuner, env, budget, seed=0):
    """ask/tell by hand; returns the tuner's re-initialisation count after each experiment."""
    tuner.setup(agents.GainSpace.from_env(env), seed=seed, env=env)
    env.reset(seed=seed)
    counts = []
    for _ in range(budget):
        gains = tuner.ask()
        info = env.step(np.asarray(gains))[4]
        tuner.tell(gains, info["cost"], info)
        counts.append(tuner.reinitializations_)
    return counts


@pytest.mark.slow
def test_result_marks_twin_rows_and_counts_activations():
    result = GuidedBO(**PAPER).run(gym.make("gbo_envs/DCMotor-v0"), budget=6, seed=0)
    frame = result.to_pandas(include_twin=True)
    plant, twin = frame[frame.source == "plant"], frame[frame.source == "twin"]
    assert plant["experiment"].tolist() == [1, 2, 3, 4, 5, 6]
    assert result.info["activations"] >= 1
    assert twin["activation"].nunique() == result.info["activations"]
    assert len(twin) == result.info["twin_evaluations"] == result.n_twin
    # twin evaluations are made before the plant experiment they guide
    assert twin["experiment"].min() >= 2
    assert np.all(np.isfinite(twin["cost"]))


def test_the_twin_identifies_the_plant_from_the_tuning_records():
    tuner = GuidedBO(**FAST)
    tuner.run(gym.make("gbo_envs/DCMotor-v0"), budget=5, seed=1)
    np.testing.assert_allclose(tuner.twin_.params_, DC_MOTOR_PARAMS, rtol=0.01)
    assert tuner.twin_.rmse_ < tuner.eta2_value


def test_periodic_activation_runs_exactly_n_ei_twin_iterations():
    result = GuidedBO(activation="periodic", period=2, n_ei=3, eta3=np.inf, **PAPER).run(
        gym.make("gbo_envs/DCMotor-v0"), budget=7, seed=0)
    twin = result.to_pandas(include_twin=True).query("source == 'twin'")
    assert twin.groupby("activation").size().eq(3).all()
    assert sorted(twin["experiment"].unique()) == [2, 4, 6]  # after the initial data, then every N_G = 2


@pytest.mark.parametrize("guidance, model", [("iterations", "cost"), ("prior", "metrics")])
def test_untrusted_twin_leaves_plain_bo(guidance, model):
    env = gym.make("gbo_envs/DCMotor-v0")
    guided = GuidedBO(eta2=1e-12, guidance=guidance, **FAST).run(env, budget=6, seed=2)
    plain = BayesianOptimization(model=model, **FAST).run(env, budget=6, seed=2)  # guided BO's GP
    assert guided.info["activations"] == 0 and guided.n_twin == 0
    cols = ["Kp", "Ki"]
    np.testing.assert_allclose(guided.to_pandas()[cols].to_numpy(), plain.to_pandas()[cols].to_numpy())


@pytest.mark.slow
def test_reinitialisation_fires_after_the_plant_changes_and_the_twin_refits():
    env = gym.make("gbo_envs/DCMotorStep-v0", change_at=5, new_params={"gain": 4.0}, noise=False)
    tuner = GuidedBO(eta1=0.0, delta=0.3, **FAST)
    counts = _drive(tuner, env, budget=9)
    assert counts[4] == 0  # nothing before the change (experiments 0..4)
    assert counts[-1] >= 1  # eq. (reinit_DTdataset) fired once the plant changed
    first = counts.index(counts[-1] if counts[-1] == 1 else 1)
    assert first >= 5
    # the twin data set restarted from the changed plant's records, and the twin refits on them
    assert tuner.twin_ is not None
    assert tuner.twin_.params_[0] == pytest.approx(4.0, rel=0.02)


@pytest.mark.parametrize("kwargs, match", [
    ({"eta1": -1.0}, "eta1"), ({"eta2": 0.0}, "eta2"), ({"n_ei": 0}, "n_ei"),
    ({"activation": "always"}, "activation"), ({"period": 0}, "period"), ({"n_samples": 3}, "n_samples"),
    ({"twin_poles": 0}, r"twin_poles: must be an int in \[1, inf\), got 0"), ({"eta3": float("nan")}, "eta3"),
    ({"twin": object()}, r"twin: must be one of \('auto', 'linear'\) or an object with method\(s\) fit, get_params"),
    ({"n_initial": 0}, "n_initial"), ({"grid_points": 1}, "grid_points"),
    ({"guidance": "mean"}, r"guidance: must be one of \('prior', 'iterations'\)"),
])
def test_bad_parameters_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        GuidedBO(**kwargs)


def test_params_are_the_constructor_keywords_and_rebuild_the_tuner():
    tuner = GuidedBO(eta1=2, eta3=np.inf, activation="periodic", **FAST)
    params = tuner.get_params()
    assert set(params) == set(GuidedBO._parameter_constraints) - {"model", "settling_model"}
    assert params["twin"] == "auto"
    assert params["eta1"] == 2.0 and type(params["eta1"]) is float and params["grid_points"] == 40
    assert agents.make("guided-bo", **params).get_params() == params
    assert tuner.model == "metrics"  # the default BO's surrogate, with the twin as prior mean
    assert GuidedBO(guidance="iterations").model == "cost"  # one GP on the cost (Algorithm 1)
    for removed in ("model", "twin_noise", "best_point", "min_twin_iterations", "twin_incumbent", "twin_polish",
                    "twin_refit_every", "twin_zeros", "twin_hyperparameters"):
        with pytest.raises(TypeError, match=removed):
            GuidedBO(**{removed: None})


def test_needs_the_plant_env():
    with pytest.raises(ValueError, match="env"):
        GuidedBO().setup(agents.GainSpace(("Kp", "Ki"), [0.1, 0.8], [1.1, 2.1]), seed=0)


def test_twin_simulations_of_the_prior_are_counted_though_not_rows():
    """With the twin as prior mean (the default) the twin is simulated on the acquisition grid, not logged as rows;
    ``make demo`` and ``gbo tune`` printed "twin evaluations 0" for guided BO."""
    guided = GuidedBO().run(gym.make("gbo_envs/DCMotor-v0"), budget=3, seed=0)
    assert guided.n_twin == 0
    assert guided.twin_evaluations == guided.info["twin_evaluations"] > 0
    assert f"(+{guided.twin_evaluations} twin evaluations)" in repr(guided)
    plain = BayesianOptimization().run(gym.make("gbo_envs/DCMotor-v0"), budget=2, seed=0)
    assert plain.twin_evaluations == 0
