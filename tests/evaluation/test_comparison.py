"""Comparison tables of studies of several plants (evaluation.comparison), and the committed reports they wrote."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from evaluation.comparison import comparison_lines, effects_column
from evaluation.curves import read_curves
from evaluation.references import suite_optima
from evaluation.study import load_study, parse_study
from evaluation.study_runner import plan_batches
from tests.support import REPO_ROOT

ENV = "gbo_envs/DCMotor-v0"


def study(tuners, table, plants=None, **report):
    return parse_study({"study": {"name": "t", "batches": 3, "budget": 4},
                        "plants": plants or [{"label": "DCMotor-v0", "id": ENV, "thresholds": [1.1, 1.05]}],
                        "tuners": [{"name": "random", "label": t} for t in tuners],
                        "report": {"table": table, **report}})


def curves(runs, budget=4):
    rows = []
    for (plant, tuner, seed), values in runs.items():
        curve, summary = (values if isinstance(values, tuple) else (values, {}))
        rows.append({"plant": plant, "tuner": tuner, "seed": seed, "budget": budget, "curve": curve,
                     "instant": None, "seconds": 2.0 * (tuner == "bo") + 1.0, "cpu_seconds": 2.0,
                     "plant_cpu_seconds": 0.5, "summary": json.dumps(summary), "source": "test"})
    return pd.DataFrame(rows)


OPTIMA = {"DCMotor-v0": np.ones(4), "DC+backlash": np.ones(4)}


def test_sections_compare_on_the_seeds_every_tuner_ran_and_count_misses_as_budget_plus_one():
    # bo reaches 1.05 at experiments 2 and 4; skopt at 3 and never (a miss, counted as budget + 1 = 5)
    runs = {("DCMotor-v0", "bo", 0): [1.2, 1.04, 1.0, 1.0], ("DCMotor-v0", "bo", 1): [1.5, 1.2, 1.08, 1.01],
            ("DCMotor-v0", "skopt", 0): [1.2, 1.2, 1.03, 1.0], ("DCMotor-v0", "skopt", 1): [1.5, 1.3, 1.2, 1.1],
            ("DCMotor-v0", "skopt", 2): [1.0, 1.0, 1.0, 1.0]}  # seed 2 has no bo run: left out
    spec = study(["bo", "skopt"], "sections", reference="bo", columns=["seconds"])
    lines, table = comparison_lines(spec, curves(runs), OPTIMA)
    table = table.set_index(["ratio", "tuner"])
    assert table.loc[(1.05, "bo"), ["seeds", "mean", "misses", "seconds"]].tolist() == [2, 3.0, 0, 3.0]
    assert table.loc[(1.05, "skopt"), ["mean", "misses", "vs_reference"]].tolist() == [4.0, 1, 4.0 / 3.0]
    assert table.loc[(1.1, "skopt"), "mean"] == 3.5  # reaches 1.1 at experiments 3 and 4
    # Student-t 95 % interval of (2, 4): 3 +- t(0.975, 1) * sqrt(2) / sqrt(2)
    assert table.loc[(1.05, "bo"), "ci_high"] == pytest.approx(3.0 + 12.7062047, rel=1e-6)
    assert "### DCMotor-v0, ratio 1.05 (2 seeds)" in lines
    assert "| skopt | 4.0 [-8.7, 16.7] (1) | 1.33 | 2 | 1.0 |" in lines
    assert "| bo | 3.0 [-9.7, 15.7] (0) | 1.00 | 2 | 3.0 |" in lines


def test_sections_take_a_tuner_with_fewer_seeds_on_those_it_shares_with_the_reference():
    bo = {0: [1.2, 1.04, 1.0, 1.0], 1: [1.5, 1.2, 1.08, 1.01], 2: [1.0, 1.0, 1.0, 1.0]}
    runs = {("DCMotor-v0", "bo", s): c for s, c in bo.items()}
    runs.update({("DCMotor-v0", "guided-bo", 0): [1.2, 1.0, 1.0, 1.0], ("DCMotor-v0", "guided-bo", 1): [1.04] * 4})
    _, table = comparison_lines(study(["bo", "guided-bo"], "sections", reference="bo"), curves(runs), OPTIMA)
    table = table.set_index(["ratio", "tuner"])
    assert table.loc[(1.05, "bo"), ["seeds", "mean"]].tolist() == [3, 7.0 / 3.0]  # on all its seeds
    # guided-bo on seeds 0 (1.05 at experiment 2) and 1 (at 1), against bo on 0 and 1 (2, 4)
    assert table.loc[(1.05, "guided-bo"), ["seeds", "mean", "vs_reference"]].tolist() == [2, 1.5, 0.5]


def test_paired_rows_hold_the_seed_by_seed_difference_to_the_second_baseline():
    # reaching 1.05: bo at 3 and 4, guided-bo at 1 and 2, mf-bo at 2 and never (budget + 1 = 5)
    summary = {"cpu_per_experiment": 1.5, "twin_evaluations": 40, "fidelity": [0.0, 0.9]}
    runs = {("DCMotor-v0", "bo", 0): [1.2, 1.1, 1.0, 1.0], ("DCMotor-v0", "bo", 1): [1.5, 1.2, 1.08, 1.01],
            ("DCMotor-v0", "guided-bo", 0): [1.0, 1.0, 1.0, 1.0], ("DCMotor-v0", "guided-bo", 1): [1.2, 1.04, 1.0, 1.0],
            ("DCMotor-v0", "mf-bo", 0): ([1.2, 1.04, 1.0, 1.0], summary),
            ("DCMotor-v0", "mf-bo", 1): ([1.3, 1.2, 1.1, 1.1], summary)}
    spec = study(["bo", "guided-bo", "mf-bo"], "paired", ratio=["bo", "guided-bo"],
                 plants=[{"label": "DCMotor-v0", "id": ENV, "thresholds": [1.05]}], headers={"tuner": "mf-bo variant"},
                 columns=["paired:variant - guided-bo, paired", "cpu_per_experiment", "twin_evaluations", "fidelity"])
    lines, _ = comparison_lines(spec, curves(runs), OPTIMA)
    assert lines[0].startswith("| plant | ratio | seeds | mf-bo variant | variant: real experiments | bo | guided-bo |")
    assert "| DCMotor-v0 | 1.05 | 2 | mf-bo | 3.5 [-15.6, 22.6] (1 misses) | 3.5 [-2.9, 9.9] (0 misses) | " \
           "1.5 [-4.9, 7.9] (0 misses) | 1.00 | 2.33 | +2.0 [-10.7, +14.7] | 1.50 | 40.0 | 0.90 |" in lines


def test_versus_rows_beside_the_reference_with_the_twins_effects():
    guided = {"activations": 3, "effects": ["saturation"]}
    runs = {("DC+backlash", "bo", s): ([1.2, 1.2, 1.04, 1.0], {"activations": None, "effects": None}) for s in (0, 1)}
    runs.update({("DC+backlash", "guided-bo", 0): ([1.04] * 4, guided),
                 ("DC+backlash", "guided-bo", 1): ([1.2, 1.0, 1.0, 1.0], {"activations": 1, "effects": []})})
    spec = study(["bo", "guided-bo"], "versus", reference="bo",
                 columns=["seconds", "tuner_cpu", "activations", "effects"],
                 plants=[{"label": "DC+backlash", "id": ENV, "thresholds": [1.05]}])
    lines, _ = comparison_lines(spec, curves(runs), OPTIMA)
    assert lines[0] == ("| plant | threshold | variant | seeds | variant: real experiments | bo, same seeds | "
                        "variant / bo | s/run | tuner CPU s/run | activations | twin effects at the end (runs) |")
    assert lines[2] == ("| DC+backlash | ratio 1.05 | guided-bo | 2 | 1.5 [-4.9, 7.9] (0 misses) | "
                        "3.0 [3.0, 3.0] (0 misses) | 0.50 | 1.0 | 1.5 [1.5, 1.5] | 2.0 | saturation (1), linear (1) |")


def test_effects_column_counts_most_frequent_first_ties_as_first_seen():
    assert effects_column(["linear", "saturation", "saturation", "cogging"]) == \
        "saturation (2), linear (1), cogging (1)"


COMMITTED = ["guided_bo_ablation", "time_varying", "peers", "mf_bo", "effect_aware", "guided_bo_oracle",
             "discrimination", "beyond_catalogue"]


@pytest.mark.slow
@pytest.mark.parametrize("name", COMMITTED)
def test_the_committed_reports_are_what_the_engine_computes_from_the_committed_curves(name, study_tuners, tmp_path):
    spec = load_study(name)
    committed_folder = REPO_ROOT / "docs" / "reports" / name
    before = {p.name: p.read_bytes() for p in committed_folder.iterdir() if p.is_file()}
    folder = tmp_path / name  # a copy: the optimum cells it lacks are cached there, not in the tracked files
    shutil.copytree(committed_folder, folder)
    budgets = {}
    for task in plan_batches(spec):
        budgets[task.plant] = max(budgets.get(task.plant, 0), task.budget)
    optima = suite_optima(spec, budgets, cache=folder / "optima.json")
    runs = read_curves(folder / "curves.parquet")
    assert len(runs) == len(plan_batches(spec))  # every run the study plans is kept as a curve
    lines, _ = comparison_lines(spec, runs, optima, folder)  # folder/optima.json: the optimum cells too
    committed = [line for line in Path(folder / "report.md").read_text().splitlines()
                 if line.startswith(("|", "###"))]
    assert [line for line in lines if line.startswith(("|", "###"))] == committed
    assert {p.name: p.read_bytes() for p in committed_folder.iterdir() if p.is_file()} == before
