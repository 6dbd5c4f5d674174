"""The evaluation helpers read a ground truth that is a search (three gains and more), not a grid."""

from __future__ import annotations

from types import SimpleNamespace

import gymnasium as gym
import numpy as np

import gbo_envs
from evaluation import analysis
from evaluation.curves import plant_optimum_cell

PID = "gbo_envs/DCMotorPID-v0"


def test_the_optimum_cell_of_a_search_is_the_grid_cell_nearest_its_optimum(tmp_path):
    truth = gbo_envs.ground_truth(PID)
    assert truth.method == "search"
    cell, names = plant_optimum_cell(PID, {}, 100, tmp_path / "optima.json")
    box = gym.make(PID).unwrapped.action_space
    axes = [np.linspace(lo, hi, 100) for lo, hi in zip(box.low, box.high)]
    nearest = tuple(int(np.argmin(np.abs(axis - g))) for axis, g in zip(axes, truth.gains))
    assert cell == nearest and names == ("Kp", "Ki", "Kd")


def test_a_study_of_a_3_gain_env_gets_its_ground_truth_twice(tmp_path):
    study = SimpleNamespace(env_id=PID, env_kwargs={}, resolution=100)
    first = analysis.study_ground_truth(study, tmp_path)
    again = analysis.study_ground_truth(study, tmp_path)
    assert first.cost == again.cost == gbo_envs.ground_truth(PID).cost and again.method == "search"
    np.testing.assert_array_equal(first.gains, again.gains)
