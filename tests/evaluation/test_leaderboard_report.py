"""The leaderboard as a newcomer reads it: intervals in range, the ranking rule, their own tuner, every curve seen."""

from __future__ import annotations

from html.parser import HTMLParser

import numpy as np
import pandas as pd

from evaluation.leaderboard import RANKING_RULE, Leaderboard, PlantTarget, mean_interval, write_leaderboard


def curves(rows):
    return pd.DataFrame([{"tuner": t, "plant": p, "seed": s, "curve": np.asarray(c, float),
                          "instant": np.asarray(c, float)} for t, p, s, c in rows])


def reach(at: int, budget: int) -> list[float]:
    """A curve that reaches ratio 1.0 at experiment ``at`` (1-based; beyond the budget: never)."""
    return [1.5 if k + 1 < at else 1.0 for k in range(budget)]


class Rows(HTMLParser):
    """The text of every table row and its class."""

    def __init__(self):
        super().__init__()
        self.rows, self._row = [], None

    def handle_starttag(self, tag, attrs):
        if tag == "tr":
            self._row = [dict(attrs).get("class", ""), ""]

    def handle_endtag(self, tag):
        if tag == "tr" and self._row is not None:
            self.rows.append(tuple(self._row))
            self._row = None

    def handle_data(self, data):
        if self._row is not None:
            self._row[1] += data + "|"


def test_the_interval_of_a_count_stays_within_the_counts():
    counts = [1, 1, 41, 41, 1, 52]  # a Student-t interval of these reaches below zero
    mean, low, high = mean_interval(counts)
    assert 1 <= low <= mean <= high <= 52
    assert mean_interval([5, 5, 5]) == (5.0, 5.0, 5.0)
    assert mean_interval(counts, seed=3) == mean_interval(counts, seed=3)


def test_the_table_states_the_interval_method_and_its_low_end_is_not_negative(tmp_path):
    plants = [PlantTarget("A", 1.05, budget=40)]
    rows = [("bo", "A", s, reach(at, 40)) for s, at in enumerate([1, 1, 41])]
    board = Leaderboard(n_bootstrap=500).fit(curves(rows), plants)
    row = board.table_.iloc[0]
    assert row["ci_low"] >= 1 and row["ci_high"] <= 41
    md = write_leaderboard(board, tmp_path, title="T")["md"].read_text()
    assert "bootstrap percentile interval (`scipy.stats.bootstrap`, 500 resamples of the seeds, seed 0" in md
    assert "[-" not in md


def test_a_tuner_that_solves_nothing_ranks_below_one_that_solves_some_and_the_rule_is_printed(tmp_path):
    plants = [PlantTarget("A", 1.05, budget=4), PlantTarget("B", 1.05, budget=4)]
    rows = [("bo", "A", s, reach(9, 4)) for s in range(2)] + [("never", "A", s, reach(9, 4)) for s in range(2)]
    rows += [("bo", "B", s, reach(1, 4)) for s in range(2)]
    rows += [("some", "B", 0, reach(2, 4)), ("some", "B", 1, reach(9, 4))]
    board = Leaderboard(n_bootstrap=50).fit(curves(rows), plants)
    ranked = board.aggregate_.set_index("tuner")
    assert ranked.loc["never", "solved"] == 0.0 and ranked.loc["some", "solved"] == 0.5
    assert ranked.loc["never", "geo_mean_vs_reference"] < ranked.loc["some", "geo_mean_vs_reference"]
    assert list(board.aggregate_["tuner"]) == ["bo", "some", "never"]  # bo and some solve 50 %
    md = write_leaderboard(board, tmp_path, title="T")["md"].read_text()
    assert RANKING_RULE.replace("the reference", "`bo`") in md


def test_the_researchers_tuner_is_in_bold_and_its_html_rows_are_highlighted(tmp_path):
    plants = [PlantTarget("A", 1.05, budget=4), PlantTarget("B", 1.05, budget=4)]
    rows = [(t, p, s, reach(at, 4)) for t, at in (("bo", 2), ("me", 1)) for p in "AB" for s in range(2)]
    board = Leaderboard(n_bootstrap=50).fit(curves(rows), plants)
    paths = write_leaderboard(board, tmp_path, title="T", highlight="me")
    md = paths["md"].read_text()
    assert md.count("| **me** ◀ yours |") == 3 and "| **bo**" not in md  # the ranking and the two plants
    parser = Rows()
    parser.feed(paths["html"].read_text())
    marked = [text for cls, text in parser.rows if cls == "highlight"]
    assert len(marked) == 3 and all("me|" in text and "bo|" not in text for text in marked)
    assert "tr.highlight td{" in paths["html"].read_text()


def test_curves_that_coincide_stay_apart_and_the_legend_says_so():
    plants = [PlantTarget("A", 1.05, budget=6)]
    rows = [(t, "A", s, reach(at, 6)) for t in ("bo", "random", "grid") for s, at in enumerate([2, 4])]
    rows += [("me", "A", s, reach(1, 6)) for s in range(2)]
    board = Leaderboard(n_bootstrap=50).fit(curves(rows), plants, order=["me", "bo", "random", "grid"])
    ax = board.plot(plant="A", highlight="me").axes[0]
    lines = {line.get_label(): line for line in ax.get_lines()}
    assert set(lines) == {"me", "bo", "random (same as bo)", "grid (same as bo, random)"}
    styles = {(line.get_linestyle(), line.get_marker()) for line in lines.values()}
    assert len(styles) == 4
    legend = [text.get_text() for text in ax.get_legend().get_texts()]
    assert "grid (same as bo, random)" in legend


def test_each_panel_of_the_plant_grid_names_its_own_coinciding_curves():
    from evaluation.leaderboard import _plant_grid

    plants = [PlantTarget("A", 1.05, budget=6), PlantTarget("B", 1.05, budget=6)]
    rows = [(t, "A", s, reach(at, 6)) for t in ("bo", "me") for s, at in enumerate([2, 4])]  # equal on A
    rows += [(t, "B", s, reach(at, 6)) for t, at in (("bo", 2), ("me", 1)) for s in range(2)]
    board = Leaderboard(n_bootstrap=50).fit(curves(rows), plants, order=["me", "bo"])
    fig = _plant_grid(board, "me")
    a, b = fig.axes[:2]
    assert [t.get_text() for t in a.texts] == ["bo (same as me)"] and not b.texts
    assert [t.get_text() for t in b.get_legend().get_texts()] == ["me", "bo"]  # the shared legend: names only
