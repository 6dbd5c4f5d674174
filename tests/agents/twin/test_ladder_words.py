"""The error ladder in words and numbers: intervals of the added parameters, what the data cannot show,
the noise floor's label, the advice that ends a diagnosis, and experiment numbers counted from 1."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from agents.twin.csvio import read_csv, write_csv
from agents.twin.ladder_text import advice, format_interval, rung_text, unit_text
from agents.twin.noise_floor import NOISE_FLOOR_LABELS, noise_floor, noise_floor_method
from agents.twin.records import Batch
from agents.twin.uncertainty import parameter_intervals
from agents.twin.workbench import GreyBoxTwin, diagnose, error_ladder
from tests.support import loop_records

GAINS = np.array([[0.3, 1.0], [0.9, 1.2], [1.05, 2.0]])
LIMIT = 150.0
# the three experiments do not reverse the speed: friction and stiction are a constant load there
NO_REVERSAL = ["saturation", "coulomb_friction", "stiction"]


@pytest.fixture(scope="module")
def saturated():
    return Batch.from_records(loop_records({"saturation": {"limit": LIMIT}}, gains=GAINS, duration=1.5,
                                              start_index=4))


def test_experiment_numbers_count_from_one_in_the_csv_and_the_data(saturated, tmp_path):
    records = loop_records(None, gains=GAINS[:2], duration=0.3, start_index=0)
    path = write_csv(records, tmp_path / "d.csv")
    assert sorted(set(path.read_text().splitlines()[1:][i].split(",")[0] for i in (0, -1))) == ["1", "2"]
    back = read_csv(path)
    assert [r.index for r in back] == [0, 1]  # the 0-based index of the env survives the round trip
    assert Batch.from_records(back).numbers.tolist() == [1, 2]
    assert saturated.numbers.tolist() == [5, 6, 7] and saturated.index.tolist() == [0, 1, 2]
    assert saturated.subset([2]).numbers.tolist() == [7]


def test_interval_of_a_fitted_limit_covers_the_truth(saturated):
    fit = GreyBoxTwin(effects=["saturation"]).fit(saturated).greybox_
    ci = parameter_intervals(saturated, fit)["saturation.limit"]
    assert ci["low"] < LIMIT < ci["high"]
    assert 0 < ci["std"] < 1.0 and ci["high"] - ci["value"] == pytest.approx(ci["value"] - ci["low"])
    with pytest.raises(ValueError, match="level"):
        parameter_intervals(saturated, fit, level=1.5)


def test_noise_floor_says_what_it_is(saturated):
    assert noise_floor_method(saturated) == "second_differences"
    assert noise_floor(saturated) == pytest.approx(0.1, rel=0.3)  # the records' white sensor noise, rad/s
    for label in NOISE_FLOOR_LABELS.values():
        assert "lower bound" not in label or "not a lower bound" in label


@pytest.mark.slow
def test_diagnose_lists_what_the_data_cannot_show_and_the_ladder_in_numbers(saturated, capsys):
    result = diagnose(saturated, candidates=NO_REVERSAL, progress=True)
    assert "diagnose linear(2p0z)" in capsys.readouterr().err  # the bar, on stderr
    assert result.best == "saturation"
    blind = {u["effect"]: u for u in result.unobservable}
    assert set(blind) == {"coulomb_friction", "stiction"}
    assert all(u["reason"].startswith("no speed reversal") and u["experiment"] for u in blind.values())
    assert ["coulomb_friction", "stiction"] in result.indistinguishable  # the same constant load
    payload = result.to_dict()
    assert payload["unobservable"] == result.unobservable
    assert payload["noise_floor"]["label"] == NOISE_FLOOR_LABELS["second_differences"]

    rungs, diagnoses = error_ladder(saturated, max_steps=1, candidates=NO_REVERSAL, units={"y": "rad/s", "u": "V"})
    assert [r["added"] for r in rungs] == [None, "saturation"]
    first, step = rungs
    assert step["before"]["rmse"] == first["rmse"] and step["before"]["fit_percent"] == first["fit_percent"]
    assert step["rmse_fall_percent"] == pytest.approx(100 * (1 - step["rmse"] / first["rmse"]))
    assert step["rmse_factor"] == pytest.approx(first["rmse"] / step["rmse"]) and step["rmse_factor"] > 2
    limit = step["added_params"]["limit"]
    assert limit["unit"] == "input units" and limit["low"] < LIMIT < limit["high"]
    assert step["text"].startswith("+ saturation (limit ") and " V, 95 % CI [" in step["text"]
    assert f"RMSE {first['rmse']:.3g} → {step['rmse']:.3g} rad/s" in step["text"]
    assert f"fit {first['fit_percent']:.1f} % → {step['fit_percent']:.1f} %" in step["text"]
    same = diagnoses[0].step("saturation", {"y": "rad/s", "u": "V"})  # the rung of one diagnosis alone
    assert same["added_params"] == step["added_params"] and same["before"]["rmse"] == first["rmse"]
    assert same["text"].startswith("+ saturation (limit ")


def test_rung_text_states_both_errors_before_and_after():
    rung = {"model": "linear(2p0z)+coulomb_friction", "added": "coulomb_friction", "rmse": 0.025,
            "fit_percent": 98.0, "before": {"rmse": 0.41, "fit_percent": 71.0}, "rmse_factor": 16.4,
            "added_params": {"torque": {"value": 4.9, "std": 0.15, "low": 4.6, "high": 5.2, "unit": "input units"}}}
    text = rung_text(rung, {"y": "rad/s", "u": "Nm"})
    assert text == ("+ coulomb_friction (torque 4.90 ± 0.3 Nm, 95 % CI [4.60, 5.20]): RMSE 0.41 → 0.025 rad/s "
                    "(-94 %, 16.4×), fit 71.0 % → 98.0 %")
    assert rung_text({"model": "linear(2p0z)", "rmse": 0.41, "fit_percent": 71.0}) == \
        "linear(2p0z): RMSE 0.41 (units of y), fit 71.0 %"
    assert format_interval("step", {"value": 0.77, "std": None}, "rad/s") == "step 0.77 rad/s (grid fit, no interval)"
    assert unit_text("input units per speed unit", {"y": "rad", "u": "V"}, output="position") == "V/(rad/s)"
    assert unit_text("s", {"y": "rad/s"}) == "s" and unit_text("input units") == "input units"


def _diagnosis(best=None, rmse=1.0, noise=0.1, pairs=(), blind=(), variant=None):
    return SimpleNamespace(best=best, best_label=f"{best}:{variant}" if variant else best,
                           current=SimpleNamespace(rmse=rmse), noise_rmse=noise,
                           indistinguishable=list(pairs), suggested_experiment="a speed reversal separates them",
                           unobservable=[{"effect": e} for e in blind])


def test_advice_names_the_next_step():
    assert advice(_diagnosis("drift"), ["saturation"], "d.csv") == \
        "next: add drift, then look for a further effect: `gbo twin diagnose d.csv --effects saturation,drift`"
    assert "still improves" in advice(_diagnosis("drift"), ["saturation"], stopped_at_max=True)
    assert advice(_diagnosis("coulomb_friction", variant="smooth"), ["input_map"], "d.csv").endswith(
        "--effects input_map,coulomb_friction:smooth`")  # the command refits the variant the diagnosis chose
    assert advice(_diagnosis(rmse=0.09, noise=0.1), []).startswith("stop: the model is at the noise floor")
    assert "explain the data equally well" in advice(_diagnosis(pairs=[["a", "b"]]), [])
    text = advice(_diagnosis(blind=["offset"]), ["saturation"], "d.csv")
    assert text.startswith("stop adding catalogue effects") and "gbo twin resid d.csv --effects saturation" in text
    assert "cannot be seen in these data" in text
