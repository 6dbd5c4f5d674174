"""The workbench's figures and page: measured data above the model, units on the axes, a page for phones."""

from __future__ import annotations

import base64

import numpy as np
import pytest

from agents.html_page import image_tag, page
from agents.twin.records import Batch
from agents.twin.report import compare_figure, ladder_figure
from agents.twin.workbench import GreyBoxTwin
from gbo_envs.lazy_pyplot import pyplot
from tests.support import loop_records


@pytest.fixture(scope="module")
def data_and_fit():
    records = loop_records(gains=np.array([[0.4, 1.0], [0.9, 1.5]]), duration=0.5, start_index=1)
    data = Batch.from_records(records)
    return data, GreyBoxTwin().fit(data).greybox_


def test_compare_draws_the_measured_trace_above_the_model_with_units(data_and_fit):
    data, fit = data_and_fit
    fig = compare_figure(data, [fit], y_unit="rad/s")
    ax = fig.axes[0]
    measured = next(line for line in ax.get_lines() if line.get_label() == "measured")
    model = next(line for line in ax.get_lines() if line.get_label().startswith("model: "))
    assert measured.get_zorder() > model.get_zorder()
    assert measured.get_linestyle() == "-" and model.get_linestyle() == "--"
    assert measured.get_color() != model.get_color()
    assert ax.get_ylabel() == "output y (rad/s)"
    assert fig.axes[2].get_ylabel() == "y - y_sim (rad/s)" and fig.axes[2].get_xlabel() == "time since step t (s)"
    assert len(fig.legends) == 1  # one legend for the figure, above the panels
    pyplot().close(fig)


def test_ladder_figure_has_its_unit_and_an_outside_legend():
    rungs = [{"model": "linear", "rmse": 1.0, "heldout_rmse": 1.2}, {"model": "linear+x", "rmse": 0.1,
                                                                      "heldout_rmse": 0.12}]
    fig = ladder_figure(rungs, 0.09, y_unit="rad/s")
    ax = fig.axes[0]
    fig.canvas.draw()
    assert ax.get_ylabel() == "RMSE (rad/s)"
    assert not ax.get_legend().get_window_extent().overlaps(ax.get_window_extent())
    pyplot().close(fig)


def test_page_is_self_contained_and_fits_a_phone():
    png = b"\x89PNG\r\n\x1a\n" + b"0" * 20
    html = page("t", image_tag(png, "a figure", "its caption"))
    assert "<meta name='viewport' content='width=device-width, initial-scale=1'>" in html
    assert "img{display:block;max-width:100%;height:auto}" in html and ".scroll{overflow-x:auto" in html
    assert f'src="data:image/png;base64,{base64.b64encode(png).decode()}"' in html
    assert "<figcaption>its caption</figcaption>" in html


def test_residual_panels_have_units_and_bad_panels_are_named(data_and_fit):
    from agents.twin.report import RESIDUAL_PANELS, residual_figure
    from agents.twin.workbench import residuals

    data, fit = data_and_fit
    analysis = residuals(data, fit)
    fig = residual_figure(analysis, y_unit="rad/s", u_unit="V")
    assert [ax.get_xlabel() for ax in fig.axes] == [
        "lag (samples)", "lag (samples)", "time in experiment (s)", "experiment (number)", "input level u (V)",
        "output level y (rad/s)"]
    assert [ax.get_ylabel() for ax in fig.axes][2:] == ["residual (rad/s)"] * 4
    pyplot().close(fig)
    one = residual_figure(analysis, panels=["input"], u_unit="V")
    assert len(one.axes) == 1 and one.axes[0].get_xlabel() == "input level u (V)"
    pyplot().close(one)
    with pytest.raises(ValueError, match="panels"):
        residual_figure(analysis, panels=["spectrum"])
    with pytest.raises(ValueError, match="experiments"):
        compare_figure(data, [fit], experiments=[5])
    assert RESIDUAL_PANELS[0] == "acf"


def test_figures_number_the_experiments_as_the_csv_does(data_and_fit):
    """Titles and the residual panel count from 1 (docs/design.md, "Experiment numbers"): the records of
    ``data_and_fit`` are experiments 2 and 3 of their CSV, and the same records numbered from 1 read 1 and 2."""
    from dataclasses import replace

    from agents.twin.report import residual_figure
    from agents.twin.workbench import residuals

    data, fit = data_and_fit
    assert data.numbers.tolist() == [2, 3] and data.index.tolist() == [0, 1]
    for shown, numbers in ((data, [2, 3]), (replace(data, first_index=0), [1, 2]),
                           (replace(data, first_index=9), [10, 11])):
        fig = compare_figure(shown, [fit])
        titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
        assert [title.split(":")[0] for title in titles] == [f"experiment {n}" for n in numbers], titles
        pyplot().close(fig)
        fig = residual_figure(residuals(shown, fit), panels=["experiment"])
        assert fig.axes[0].get_lines()[0].get_xdata().tolist() == numbers
        pyplot().close(fig)
