"""The one plotting module: units on every axis, legends outside the data, the env's render, convergence bands."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest

import gbo_envs
from gbo_envs import plotting
from gbo_envs.lazy_pyplot import pyplot


def _outside(ax) -> bool:
    """Whether the legend of ``ax`` lies wholly outside its data area."""
    ax.figure.canvas.draw()
    legend = ax.get_legend() or ax.figure.legends[0]
    return not legend.get_window_extent().overlaps(ax.get_window_extent())


def test_gain_units_follow_the_env_input_and_output_units():
    assert gym.make("gbo_envs/DCMotor-v0").unwrapped.gain_units == ("(input units)/(rad/s)", "1/s")
    assert gym.make("gbo_envs/DCMotorRig-v0").unwrapped.gain_units == ("(input units)/(rad/s)", "1/s")
    assert gym.make("gbo_envs/LinearMotor-v0").unwrapped.gain_units == ("A/m", "A s/m")
    assert gbo_envs.PIController().units_for("V", "rad/s") == ("V/(rad/s)", "1/s")


def test_axis_label_names_the_unit():
    assert plotting.axis_label("cost J", "-") == "cost J (-)"
    assert plotting.axis_label("gain Kp", "(input units)/(rad/s)") == "gain Kp [(input units)/(rad/s)]"
    assert plotting.axis_label("output y", "") == "output y (units unknown)"


def test_render_has_a_title_and_units(monkeypatch):
    figures = []
    monkeypatch.setattr(plotting, "figure_to_rgb",
                        lambda fig: figures.append(fig) or np.zeros((2, 2, 3), dtype=np.uint8))
    env = gym.make("gbo_envs/DCMotor-v0", render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.array([0.5, 1.2]))
    env.render()
    ax_y, ax_u = figures[0].axes
    assert ax_y.get_title() == "DCMotorEnv, experiment 1: Kp = 0.5 (input units)/(rad/s), Ki = 1.2 1/s"
    assert ax_y.get_ylabel() == "output y (rad/s)"
    assert ax_u.get_ylabel() == "command u (input units)"
    assert ax_u.get_xlabel() == "time since step t (s)"
    assert _outside(ax_y)
    pyplot().close("all")


@pytest.fixture(scope="module")
def truth():
    return gbo_envs.ground_truth("gbo_envs/DCMotor-v0", resolution=8, n_jobs=1, noise=False)


def test_cost_surface_marks_the_optimum_and_the_tuners_path(truth):
    path = np.array([[0.3, 1.0], [0.6, 1.5], [0.5, 1.2]])
    ax = truth.plot(path=path)
    labels = [line.get_label() for line in ax.get_lines()]
    assert f"optimum J* = {truth.cost:.3f}" in labels and "tuner's path (3 experiments)" in labels
    assert [t.get_text() for t in ax.texts] == ["1", "2", "3"]
    assert ax.get_xlabel() == "gain Kp [(input units)/(rad/s)]" and ax.get_ylabel() == "gain Ki (1/s)"
    assert ax.figure.axes[1].get_ylabel() == "cost J (-)"  # the colour bar
    assert _outside(ax)
    pyplot().close("all")


def test_convergence_over_seeds_has_the_mean_and_a_95_percent_band():
    runs = pd.DataFrame({"tuner": "bo", "seed": np.repeat([0, 1, 2], 3), "experiment": np.tile([1, 2, 3], 3),
                         "source": "plant", "cost": 9.0,
                         "true_cost": [4.0, 2.0, 3.0, 2.0, 2.0, 1.0, 3.0, 1.0, 1.0]})
    curves = plotting.convergence_curves(runs, optimum=2.0)
    np.testing.assert_allclose(curves["bo"], [[2, 1, 1], [1, 1, 0.5], [1.5, 0.5, 0.5]])
    fig = plotting.convergence_figure(runs, optimum=2.0)
    ax = fig.axes[0]
    mean = next(line for line in ax.get_lines() if line.get_label() == "bo: mean of 3 runs")
    np.testing.assert_allclose(mean.get_ydata(), [1.5, 2.5 / 3, 2 / 3])
    band = next(c for c in ax.collections if c.get_label() == "bo: 95% confidence band of the mean")
    low = band.get_paths()[0].vertices[:, 1].min()
    assert low < 2 / 3 - 0.1  # t(0.975, 2) * std / sqrt(3) below the last mean
    assert ax.get_xlabel() == "plant experiments (count)"
    assert ax.get_ylabel() == "minimum observed optimality ratio J/J* (-)"
    assert _outside(ax)
    with pytest.raises(ValueError, match="level"):
        plotting.convergence_figure(runs, level=1.5)
    with pytest.raises(ValueError, match="columns"):
        plotting.convergence_figure(runs.drop(columns="seed"))
    pyplot().close("all")
