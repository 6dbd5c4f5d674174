"""Constrained and safe tuning: bo's EI x probability of feasibility, its safe mode, SafeOpt, the peers, the result."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import agents
import gbo_envs  # noqa: F401
from agents.feasibility import ConstraintModel, reported_slacks
from agents.safeopt import _optimistic_upper

ENV = "gbo_envs/DCMotor-v0"
LIMITS = {"overshoot_pct": 2.0, "peak_u": 140.0}
SAFE_START = [[0.3, 1.0]]


def _env(**kwargs):
    return gym.make(ENV, constraints=LIMITS, **kwargs)


def _space():
    return agents.GainSpace.from_env(gym.make(ENV))


def _record(slack: float) -> dict:
    """A record of one constraint ``x`` with slack ``slack``."""
    return {"constraints": {"x": slack}, "feasible": slack <= 0, "unstable": False}


# -- constrained bo ----------------------------------------------------------------------------------------
def test_constrained_bo_models_the_constraints_and_its_best_is_feasible():
    tuner = agents.make("bo")
    result = tuner.run(_env(), budget=12, seed=0)
    frame = result.to_pandas()
    assert tuner.constraint_model is not None and tuner.constraint_model.names == tuple(LIMITS)
    assert frame["feasible"].dtype == bool and set(frame.columns) >= {"constraint_overshoot_pct",
                                                                      "constraint_peak_u"}
    assert result.violations == int((~frame["feasible"]).sum())
    best = frame.loc[frame["cost"].idxmin()] if frame["feasible"].all() else \
        frame[frame["feasible"]].loc[frame[frame["feasible"]]["cost"].idxmin()]
    assert result.best_cost == best["cost"] and bool(best["feasible"])
    assert f"{result.violations} broke a constraint" in repr(result)


def test_without_a_feasible_experiment_bo_maximises_the_probability_of_feasibility():
    space = _space()
    tuner = agents.make("bo", model="cost")
    tuner.setup(space, seed=0)
    for kp in (0.6, 0.8, 1.0):  # slack grows with Kp, feasible below Kp = 0.3: none measured yet
        gains = np.array([kp, 1.5])
        tuner.tell(gains, 1.0 - 0.1 * kp, _record(kp - 0.3))
    acquisition = tuner._constrained_acquisition(tuner.fit_surrogate())
    assert acquisition.ei is None
    gains = np.asarray(tuner.ask())
    assert gains[0] < 0.6  # towards the feasible side, not the lowest cost (Kp = 1.0)


def test_the_incumbent_is_the_best_feasible_cost():
    space = _space()
    tuner = agents.make("bo", model="cost")
    tuner.setup(space, seed=0)
    tuner.tell(np.array([1.0, 1.5]), 0.2, _record(0.5))  # cheapest, but infeasible
    tuner.tell(np.array([0.2, 1.5]), 0.6, _record(-0.1))
    tuner.tell(np.array([0.3, 1.2]), 0.5, _record(-0.2))
    assert tuner.incumbent() == pytest.approx(0.5)


def test_bo_without_constraints_proposes_what_it_proposed_before():
    # bo's proposals on DCMotor-v0, seed 0, budget 10, recorded before constraints existed
    pinned = json.loads((Path(__file__).parent / "data" / "bo_unconstrained_proposals.json").read_text())
    result = agents.make("bo").run(gym.make(ENV), budget=10, seed=0)
    np.testing.assert_allclose(result.to_pandas()[["Kp", "Ki", "cost"]].to_numpy(), pinned["0"], rtol=0, atol=1e-9)
    assert "broke" not in repr(result)


# -- safe mode ---------------------------------------------------------------------------------------------
def test_safe_mode_refuses_without_a_safe_start_or_without_constraints():
    with pytest.raises(ValueError, match="safe_start"):
        agents.make("bo", safe=True)
    with pytest.raises(ValueError, match="constraints"):
        agents.make("bo", safe=True, safe_start=SAFE_START).run(gym.make(ENV), budget=2, seed=0)
    with pytest.raises(ValueError, match="safe_start"):
        agents.make("bo", safe=True, safe_start=[[0.3, 1.0, 2.0]]).run(_env(), budget=2, seed=0)
    with pytest.raises(ValueError, match="delta"):
        agents.make("bo", safe=True, safe_start=SAFE_START, delta=1.0)


def test_safe_mode_starts_at_the_safe_start_and_proposes_only_likely_safe_gains():
    env = _env()
    tuner = agents.make("bo", safe=True, safe_start=SAFE_START, delta=0.05)
    tuner.setup(agents.GainSpace.from_env(env), seed=0, env=env)
    env.reset(seed=0)
    for i in range(10):
        gains = np.asarray(tuner.ask())
        if i == 0:
            np.testing.assert_array_equal(gains, SAFE_START[0])
        else:
            pf = tuner.constraint_model.probability(tuner.space.to_unit(gains)[None, :])[0]
            repeated = any(np.allclose(tuner.space.to_unit(gains), x) for x in tuner._plant_X)
            assert pf >= 0.95 or repeated
        info = env.step(gains)[4]
        tuner.tell(gains, info["cost"], info)
    assert tuner.get_params()["safe"] is True and tuner.get_params()["safe_start"] == SAFE_START


def test_safe_mode_repeats_the_best_feasible_gains_when_nothing_is_safe(monkeypatch):
    space = _space()
    tuner = agents.make("bo", model="cost", safe=True, safe_start=[[0.3, 1.0], [0.35, 1.1]])
    tuner.setup(space, seed=0)
    tuner.tell(np.array([0.3, 1.0]), 0.6, _record(-0.5))
    tuner.tell(np.array([0.35, 1.1]), 0.5, _record(-0.2))
    monkeypatch.setattr(tuner.constraint_model, "probability", lambda X: np.full(len(X), 0.5))
    np.testing.assert_allclose(tuner.ask(), [0.35, 1.1])


def test_safe_mode_without_an_env_learns_the_constraints_from_the_records():
    tuner = agents.make("bo", model="cost", safe=True, safe_start=[[0.3, 1.0]])
    tuner.setup(_space(), seed=0)
    tuner.tell(np.array([0.3, 1.0]), 0.6, {"cost": 0.6})  # no constraints reported
    with pytest.raises(ValueError, match="report their constraints"):
        tuner.ask()


# -- SafeOpt -----------------------------------------------------------------------------------------------
def test_safeopt_refuses_a_constrained_env_without_a_safe_start_and_takes_an_unconstrained_one():
    with pytest.raises(ValueError, match="safe_start"):
        agents.make("safeopt").run(_env(), budget=2, seed=0)
    with pytest.raises(ValueError, match="safe_start"):
        agents.make("safeopt", safe_start=[[0.3]]).run(_env(), budget=2, seed=0)
    tuner = agents.make("safeopt")
    result = tuner.run(gym.make(ENV), budget=3, seed=0)  # no constraints: every gain is safe
    assert result.n_experiments == 3 and tuner._safe.all()


def test_safeopt_proposes_only_from_its_safe_set_which_grows_from_the_start():
    tuner = agents.make("safeopt", safe_start=SAFE_START)
    env = _env()
    tuner.setup(agents.GainSpace.from_env(env), seed=0, env=env)
    env.reset(seed=0)
    sizes = []
    for i in range(8):
        gains = np.asarray(tuner.ask())
        index = int(np.argmin(np.abs(tuner._D - tuner.space.to_unit(gains)).sum(axis=1)))
        assert tuner._safe[index]
        if i:
            mean, std = tuner.constraints.predict(tuner._D[index][None, :])
            assert np.all(mean + tuner.beta * std <= 0) or index < len(SAFE_START)
            sizes.append(tuner.last_sets_["safe_set"])
        info = env.step(gains)[4]
        tuner.tell(gains, info["cost"], info)
    assert sizes[-1] > sizes[0] > 1 and sizes == sorted(sizes)


def test_the_expanders_fictitious_observation_is_the_refitted_gp():
    rng = np.random.default_rng(0)
    model = ConstraintModel(["x"], [1.0])
    for x in rng.random((6, 2)):
        model.add(x, _record(float(x[0] - 0.5)))
    model.fit(seed=0)
    gp = model.models[0]
    A, B = model.features(rng.random((3, 2))), model.features(rng.random((4, 2)))
    upper = _optimistic_upper(gp, A, B, beta=2.0)
    for i, a in enumerate(A):
        mean, std = gp.predict(a[None, :], return_std=True)
        noise = gp.kernel_.k2.noise_level
        latent_std = np.sqrt(std**2 - noise)
        refit = type(gp)(gp.kernel_, optimizer=None, alpha=gp.alpha, normalize_y=False)
        refit.fit(np.vstack([gp.X_train_, a]), np.append(gp.y_train_, mean - 2.0 * latent_std))
        m, s = refit.predict(B, return_std=True)
        np.testing.assert_allclose(upper[i], m + 2.0 * np.sqrt(np.maximum(s**2 - noise, 0)), rtol=1e-5, atol=1e-6)


# -- peers -------------------------------------------------------------------------------------------------
def test_optuna_trials_carry_the_constraints_of_the_env():
    tuner = agents.make("optuna-gp", n_initial=1)
    result = tuner.run(_env(), budget=3, seed=0)
    trials = tuner.study.trials
    frame = result.to_pandas()
    for trial, (_, row) in zip(trials, frame.iterrows()):
        assert trial.constraints == pytest.approx({name: row[f"constraint_{name}"] for name in LIMITS})


def test_reported_slacks_count_an_unstable_or_failed_experiment_as_broken():
    names, limits = ("overshoot_pct", "peak_u"), (2.0, 140.0)
    assert reported_slacks(None, names, limits) == [2.0, 140.0]
    unstable = {"constraints": {"overshoot_pct": -2.0, "peak_u": float("inf")}, "unstable": True}
    assert reported_slacks(unstable, names, limits) == [2.0, 1400.0]


def test_botorch_builds_a_constrained_acquisition():
    pytest.importorskip("botorch")
    from botorch.acquisition.analytic import LogConstrainedExpectedImprovement

    tuner = agents.make("botorch", n_initial=3, acquisition="logei")
    tuner.run(_env(), budget=4, seed=0)
    assert len(tuner._C) == 4 and len(tuner._C[0]) == len(LIMITS)
    import torch

    x = torch.as_tensor(np.asarray(tuner._X), dtype=torch.float64)
    y = -torch.as_tensor(np.asarray(tuner._y), dtype=torch.float64).unsqueeze(-1)
    acquisition = tuner._constrained_acquisition(x, y)
    assert isinstance(acquisition, LogConstrainedExpectedImprovement)
    assert set(acquisition.constraints) == {1, 2}


# -- result ------------------------------------------------------------------------------------------------
def test_an_unconstrained_result_has_a_feasible_column_and_no_violation_line():
    result = agents.make("random").run(gym.make(ENV), budget=3, seed=0)
    frame = result.to_pandas()
    assert frame["feasible"].tolist() == [True] * 3 and result.constraints == {}
    assert result.violations == 0 and "broke" not in repr(result)


def test_a_result_without_a_feasible_experiment_says_so():
    env = gym.make(ENV, constraints={"peak_u": 100.0})  # the steady command alone is 134.6
    result = agents.make("random").run(env, budget=2, seed=0)
    assert result.violations == 2 and "no feasible experiment" in repr(result)
