"""The twin's HTML report as a reader meets it: words not Python lists, headers with units, numbers in fixed point,
text that wraps, one noise-floor figure, and the input drawn against a fitted saturation limit."""

from __future__ import annotations

from html.parser import HTMLParser
from types import SimpleNamespace

import numpy as np
import pytest

from agents.html_page import PAGE_STYLE
from agents.twin.ladder_text import advice, number, pairs_text, params_text
from agents.twin.records import Batch
from agents.twin.report import saturation_figure, write_report
from agents.twin.workbench import GreyBoxTwin, residuals
from gbo_envs.lazy_pyplot import pyplot
from tests.support import loop_records

UNITS = {"y": "rad/s", "u": "V"}


class Tables(HTMLParser):
    """Every table of a page: its attributes, its header cells and its rows of cell texts."""

    def __init__(self):
        super().__init__()
        self.tables, self._cell, self._in = [], None, None

    def handle_starttag(self, tag, attrs):
        if tag == "table":
            self.tables.append({"attrs": dict(attrs), "head": [], "rows": []})
        elif tag == "tr" and self.tables:
            self.tables[-1]["rows"].append([])
        elif tag in ("td", "th"):
            self._cell, self._in = "", tag

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            table = self.tables[-1]
            (table["head"] if self._in == "th" else table["rows"][-1]).append(self._cell)
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data


@pytest.fixture(scope="module")
def saturated():
    """Two DCMotor-v0 records whose commands pass a 150 V drive limit, and a twin with the limit fitted."""
    records = loop_records({"saturation": {"limit": 150.0}}, gains=np.array([[0.9, 1.5], [0.4, 1.0]]), duration=0.5,
                           start_index=1)
    data = Batch.from_records(records)
    return data, GreyBoxTwin().fit(data).greybox_, GreyBoxTwin(effects=["saturation"]).fit(data).greybox_


def _diagnosis(fit, sat):
    candidates = [
        {"effect": "saturation", "kind": "effect", "rmse": 0.0855, "train_rmse": 0.0844, "delta_bic": -12776.8,
         "params": {"limit": sat.effect_params["saturation"]["limit"]}, "verdict": "selected",
         "intervals": {"limit": {"value": 150.0, "unit": "input units"}}, "evidence": "command exceeds 150 V"},
        {"effect": "pole_pair", "kind": "order", "rmse": 1.9, "train_rmse": 1.8, "delta_bic": -336.4,
         "params": {"frequency": 66.7, "damping": 0.36}, "verdict": "passes",
         "intervals": {"frequency": {"value": 66.7, "unit": "rad/s"}, "damping": {"value": 0.36, "unit": "1"}},
         "evidence": "residual rings"},
        {"effect": "dead_zone", "kind": "effect", "rmse": 2.07, "train_rmse": 1.2, "delta_bic": 7.6, "params": {},
         "verdict": "not fitted", "evidence": "not fitted",
         "note": "the input never crosses zero and no experiment shows its rest: " * 4}]
    return SimpleNamespace(current=fit, noise_rmse=0.09285, noise_label="noise floor (not a lower bound)",
                           best="saturation", candidates=candidates, validation="held-out: 2-fold", unobservable=[],
                           indistinguishable=[["zero", "pole_pair"], ["coulomb_friction", "stiction"]],
                           suggested_experiment="a wider range of inputs separates zero from pole_pair",
                           fits={"saturation": sat},
                           not_tried="not fitted: input_map, output_map (saturation is selected and explains 99.5 %)")


def test_the_report_speaks_in_words_units_and_fixed_point(saturated, tmp_path):
    data, fit, sat = saturated
    diagnosis = _diagnosis(fit, sat)
    rungs = [{"model": "linear(2p0z)", "added": None, "rmse": 1.235, "heldout_rmse": 2.077, "fit_percent": 93.24,
              "params": {}, "text": "linear"},
             {"model": "linear(2p0z)+saturation", "added": "saturation", "rmse": 0.0844, "heldout_rmse": 0.0856,
              "fit_percent": 99.5, "params": {"saturation": {"limit": 159.935}}, "text": "+ saturation"}]
    last = SimpleNamespace(**{**vars(diagnosis), "current": sat, "best": None, "indistinguishable": []})
    path = write_report(tmp_path, data, rungs, [diagnosis, last], [residuals(data, fit), residuals(data, sat)],
                        source="rig.csv", y_unit="rad/s", u_unit="V")
    page = path.read_text()
    assert "Indistinguishable on this data: zero and pole pair; coulomb friction and stiction. A wider" in page
    assert "<p>Not fitted: input_map, output_map (saturation is selected and explains 99.5 %).</p>" in page
    assert "[[" not in page and "['" not in page
    parser = Tables()
    parser.feed(page)
    ladder, ranking = parser.tables[0], parser.tables[1]
    assert ladder["head"] == ["model", "effect added", "RMSE of the fit (rad/s)", "held-out RMSE (rad/s)", "fit (%)",
                              "effect parameters"]
    assert ranking["head"] == ["effect", "verdict", "held-out RMSE (rad/s)", "RMSE of the fit (rad/s)", "delta BIC (-)",
                               "fitted parameters", "evidence", "note"]
    assert ranking["rows"][1][4] == "-12776.8" and ranking["rows"][1][5].startswith("limit = 1")
    assert ranking["rows"][1][5].endswith(" V") and ranking["rows"][1][1] == "selected"
    assert ranking["rows"][2][5] == "frequency = 66.7 rad/s, damping = 0.36"
    assert "order: the candidates that pass every rule first" in page
    assert ladder["rows"][2][5] == "saturation: limit = 159.9 V"
    cells = [cell for table in parser.tables for row in table["rows"] for cell in row]
    assert not [cell for cell in cells if "e+" in cell or "e-0" in cell]
    assert ranking["attrs"].get("class") == "wrap" and ladder["attrs"].get("class") == "wrap"
    assert "table.wrap{width:100%}" in PAGE_STYLE and "table.wrap td{max-width:none" in PAGE_STYLE
    assert "0.0929" in page and "0.09285" not in page  # the noise floor, as the advice gives it
    assert "0.0929" in advice(last, ["saturation"], units=UNITS) or "noise" not in advice(last, ["saturation"])
    assert "Input against the fitted saturation limit" in page


def test_the_input_is_drawn_against_the_fitted_limit_with_units(saturated):
    data, fit, sat = saturated
    limit = sat.effect_params["saturation"]["limit"]
    ax = saturation_figure(data, sat, u_unit="V").axes[0]
    assert ax.get_xlabel() == "time since step t (s)" and ax.get_ylabel() == "commanded input u (V)"
    levels = sorted({line.get_ydata()[0] for line in ax.get_lines() if line.get_linestyle() == "--"})
    assert levels == pytest.approx([limit])  # every command is positive: the upper limit only
    low, high = ax.get_ylim()
    assert low <= data.u[data.mask].min() and high >= max(limit, data.u[data.mask].max()) and low > 0
    assert sum(line.get_label().startswith("u, experiment") for line in ax.get_lines()) == 2
    pyplot().close(ax.figure)
    with pytest.raises(ValueError, match="fit: a model with the saturation effect"):
        saturation_figure(data, fit)


def test_numbers_parameters_and_pairs_read_as_text():
    assert number(-12776.8, 5) == "-12777" and number(0.09285) == "0.0929" and number(1.2e-5) == "0.000012"
    assert number(float("nan")) == "n/a" and number(3) == "3"
    assert params_text("cogging", {"period": 82.39}, UNITS) == "period = 82.39 rad"
    assert params_text("zero", {"time_constant": -0.0194}, intervals={"time_constant": {"unit": "s"}}) == \
        "time constant = -0.0194 s"
    assert params_text("saturation", {"limit": 159.935}) == "limit = 159.9 input units"
    assert pairs_text([["zero", "pole_pair"]]) == "zero and pole pair"
