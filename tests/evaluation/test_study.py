"""Study specs: parsing, sweeps, validation messages, shipped studies."""

from __future__ import annotations

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
    study = parse_study(spec(tuners=[{"name": "guided-bo", "label": "gbo n_ei={n_ei} N_G={period}",
                                      "params": {"eta3": 0.2}, "sweep": {"n_ei": [5, 10], "period": [1, 3, 5]}}]))
    assert len(study.tuners) == 6
    assert study.labels[0] == "gbo n_ei=5 N_G=1" and study.labels[-1] == "gbo n_ei=10 N_G=5"
    entry = study.tuner("gbo n_ei=10 N_G=3")
    assert entry.params == {"eta3": 0.2, "n_ei": 10, "period": 3}
    assert entry.sweep == {"n_ei": 10, "period": 3}
    assert entry.group == "gbo n_ei={n_ei} N_G={period}"


def test_point_list_sweep_and_default_label():
    study = parse_study(spec(tuners=[{"name": "guided-bo", "sweep": [{"eta1": 1e-6}, {"eta1": 3.0}]}]))
    assert study.labels == ["guided-bo eta1=1e-06", "guided-bo eta1=3"]
    assert study.tuners[1].params == {"eta1": 3.0}


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
