"""The agents package surface: registry, lazy classes, the shared run loop and the third-party example."""

from __future__ import annotations

import runpy

import gymnasium as gym
import numpy as np
import pytest

import agents
import gbo_envs  # noqa: F401
from tests.support import REPO_ROOT

EXAMPLE = REPO_ROOT / "examples" / "custom_tuner.py"


def test_registry_has_the_short_names():
    assert {"bo", "random", "grid", "nominal", "optuna-gp", "optuna-tpe"} <= set(agents.registered_names())
    assert isinstance(agents.make("bo"), agents.BayesianOptimization)
    assert isinstance(agents.make("grid", budget=16), agents.GridSearch)
    assert agents.make("optuna-gp").name == "optuna-gp"


def test_make_unknown_name_lists_the_known_ones():
    with pytest.raises(ValueError, match="random"):
        agents.make("no-such-tuner")


def test_lazy_exports_resolve_and_unknown_attributes_raise():
    for name in ("BayesianOptimization", "GridSearch", "RandomSearch", "NominalPGM", "OptunaTuner",
                 "estimate_noise", "GPSurrogate", "expected_improvement"):
        assert name in agents.__all__
        assert getattr(agents, name).__name__ == name
    with pytest.raises(AttributeError):
        agents.DoesNotExist  # noqa: B018


def test_bo_just_works_with_defaults_and_gives_a_tidy_result():
    result = agents.BayesianOptimization(grid_points=30).run(gym.make("gbo_envs/DCMotor-v0"), budget=4, seed=0)
    frame = result.to_pandas()
    assert list(frame["experiment"]) == [1, 2, 3, 4]
    assert set(frame["source"]) == {"plant"}
    for column in ("Kp", "Ki", "cost", "best_cost", "true_cost", "overshoot_pct", "wall_time"):
        assert column in frame
    assert np.all(np.diff(frame["best_cost"]) <= 0)
    assert result.info["params"]["grid_points"] == 30


def test_third_party_example_runs_as_documented(capsys, tuner_registry):
    namespace = runpy.run_path(str(EXAMPLE), run_name="__main__")
    assert "local-random" in agents.registered_names()
    out = capsys.readouterr().out
    assert "best_cost" in out and "20" in out
    tuner = agents.make("local-random", step=0.2)
    assert isinstance(tuner, namespace["LocalRandomSearch"])
    result = tuner.run(gym.make("gbo_envs/DCMotor-v0"), budget=8, seed=1)
    assert result.n_experiments == 8 and result.info["params"] == {"step": 0.2}
    code = [line for line in EXAMPLE.read_text().splitlines()
            if line.strip() and not line.strip().startswith(("#", '"""'))]
    assert len(code) < 30
