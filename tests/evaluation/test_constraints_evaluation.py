"""Constraints in the evaluation: gbo tune --constraints, study files, feasible-only curves, leaderboard violations."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import gbo_envs  # noqa: F401
from evaluation.cli import main
from evaluation.curves import curves_from_results
from evaluation.leaderboard import Leaderboard, PlantTarget, leaderboard_markdown
from evaluation.study import StudySpecError, parse_study
from evaluation.suite import load_suite

LIMITS = {"overshoot_pct": 2.0, "peak_u": 140.0}


def _spec(**env) -> dict:
    return {"study": {"name": "tiny", "batches": 1, "budget": 3, "resolution": 10},
            "env": {"id": "gbo_envs/DCMotor-v0", **env}, "tuners": [{"name": "random"}], "thresholds": [1.1]}


def test_gbo_tune_takes_constraints_and_reports_the_violations(tmp_path, capsys):
    db = str(tmp_path / "runs.sqlite")
    status = main(["tune", "--budget", "3", "--db", db, "--quiet", "--constraints", '{"peak_u": 100.0}'])
    out = capsys.readouterr().out
    assert status == 0 and "3 broke a constraint" in out and "best measured" not in out


def test_gbo_tune_refuses_an_unknown_constraint_naming_it(tmp_path, capsys):
    status = main(["tune", "--budget", "3", "--db", str(tmp_path / "r.sqlite"), "--constraints", '{"amps": 7}'])
    err = capsys.readouterr().err
    assert status == 2 and "--constraints" in err and "'amps'" in err and "peak_u" in err


def test_a_study_states_the_constraints_of_its_env_and_refuses_bad_ones():
    study = parse_study(_spec(constraints=LIMITS))
    assert study.env_kwargs["constraints"] == LIMITS
    with pytest.raises(StudySpecError, match="constraints.*'amps'"):
        parse_study(_spec(constraints={"amps": 7.0}))
    with pytest.raises(StudySpecError, match="twice"):
        parse_study(_spec(constraints=LIMITS, kwargs={"constraints": LIMITS}))


def test_the_suite_has_a_constrained_plant():
    plants = {plant.label: plant for plant in load_suite("standard").plants}
    assert plants["DC+limits"].env_kwargs["constraints"] == LIMITS


def _frame(feasible, true_cost, constrained=True):
    rows = []
    for k, (ok, cost) in enumerate(zip(feasible, true_cost)):
        row = {"source": "plant", "plant": "P", "tuner": "t", "batch": 0, "seed": 0, "experiment": k + 1,
               "cost": cost, "true_cost": cost, "feasible": ok}
        if constrained:
            row["constraint_peak_u"] = -1.0 if ok else 1.0
        rows.append(row)
    return pd.DataFrame(rows)


def test_on_a_constrained_plant_only_feasible_experiments_count_towards_the_best():
    optima = {"P": np.ones(4)}
    curve = curves_from_results(_frame([False, True, False, True], [1.0, 1.5, 1.1, 1.2]), optima).iloc[0]
    assert curve["curve"] == [np.inf, 1.5, 1.5, 1.2] and curve["violations"] == 2
    free = curves_from_results(_frame([False, True, False, True], [1.0, 1.5, 1.1, 1.2], constrained=False),
                               optima).iloc[0]
    assert free["curve"] == [1.0, 1.0, 1.0, 1.0] and np.isnan(free["violations"])


def test_the_leaderboard_shows_the_violations_per_run():
    curves = pd.DataFrame([{"tuner": t, "plant": p, "seed": s, "curve": np.array(c, float),
                            "instant": np.array(c, float), "violations": v}
                           for t, p, s, c, v in [("bo", "C", 0, [1.2, 1.0], 2), ("bo", "C", 1, [1.0, 1.0], 0),
                                                 ("bo", "F", 0, [1.0, 1.0], np.nan)]])
    board = Leaderboard(n_bootstrap=20).fit(curves, [PlantTarget("C", 1.05, 2), PlantTarget("F", 1.05, 2)])
    table = board.table_.set_index("plant")
    assert table.loc["C", "violations"] == 1.0 and np.isnan(table.loc["F", "violations"])
    lines = "\n".join(leaderboard_markdown(board, "t", [], {}, []))
    constrained, free = lines.split("### F")
    assert "| violations per run |" in constrained and "| 1.0 |" in constrained
    assert "| violations per run |" not in free
