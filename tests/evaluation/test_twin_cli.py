"""``gbo twin``: arguments, exit codes, stdout and output files of compare, resid, diagnose and report.

Whether the workbench finds the hidden effect, and with which parameters, is
tested in ``tests/agents/twin/test_workbench.py``; here the command line: three
1.5 s experiments (indices 4, 5, 6: numbered 5, 6, 7 in the CSV and the output)
with a hidden saturation, long enough for the saturated model to beat the linear
one. ``diagnose`` and ``report`` fit every catalogue effect, so they are marked slow.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from agents.twin.candidates import ORDER_CANDIDATES
from agents.twin.csvio import write_csv
from agents.twin.ranking import ORDER_RULE
from agents.twin.static_map import MAP_NAMES
from evaluation.cli import main
from gbo_envs.physics import EFFECT_NAMES
from tests.support import loop_records


@pytest.fixture(scope="module")
def csv_path(tmp_path_factory):
    gains = np.array([[0.3, 1.0], [0.9, 1.2], [1.05, 2.0]])
    records = loop_records({"saturation": {"limit": 150.0}}, gains=gains, duration=1.5, start_index=4)
    return write_csv(records, tmp_path_factory.mktemp("twin") / "sat.csv")


@pytest.mark.slow
def test_diagnose_json_is_exactly_one_object(csv_path, capsys):
    assert main(["twin", "diagnose", str(csv_path), "--json", "--folds", "2"]) == 0
    out = capsys.readouterr().out
    payload = json.loads(out)  # the whole stdout is one JSON object
    assert set(payload) >= {"model", "rmse", "fit_percent", "noise_rmse", "best", "candidates"}
    assert payload["model"] == "linear(2p0z)"
    assert isinstance(payload["rmse"], float) and isinstance(payload["fit_percent"], float)
    assert isinstance(payload["noise_rmse"], float)
    # every catalogue effect ranked; each general structure (the linear part's orders, the maps) ranked or named
    # as not fitted (the selected saturation explains nearly all of the residual)
    ranked = {c["effect"] for c in payload["candidates"]}
    general = set(ORDER_CANDIDATES) | set(MAP_NAMES)
    assert ranked - general == set(EFFECT_NAMES)
    not_tried = payload["not_tried"].removeprefix("not fitted: ").split(" (")[0].split(", ") if payload["not_tried"] \
        else []
    assert set(not_tried) | (ranked & general) == general and not set(not_tried) & ranked
    first = payload["candidates"][0]
    assert set(first) >= {"effect", "rmse", "delta_bic", "params", "evidence"}
    assert payload["best"] in (None, first["effect"])
    assert [c["delta_bic"] for c in payload["candidates"]] == sorted(c["delta_bic"] for c in payload["candidates"])
    assert payload["best"] == "saturation" and payload["best_step"]["added"] == "saturation"
    # backlash (a play in the drive) is excited wherever the command turns back, as in this PI step
    assert {u["effect"] for u in payload["unobservable"]} >= {"coulomb_friction", "stiction", "offset"}
    assert ["coulomb_friction", "stiction"] in payload["indistinguishable"]
    assert payload["next"].startswith("next: add saturation")
    assert "not a lower bound" in payload["noise_floor"]["label"]


@pytest.mark.slow
def test_diagnose_text_says_what_it_found_and_what_to_do_next(csv_path, capsys):
    assert main(["twin", "diagnose", str(csv_path), "--folds", "2", "--y-unit", "rad/s", "--u-unit", "V"]) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert captured.err == ""  # the bar only draws on a terminal
    assert "noise floor (white-noise estimate" in out
    best = next(line for line in out.splitlines() if line.startswith("best: "))
    assert best.startswith("best: + saturation (limit ") and " V, 95 % CI [" in best and " rad/s (-" in best
    assert "fit " in best and " % → " in best
    assert "not observable in this data:" in out and "coulomb_friction is not observable here (no speed reversal" in out
    # the ranking says what orders it, and its order follows the printed verdict, then delta BIC
    lines = out.splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("ranking ("))
    assert lines[head].endswith(f"{ORDER_RULE}:") and lines[head + 2].split() == ["(rad/s)", "(-)"]
    rows = lines[head + 3:next(i for i, line in enumerate(lines) if line.startswith("best: "))]
    assert len(rows) >= len(EFFECT_NAMES)
    header = lines[head + 1]
    verdict_at, rmse_at, bic_end = header.index("verdict"), header.index("held-out RMSE") - 1, header.index(
        "delta BIC") + len("delta BIC")
    verdicts = [row[verdict_at:rmse_at].strip() for row in rows]
    assert verdicts[0] == "selected" and rows[0].split()[0] == "saturation"
    passing = sum(v in ("selected", "passes") for v in verdicts)
    assert all(v not in ("selected", "passes") for v in verdicts[passing:])
    bics = [float(row[bic_end - 10:bic_end]) for row in rows[passing:]]
    assert bics == sorted(bics)  # after the candidates that pass, the order is the printed delta BIC's
    assert out.splitlines()[-1] == f"next: add saturation, then look for a further effect: `gbo twin diagnose " \
                                   f"{csv_path} --effects saturation`"


def test_compare_with_effects_and_plots(csv_path, tmp_path, capsys):
    assert main(["twin", "compare", str(csv_path), "--json"]) == 0
    linear = json.loads(capsys.readouterr().out)
    assert main(["twin", "compare", str(csv_path), "--effects", "saturation", "--json", "--out", str(tmp_path)]) == 0
    sat = json.loads(capsys.readouterr().out)
    assert [e["experiment"] for e in sat["experiments"]] == [5, 6, 7]  # counted from 1, as in the CSV
    assert sat["rmse"] < 0.5 * linear["rmse"] and sat["fit_percent"] > linear["fit_percent"]
    assert sat["model"] == "linear(2p0z)+saturation"
    assert (tmp_path / "compare.png").stat().st_size > 1000
    assert sat["plots"] == [str(tmp_path / "compare.png")]


def test_compare_writes_its_plot_by_default_and_says_where(csv_path, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["twin", "compare", str(csv_path), "--y-unit", "rad/s"]) == 0
    captured = capsys.readouterr()
    plot = tmp_path / "out" / "twin" / csv_path.stem / "compare.png"
    assert plot.stat().st_size > 1000
    lines = captured.out.splitlines()
    assert lines[-1] == f"plots: {plot.relative_to(tmp_path)}" and " rad/s" in lines[0]
    assert [int(line.split()[0]) for line in lines[2:-1]] == [5, 6, 7]  # under the header "experiment fit % RMSE"
    assert captured.err == ""  # not a terminal: no bar


def test_resid_reports_whiteness_and_worst_segments(csv_path, tmp_path, capsys):
    assert main(["twin", "resid", str(csv_path), "--json", "--out", str(tmp_path)]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["white"] is False and len(payload["worst"]) == 5
    assert set(payload["bins"]) == {"time", "experiment", "input", "output", "velocity_sign"}
    assert (tmp_path / "residuals.png").exists()
    assert main(["twin", "resid", str(csv_path)]) == 0
    assert "worst segments" in capsys.readouterr().out


@pytest.mark.slow
def test_report_is_one_self_contained_page(csv_path, tmp_path, capsys):
    assert main(["twin", "report", str(csv_path), "--out", str(tmp_path), "--max-steps", "1"]) == 0
    out = capsys.readouterr().out
    assert "  + saturation (limit " in out and "not observable in this data:" in out
    assert out.splitlines()[-2].startswith(("next: ", "stop"))
    page = (tmp_path / "index.html").read_text()
    assert page.count("data:image/png;base64,") >= 4
    assert "error ladder" in page
    assert "+ saturation (limit " in page and "Not observable in this data" in page  # the ladder in words
    assert "not a lower bound" in page
    assert "src=\"http" not in page
    assert list(tmp_path.iterdir()) == [tmp_path / "index.html"]


def test_bad_csv_exits_with_a_message(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("experiment,t,r,u,y\n0,0,1,2,3\n0,0.1,1,x,3\n0,0.2,1,2,3\n")
    assert main(["twin", "diagnose", str(bad), "--json"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert "row 3, column 'u'" in captured.err
