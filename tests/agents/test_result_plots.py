"""TuningResult's figures: the cost over the experiments, the path on the cost surface, convergence over seeds."""

from __future__ import annotations

import gymnasium as gym

import agents
import gbo_envs
from gbo_envs.lazy_pyplot import pyplot
from gbo_envs.plotting import convergence_figure


def test_path_on_the_cost_surface_and_convergence_over_seeds():
    results = [agents.make("random").run(gym.make("gbo_envs/DCMotor-v0"), budget=4, seed=seed) for seed in (0, 1, 2)]
    truth = gbo_envs.ground_truth("gbo_envs/DCMotor-v0", resolution=6, n_jobs=1, noise=False)
    ax = results[0].plot_gains(truth)
    path = next(line for line in ax.get_lines() if line.get_label() == "tuner's path (4 experiments)")
    assert path.get_xdata().tolist() == [row["Kp"] for row in results[0].plant_rows]
    assert ax.get_title() == "random on gbo_envs/DCMotor-v0, seed 0"
    fig = convergence_figure(results, optimum=truth.cost)
    labels = [c.get_label() for c in fig.axes[0].collections]
    assert "random: 95% confidence band of the mean" in labels
    assert [line.get_label() for line in fig.axes[0].get_lines()][0] == "random: mean of 3 runs"
    ax = results[0].plot(optimum=truth.cost)
    assert ax.get_xlabel() == "plant experiments (count)" and ax.get_ylabel() == "cost J (-)"
    pyplot().close("all")
