"""Guided BO: Algorithm 1 (activation, twin rows), the twin prior, re-initialisation after a plant change."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import agents
import gbo_envs  # noqa: F401
from agents.bo import BayesianOptimization
from agents.guidance import TwinIterations, TwinPrior, as_guidance
from agents.guided_bo import GuidedBO
from tests.support import DC_MOTOR_PARAMS

FAST = {"grid_points": 40}
PAPER = {"guidance": "iterations", **FAST}  # the paper's Algorithm 1, the parameter table's values


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
    periodic = TwinIterations(activation="periodic", period=2, n_ei=3, eta3=np.inf)
    result = GuidedBO(guidance=periodic, **FAST).run(gym.make("gbo_envs/DCMotor-v0"), budget=7, seed=0)
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
    tuner = GuidedBO(delta=0.3, **FAST)
    counts = _drive(tuner, env, budget=9)
    assert counts[4] == 0  # nothing before the change (experiments 0..4)
    assert counts[-1] >= 1  # eq. (reinit_DTdataset) fired once the plant changed
    first = counts.index(counts[-1] if counts[-1] == 1 else 1)
    assert first >= 5
    # the twin data set restarted from the changed plant's records, and the twin refits on them
    assert tuner.twin_ is not None
    assert tuner.twin_.params_[0] == pytest.approx(4.0, rel=0.02)


@pytest.mark.parametrize("kwargs, match", [
    ({"eta2": 0.0}, "eta2"), ({"n_samples": 3}, "n_samples"),
    ({"twin_poles": 0}, r"twin_poles: must be an int in \[1, inf\), got 0"),
    ({"twin": object()}, r"twin: must be one of \('auto', 'linear'\) or an object with method\(s\) fit, get_params"),
    ({"n_initial": 0}, "n_initial"), ({"grid_points": 1}, "grid_points"),
    ({"guidance": "mean"}, r"guidance: must be one of \('prior', 'iterations'\)"),
    ({"guidance": {"iterations": {"eta1": -1.0}}}, r"eta1: must be a float in \[0, inf\), got -1.0"),
    ({"guidance": {"iterations": {"eta_1": 1.0}}}, r"guidance: 'iterations' takes .*'eta1'.*, got \['eta_1'\]"),
    ({"guidance": {"prior": {"eta1": 1.0}}}, r"guidance: 'prior' takes no parameters, got \['eta1'\]"),
    ({"guidance": {"iterations": {}, "prior": {}}}, "guidance: must be one of"),
])
def test_bad_parameters_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        GuidedBO(**kwargs)


@pytest.mark.parametrize("kwargs, match", [
    ({"eta1": -1.0}, "eta1"), ({"n_ei": 0}, "n_ei"), ({"activation": "always"}, "activation"),
    ({"period": 0}, "period"), ({"eta3": float("nan")}, "eta3"), ({"max_twin_iterations": 0}, "max_twin_iterations"),
    ({"n_ei": 2.5}, r"n_ei: must be an int in \[1, inf\), got 2.5"),
])
def test_bad_twin_iterations_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        TwinIterations(**kwargs)


def test_guidance_objects_are_small_validated_values():
    """Frozen, equal when their values are (ints and floats converted), picklable, with a repr that rebuilds them;
    a name or a one-key table (a study file's form) stands for them."""
    import pickle

    paper = TwinIterations()
    assert (paper.eta1, paper.eta3, paper.n_ei, paper.max_twin_iterations, paper.activation, paper.period) == (
        3.0, 0.2, 3, 20, "uncertainty", 1)  # the paper's parameter table
    assert TwinIterations(eta1=3) == paper and type(TwinIterations(eta1=3).eta1) is float
    assert eval(repr(TwinIterations(eta1=2, n_ei=5)), {"TwinIterations": TwinIterations}) == TwinIterations(eta1=2,
                                                                                                          n_ei=5)
    assert repr(TwinPrior()) == "TwinPrior()" and TwinPrior() == TwinPrior()
    for guidance in (paper, TwinPrior(), TwinIterations(activation="periodic", eta3=np.inf)):
        assert pickle.loads(pickle.dumps(guidance)) == guidance
    with pytest.raises(AttributeError):
        paper.eta1 = 1.0  # frozen
    assert as_guidance("iterations") == paper and as_guidance("prior") == TwinPrior()
    assert as_guidance({"iterations": {"eta1": 2}}) == TwinIterations(eta1=2.0)
    assert as_guidance({"prior": {}}) == TwinPrior() and as_guidance(paper) is paper
    assert (TwinPrior.model, TwinIterations.model) == ("metrics", "cost")


def test_params_are_the_constructor_keywords_and_rebuild_the_tuner():
    import inspect
    import pickle

    tuner = GuidedBO(guidance=TwinIterations(eta1=2, eta3=np.inf, activation="periodic"), **FAST)
    params = tuner.get_params()
    keywords = [p.name for p in inspect.signature(GuidedBO).parameters.values() if p.kind is p.KEYWORD_ONLY]
    safe_mode = ["safe", "safe_start", "safe_delta"]  # as bo's: in the params only in safe mode (specs unchanged)
    assert list(params) == [name for name in keywords if name not in safe_mode]
    safe = GuidedBO(safe=True, safe_start=[[0.3, 1.0]], **FAST).get_params()
    assert list(safe) == keywords and agents.make("guided-bo", **safe).get_params() == safe
    assert params["twin"] == "auto" and params["grid_points"] == 40
    assert params["guidance"] == TwinIterations(eta1=2.0, eta3=np.inf, activation="periodic")
    assert agents.make("guided-bo", **params).get_params() == params
    assert pickle.loads(pickle.dumps(tuner)).get_params() == params  # sessions pickle the tuner
    assert tuner.model == "cost"  # one GP on the cost (Algorithm 1)
    assert GuidedBO().model == "metrics"  # the default BO's surrogate, with the twin as prior mean
    assert GuidedBO().guidance == TwinPrior() and GuidedBO(guidance="iterations").guidance == TwinIterations()
    assert GuidedBO(guidance={"iterations": {"n_ei": 5}}).get_params()["guidance"] == TwinIterations(n_ei=5)
    for removed in ("model", "twin_noise", "best_point", "min_twin_iterations", "twin_incumbent", "twin_polish",
                    "twin_refit_every", "twin_zeros", "twin_hyperparameters"):
        with pytest.raises(TypeError, match=removed):
            GuidedBO(**{removed: None})


def test_the_former_keywords_warn_and_give_the_same_tuner():
    """For one release ``GuidedBO(eta1=...)`` still works: a FutureWarning names the new spelling, the tuner and its
    run are those of ``guidance=TwinIterations(...)``; beside ``guidance="prior"`` they have, as before, no effect."""
    env = gym.make("gbo_envs/DCMotor-v0")
    with pytest.warns(FutureWarning, match=r"guidance=TwinIterations\(n_ei=2, activation='periodic', eta3=inf\)"
                                           r" \(in a study file: guidance = \{iterations = \{n_ei = 2, "
                                           r"activation = \"periodic\", eta3 = inf\}\}\)"):
        old = GuidedBO(guidance="iterations", n_ei=2, activation="periodic", eta3=np.inf, **FAST)
    new = GuidedBO(guidance=TwinIterations(n_ei=2, activation="periodic", eta3=np.inf), **FAST)
    assert old.get_params() == new.get_params()
    runs = [tuner.run(env, budget=3, seed=0).to_pandas(include_twin=True) for tuner in (old, new)]
    np.testing.assert_array_equal(runs[0][["Kp", "Ki", "cost"]].to_numpy(), runs[1][["Kp", "Ki", "cost"]].to_numpy())
    with pytest.warns(FutureWarning, match=r"no effect with guidance='prior'.*guidance=TwinIterations\(eta1=0.0\)"):
        prior = GuidedBO(eta1=0.0, **FAST)
    assert prior.get_params() == GuidedBO(**FAST).get_params()
    with pytest.raises(ValueError, match="eta1"):
        GuidedBO(guidance="iterations", eta1=-1.0)  # still checked
    with pytest.raises(ValueError, match=r"eta1: give them in the guidance"):
        GuidedBO(guidance=TwinIterations(n_ei=5), eta1=2.0)
    with pytest.raises(TypeError, match="unexpected keyword argument 'eta_1'"):
        GuidedBO(eta_1=2.0)


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


@pytest.mark.slow
def test_the_twin_prior_guides_bo_beyond_two_gains():
    """DCMotorPID-v0 (3 gains): EI is maximised off any grid, and the prior is the twin evaluated wherever it looks."""
    result = agents.make("guided-bo").run(gym.make("gbo_envs/DCMotorPID-v0"), budget=3, seed=0)
    assert result.info["activations"] == 2 and result.info["twin_evaluations"] > 0
    optimum = gbo_envs.ground_truth("gbo_envs/DCMotorPID-v0").cost
    assert result.min_true_cost_curve().min() / optimum <= 1.1
