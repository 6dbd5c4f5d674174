"""Runs as curves (evaluation.curves): experiments to a target, and the ratio judged on the plant of each experiment."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import agents
import gbo_envs  # noqa: F401  (registers the envs)
from evaluation.curves import change_at, experiments_to_target, plant_optima, plant_optimum_cell
from evaluation.study_runner import best_true_cost_now


def test_counts_restart_at_the_change_and_only_the_changed_plants_experiments_count():
    # r_k judges earlier gains on the current plant; after a change only experiments on the new plant count
    curve, instant = [1.3, 1.04, 1.02, 1.02, 1.02], [1.3, 1.04, 1.5, 1.2, 1.03]
    assert experiments_to_target(curve, 1.05, budget=2) == 2  # before a change at experiment index 2
    assert experiments_to_target(curve, 1.05, instant=instant, start=2) == 3  # r_2 = 1.02 from an old gain: no
    assert experiments_to_target(curve, 1.01, instant=instant, start=2) == 4  # a miss counts budget - change + 1
    assert experiments_to_target(curve, 1.01) == 6
    assert change_at("gbo_envs/DCMotorStep-v0", {"change_at": 7}) == 7
    assert change_at("gbo_envs/DCMotorDrift-v0", {}) is None and change_at("gbo_envs/DCMotor-v0", {}) is None


@pytest.mark.slow
def test_the_ratio_judges_the_best_gains_so_far_on_the_plant_of_each_experiment(tmp_path):
    # DCMotorStep-v0 changes its plant at experiment 15: the grid optimum moves from (0.52, 1.163) to (0.70, 0.87)
    optima = plant_optima("gbo_envs/DCMotorStep-v0", {}, 35, cache=tmp_path / "optima.json")
    assert len(optima) == 35 and len(set(optima)) == 2 and optima[0] == optima[14] != optima[15]
    assert np.array_equal(plant_optima("gbo_envs/DCMotorStep-v0", {}, 35, cache=tmp_path / "optima.json"), optima)
    plant = gym.make("gbo_envs/DCMotorStep-v0").unwrapped
    old, new = [0.52, 1.1633333333333333], [0.7, 0.87]

    class Fixed(agents.Tuner):
        def __init__(self, *, path=()) -> None:
            self.path = [list(p) for p in path]
            self._params = {}

        def _ask(self):
            return np.array(self.path[len(self.told)])

        def _setup(self) -> None:
            self.told = []

        def _tell(self, gains, cost, record) -> None:
            self.told.append(gains)

    def ratios(path):
        result = Fixed(path=path).run(gym.make("gbo_envs/DCMotorStep-v0", noise=False), budget=len(path), seed=0)
        return best_true_cost_now(plant, result) / optima[: len(path)]

    moving = ratios([old] * 15 + [new] + [old])
    assert moving[0] == pytest.approx(1.0) and moving[14] == pytest.approx(1.0)
    assert moving[15] == pytest.approx(1.0)  # the new optimum tried on the new plant
    assert moving[16] == pytest.approx(1.0)  # and still the best known afterwards
    assert ratios([old] * 16)[15] > 1.5  # the old optimum costs about 2 J* on the changed plant


def test_the_optimum_cell_is_the_ground_truths_and_is_computed_once(tmp_path, monkeypatch):
    cache = tmp_path / "optima.json"
    truth = gbo_envs.ground_truth("gbo_envs/DCMotor-v0", resolution=12)
    cell, names = plant_optimum_cell("gbo_envs/DCMotor-v0", {}, 12, cache)
    assert cell == np.unravel_index(np.argmin(truth.costs), truth.costs.shape) and names == tuple(truth.gain_names)
    monkeypatch.setattr(gbo_envs, "ground_truth", lambda *a, **k: pytest.fail("computed again"))
    assert plant_optimum_cell("gbo_envs/DCMotor-v0", {}, 12, cache) == (cell, names)
    with pytest.raises(pytest.fail.Exception):  # another resolution is another cell
        plant_optimum_cell("gbo_envs/DCMotor-v0", {}, 13, cache)
