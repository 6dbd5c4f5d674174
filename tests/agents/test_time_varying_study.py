"""benchmarks/time_varying_guided_bo.py: the optimality ratio against the plant of each experiment."""

from __future__ import annotations

import numpy as np
import pytest

from tests.support import benchmark_module


@pytest.fixture()
def study(monkeypatch, tmp_path):
    return benchmark_module(monkeypatch, "time_varying_guided_bo", RESULTS=tmp_path,
                            RUNS=tmp_path / "runs.jsonl", OPTIMA=tmp_path / "optima.json")


def test_counts_restart_at_the_change_and_only_the_changed_plants_experiments_count(study):
    # r_k judges earlier gains on the current plant; after a change only experiments on the new plant count
    run = {"ratios": [1.3, 1.04, 1.02, 1.02, 1.02], "instant": [1.3, 1.04, 1.5, 1.2, 1.03]}
    assert study.experiments_to(run, 1.05, 0, 2) == 2  # before a change at experiment index 2
    assert study.experiments_to(run, 1.05, 2, 5) == 3  # r_2 = 1.02 from an old gain does not count
    assert study.experiments_to(run, 1.01, 2, 5) == 4  # a miss counts budget - change + 1
    assert study.experiments_to(run, 1.01, 0, 5) == 6


@pytest.mark.slow
def test_the_ratio_judges_the_best_gains_so_far_on_the_plant_of_each_experiment(study):
    # DCMotorStep-v0 changes its plant at experiment 15: the grid optimum moves from (0.52, 1.163) to (0.70, 0.87)
    optima = study.grid_optima("DCMotorStep-v0")
    assert len(optima) == 35 and len(set(optima)) == 2 and optima[0] == optima[14] != optima[15]
    assert study.grid_optima("DCMotorStep-v0") == optima  # cached
    plant = study.make("DCMotorStep-v0").unwrapped
    old, new = [0.52, 1.1633333333333333], [0.7, 0.87]
    gains = np.array([old] * 15 + [new] + [old])
    ratios = study.moving_ratios(plant, gains, optima)
    assert ratios[0] == pytest.approx(1.0) and ratios[14] == pytest.approx(1.0)
    assert ratios[15] == pytest.approx(1.0)  # the new optimum tried on the new plant
    assert ratios[16] == pytest.approx(1.0)  # and still the best known afterwards
    stale = study.moving_ratios(plant, np.array([old] * 16), optima)
    assert stale[15] > 1.5  # the old optimum costs about 2 J* on the changed plant
