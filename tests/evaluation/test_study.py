"""Study specs: parsing, sweeps, validation messages, shipped studies."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import gbo_envs  # noqa: F401
from evaluation.study import (
    STUDIES_DIR,
    StudySpecError,
    load_study,
    parse_study,
    resolve_study_path,
    shipped_studies,
    slugify,
)

PAPER_STUDIES = ("twin_fidelity", "n0_sensitivity", "eta1_sweep", "performance", "linear_motor", "smoke")


def spec(**changes) -> dict:
    data = {
        "study": {"name": "tiny", "batches": 2, "budget": 3, "n_initial": 1, "seed": 5, "resolution": 10},
        "env": {"id": "gbo_envs/DCMotor-v0"},
        "tuners": [{"name": "random"}],
        "thresholds": [1.1, {"label": "nominal", "gains": [0.85, 1.07], "paper_ratio": 1.71}],
    }
    data.update(changes)
    return data


def test_minimal_spec_defaults():
    study = parse_study(spec())
    assert study.name == "tiny" and study.title == "tiny"
    assert (study.batches, study.budget, study.n_initial, study.seed, study.resolution) == (2, 3, 1, 5, 10)
    assert study.env_kwargs == {}
    assert study.labels == ["random"]
    assert [t.label for t in study.thresholds] == ["phi=1.1", "nominal"]
    assert study.thresholds[0].ratio == 1.1 and study.thresholds[1].gains == (0.85, 1.07)
    assert study.count_initial and study.threshold_offset == 0
    assert study.with_batches(7).batches == 7


def test_cartesian_sweep_expands_with_label_template():
    study = parse_study(spec(tuners=[{"name": "guided-bo", "label": "gbo delta={delta} n={n_samples}",
                                      "params": {"eta2": 0.2}, "sweep": {"delta": [1.0, 2.0],
                                                                         "n_samples": [50, 100, 200]}}]))
    assert len(study.tuners) == 6
    assert study.labels[0] == "gbo delta=1 n=50" and study.labels[-1] == "gbo delta=2 n=200"
    entry = study.tuner("gbo delta=2 n=100")
    assert entry.params == {"eta2": 0.2, "delta": 2.0, "n_samples": 100}
    assert entry.sweep == {"delta": 2.0, "n_samples": 100}
    assert entry.group == "gbo delta={delta} n={n_samples}"


def test_dotted_sweep_keys_set_parameters_inside_a_table():
    """``sweep = {guidance.iterations.eta1 = [...]}`` (TOML's dotted keys) merges into the guidance table."""
    import tomllib

    raw = tomllib.loads("""
        [[tuners]]
        name = "guided-bo"
        label = "gbo n_ei={n_ei} N_G={period} eta3={eta3}"
        params = { twin = "linear", guidance = { iterations = { eta3 = inf, activation = "periodic" } } }
        sweep = [{ guidance.iterations = { n_ei = 5, period = 1 } }, { guidance.iterations.n_ei = 10, period = 3 }]
        [[tuners]]
        name = "guided-bo"
        label = "eta1"
        params = { guidance = { iterations = { n_ei = 3 } } }
        sweep = { guidance.iterations.eta1 = [1e-6, 3.0] }
    """)
    study = parse_study(spec(tuners=raw["tuners"]))
    assert study.labels == ["gbo n_ei=5 N_G=1 eta3=inf", "gbo n_ei=10 N_G=3 eta3=inf", "eta1 eta1=1e-06", "eta1 eta1=3"]
    first, second, low, high = study.tuners
    assert first.params == {"twin": "linear", "guidance": {"iterations": {"eta3": math.inf, "activation": "periodic",
                                                                          "n_ei": 5, "period": 1}}}
    assert first.sweep == {"n_ei": 5, "period": 1}
    assert second.params == {"twin": "linear", "period": 3,
                             "guidance": {"iterations": {"eta3": math.inf, "activation": "periodic", "n_ei": 10}}}
    assert low.params == {"guidance": {"iterations": {"n_ei": 3, "eta1": 1e-6}}} and low.sweep == {"eta1": 1e-6}
    assert [low.label, high.label] == ["eta1 eta1=1e-06", "eta1 eta1=3"]
    assert "eta1" not in raw["tuners"][1]["params"]["guidance"]["iterations"]  # the spec's table is not changed
    import agents

    assert agents.make(first.name, **first.params).guidance == agents.TwinIterations(
        eta3=math.inf, activation="periodic", n_ei=5, period=1)


def test_point_list_sweep_and_default_label():
    study = parse_study(spec(tuners=[{"name": "guided-bo", "sweep": [{"delta": 1.0}, {"delta": 3.0}]}]))
    assert study.labels == ["guided-bo delta=1", "guided-bo delta=3"]
    assert study.tuners[1].params == {"delta": 3.0}


@pytest.mark.parametrize("changes, message", [
    ({"study": {"batches": 0, "budget": 3}}, "[study] batches: expected an integer >= 1, got 0"),
    ({"study": {"batches": 2}}, "[study] budget: expected an integer >= 1, got None"),
    ({"study": {"batches": 2, "budget": 3, "bugdet": 4}}, "unknown key(s) ['bugdet']; allowed keys: ['name'"),
    ({"env": {}}, "[env] id: expected an env id string"),
    ({"tuners": []}, "tuners: expected at least one [[tuners]]"),
    ({"tuners": [{"label": "x"}]}, "tuners[0] name: expected a tuner registry name"),
    ({"tuners": [{"name": "bo"}, {"name": "bo"}]}, "labels must be unique, repeated: ['bo']"),
    ({"tuners": [{"name": "bo", "sweep": {"eta1": []}}]}, "tuners[0] sweep eta1: expected a non-empty list"),
    ({"tuners": [{"name": "bo", "label": "{nope}", "sweep": {"eta1": [1]}}]}, "placeholder 'nope'"),
    ({"thresholds": [{"ratio": 1.1, "gains": [1, 2]}]}, "give exactly one of 'ratio'"),
    ({"thresholds": [{"ratio": -1}]}, "thresholds[0] ratio: expected a number > 0"),
    ({"report": {"bands": "yes"}}, "[report] bands: expected true or false"),
    ({"report": {"surface_tuners": ["nope"]}}, "[report] surface_tuners: expected a list of tuner labels"),
    ({"analysis": {"count_initial": 1}}, "[analysis] count_initial: expected true or false"),
    ({"paper": {"thresholds": [{"tuner": "BO", "threshold": "phi=1.1", "mean": 3}]}},
     "[paper] thresholds[0] tuner: expected one of the tuner labels ['random']"),
    ({"paper": {"metrics": [{"tuner": "random", "metric": "speed", "value": 1}]}},
     "[paper] metrics[0] metric: expected one of ('final_ratio'"),
    ({"surprise": 1}, "top level: unknown key(s) ['surprise']"),
])
def test_invalid_specs_name_the_key(changes, message):
    with pytest.raises(StudySpecError) as info:
        parse_study(spec(**changes), name="bad")
    assert message in str(info.value)
    assert str(info.value).startswith("bad: ")


def test_threshold_from_gains_is_the_controllers_ratio():
    study = parse_study(spec())
    env = gym.make("gbo_envs/DCMotor-v0")
    optimum = 0.25
    cost = env.unwrapped.evaluate(np.array([[0.85, 1.07]]), experiment_index=0)[1][0]
    assert study.thresholds[1].resolve(env, optimum) == pytest.approx(cost / optimum)
    assert study.thresholds[0].resolve(env, optimum) == 1.1


def test_shipped_studies_load_and_are_package_data():
    assert set(PAPER_STUDIES) <= set(shipped_studies())
    for name in PAPER_STUDIES:
        study = load_study(name)
        assert study.path == STUDIES_DIR / f"{name}.toml"
        assert study.text and study.batches >= 1
    assert len(load_study("twin_fidelity").tuners) == 19
    assert load_study("eta1_sweep").labels[1:] == [f"guided BO eta1={v}" for v in
                                                    ("1e-06", "1", "2", "3", "5", "8", "20")]
    linear = load_study("linear_motor")
    assert linear.env_id == "gbo_envs/LinearMotor-v0" and linear.threshold_offset == 1
    performance = load_study("performance")
    assert (performance.batches, performance.budget, performance.n_initial) == (100, 35, 1)


def test_shipped_studies_pin_the_paper_guidance_in_the_current_spelling():
    """Every tuner of every shipped study is built without the FutureWarning of ``GuidedBO``'s former keywords;
    the paper studies pin the twin iterations (their parameters in ``TwinIterations``) and the linear twin."""
    import importlib
    import warnings

    import agents
    from evaluation.study_runner import resolve_params

    for name in shipped_studies():
        study = load_study(name)
        for module in study.imports:  # the tuners a study defines in its own modules (evaluation/study_tuners.py)
            importlib.import_module(module)
        for entry in study.tuners:
            if entry.name == "rl":
                continue  # stable-baselines3 is an extra
            with warnings.catch_warnings():
                warnings.simplefilter("error", FutureWarning)
                tuner = agents.make(entry.name, **resolve_params(entry, study.n_initial))
            if name in PAPER_STUDIES and entry.name == "guided-bo":
                assert isinstance(tuner.guidance, agents.TwinIterations) and tuner.twin == "linear", entry.label
    sweep = load_study("eta1_sweep")
    assert [agents.make("guided-bo", **e.params).guidance.eta1 for e in sweep.tuners[1:]] == [
        1e-6, 1.0, 2.0, 3.0, 5.0, 8.0, 20.0]
    fidelity = load_study("twin_fidelity").tuner("low-fidelity n_EI=10 N_G=3")
    assert agents.make("guided-bo", **fidelity.params).guidance == agents.TwinIterations(
        activation="periodic", eta3=math.inf, max_twin_iterations=50, n_ei=10, period=3)


def test_paths_names_and_yaml(tmp_path):
    assert resolve_study_path("smoke") == STUDIES_DIR / "smoke.toml"
    with pytest.raises(StudySpecError, match="shipped studies: .*smoke"):
        resolve_study_path("no-such-study")
    (tmp_path / "bad.toml").write_text("[study\n")
    with pytest.raises(StudySpecError, match="cannot parse"):
        load_study(tmp_path / "bad.toml")
    (tmp_path / "mine.yaml").write_text(
        "study: {batches: 1, budget: 2}\nenv: {id: gbo_envs/DCMotor-v0}\ntuners: [{name: random}]\n")
    study = load_study(tmp_path / "mine.yaml")
    assert study.name == "mine" and study.budget == 2


def test_slugify():
    assert slugify("guided BO eta1=3") == "guided-BO-eta1-3"
    assert slugify("n_EI=5 N_G=1") == "n_EI-5-N_G-1"
    assert slugify("///") == "tuner"
