"""Statistics and figures of study results, on hand-made tables with known answers."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest

import agents
import gbo_envs  # noqa: F401
from evaluation import analysis, figures
from evaluation.study_runner import BatchTask, run_batch


def table(batches: dict[tuple[str, int], list[tuple]], info: dict | None = None) -> pd.DataFrame:
    """Rows ``(source, experiment, cost, true_cost, wall_time)`` per (tuner, batch)."""
    rows = []
    for (tuner, batch), entries in batches.items():
        for i, (source, experiment, cost, true, wall) in enumerate(entries):
            rows.append({"tuner": tuner, "batch": batch, "row": i, "source": source, "experiment": experiment,
                         "cost": cost, "true_cost": true, "wall_time": wall, "Kp": 0.1 * experiment + batch,
                         "Ki": 1.0 + 0.01 * experiment, "batch_wall_time": entries[-1][4],
                         "info": json.dumps((info or {}).get((tuner, batch), {}))})
    return pd.DataFrame(rows)


# measured costs: 3.0, 2.0, 2.5, 1.5 -> choices: e1, e2, e2, e4 ; true costs: 2.9, 2.2, 1.0, 1.6
BATCH_A = [("plant", 1, 3.0, 2.9, 0.1), ("plant", 2, 2.0, 2.2, 0.2), ("plant", 3, 2.5, 1.0, 0.3),
           ("plant", 4, 1.5, 1.6, 0.4)]
# equal measured costs keep the first; a twin row is ignored by the curves
BATCH_B = [("plant", 1, 2.0, 2.0, 0.1), ("twin", 2, 0.5, np.nan, 0.15), ("twin", 2, 0.4, np.nan, 0.2),
           ("plant", 2, 2.0, 1.2, 0.5), ("plant", 3, 1.9, 1.1, 0.6), ("plant", 4, 5.0, 1.0, 0.7)]


def test_ratio_curves_take_the_lowest_observed_true_cost():
    frame = table({("A", 0): BATCH_A, ("A", 1): BATCH_B})
    curves = analysis.ratio_curves(frame, optimum=1.0)
    np.testing.assert_allclose(curves["A"], [[2.9, 2.2, 1.0, 1.0], [2.0, 1.2, 1.1, 1.0]])
    half = analysis.ratio_curves(frame, optimum=2.0)["A"]
    np.testing.assert_allclose(half[0], [1.45, 1.1, 0.5, 0.5])


def test_incumbent_ratio_curves_follow_the_best_measured_gains():
    frame = table({("A", 0): BATCH_A, ("A", 1): BATCH_B})
    curves = analysis.ratio_curves(frame, optimum=1.0, rule="incumbent")
    np.testing.assert_allclose(curves["A"], [[2.9, 2.2, 2.2, 1.6], [2.0, 2.0, 1.1, 1.1]])
    with pytest.raises(ValueError, match="rule"):
        analysis.ratio_curves(frame, optimum=1.0, rule="best")


def test_ratio_curves_match_tuning_result(tmp_path):
    task = BatchTask(study="t", label="random", tuner="random", params={}, batch=0, seed=3,
                     env_id="gbo_envs/DCMotor-v0", env_kwargs={}, budget=6)
    frame = run_batch(task)
    result = agents.make("random").run(gym.make("gbo_envs/DCMotor-v0"), budget=6, seed=3)
    np.testing.assert_allclose(analysis.ratio_curves(frame, optimum=0.5)["random"][0],
                               result.min_true_cost_curve() / 0.5)
    np.testing.assert_allclose(analysis.ratio_curves(frame, optimum=0.5, rule="incumbent")["random"][0],
                               result.best_true_cost_curve() / 0.5)


def test_experiments_to_threshold_counts_never_as_budget_plus_one():
    curves = np.array([[3.0, 1.2, 1.04, 1.0], [2.0, 1.9, 1.8, 1.7], [1.0, 1.0, 1.0, 1.0]])
    np.testing.assert_array_equal(analysis.experiments_to_threshold(curves, 1.05), [3, 5, 1])
    np.testing.assert_array_equal(analysis.experiments_to_threshold(curves, 1.05, offset=1), [2, 4, 0])
    result = analysis.threshold_table({"A": curves}, {"phi=1.05": 1.05, "easy": 5.0})
    row = result.set_index("threshold").loc["phi=1.05"]
    assert (row["mean"], row["best"], row["worst"], row["never"], row["n"]) == (3.0, 1, 5, 1, 3)
    assert result.set_index("threshold").loc["easy", "mean"] == 1.0


def test_percentile_bands():
    curves = np.arange(101, dtype=float)[:, None] * np.ones((1, 4))
    stats = analysis.percentile_bands(curves)
    np.testing.assert_allclose(stats["mean"], 50.0)
    low, high = stats["bands"][0.9]
    np.testing.assert_allclose(low, 5.0)
    np.testing.assert_allclose(high, 95.0)
    assert set(stats["bands"]) == {0.68, 0.9, 0.95, 0.99}
    with pytest.raises(ValueError, match="levels"):
        analysis.percentile_bands(curves, levels=(1.5,))


def test_measured_ratio_histogram_percentages():
    frame = table({("A", 0): BATCH_A, ("B", 0): BATCH_B})
    ratios = analysis.measured_ratios(frame, optimum=2.0)
    np.testing.assert_allclose(ratios["A"], [1.5, 1.0, 1.25, 0.75])
    np.testing.assert_allclose(ratios["B"], [1.0, 1.0, 0.95, 2.5])  # measured, twin rows left out
    hist = analysis.histogram_table(ratios, np.array([0.5, 1.0, 1.5, 2.0]))
    assert list(hist["A"]) == [25.0, 50.0, 25.0]
    assert list(hist["B"]) == [25.0, 50.0, 25.0]  # 2.5 clipped into the last bin
    assert hist[["A", "B"]].sum().tolist() == [100.0, 100.0]
    edges = analysis.histogram_edges(ratios, bins=4, upper=3.0)
    np.testing.assert_allclose(edges, [0.75, 1.3125, 1.875, 2.4375, 3.0])


def test_twin_activations_and_timing():
    frame = table({("A", 0): BATCH_A, ("B", 0): BATCH_B, ("B", 1): BATCH_B},
                  info={("B", 1): {"activations": 7}})
    twin = analysis.twin_activations(frame).set_index(["tuner", "batch"])
    assert twin.loc[("A", 0)].tolist() == [0, 0]
    assert twin.loc[("B", 0)].tolist() == [2, 1]  # 2 twin rows before one plant experiment
    assert twin.loc[("B", 1)].tolist() == [2, 7]  # the tuner's own count wins
    timing = analysis.timing_table(frame).set_index("tuner")
    assert timing.loc["A", "plant_experiment_s"] == pytest.approx(0.1)
    assert np.isnan(timing.loc["A", "twin_evaluation_s"])
    # B: plant durations 0.1, 0.4 (with twin), 0.1, 0.1 -> extra 0.3 s over 2 twin evaluations
    assert timing.loc["B", "plant_experiment_s"] == pytest.approx(0.1)
    assert timing.loc["B", "twin_evaluation_s"] == pytest.approx(0.15)
    assert timing.loc["B", "batch_s"] == pytest.approx(0.7)
    summary = analysis.summary_table(frame, optimum=1.0).set_index("tuner")
    assert summary.loc["B", "activations"] == 4.0 and summary.loc["B", "twin_evaluations"] == 2.0
    assert summary.loc["A", "final_ratio"] == pytest.approx(1.0)


def test_best_gains_table_at_an_experiment():
    frame = table({("A", 0): BATCH_A, ("A", 1): BATCH_B})
    gains = analysis.best_gains_table(frame, optimum=1.0, gain_names=["Kp", "Ki"], at_experiment=2)
    row = gains.set_index("tuner").loc["A"]
    # batch 0: best of e1, e2 is e2 (Kp 0.2); batch 1: e1 (Kp 1.1) -> median 0.65
    assert row["Kp"] == pytest.approx(0.65)
    assert row["true_cost"] == pytest.approx((2.2 + 2.0) / 2)


def test_sweep_table_sorts_by_the_parameter():
    frame = table({("g eta1=3", 0): BATCH_A, ("g eta1=1", 0): BATCH_B, ("BO", 0): BATCH_A})
    sweeps = {"BO": {}, "g eta1=3": {"eta1": 3.0}, "g eta1=1": {"eta1": 1.0}}
    result = analysis.sweep_table(frame, 1.0, {"phi=1.5": 1.5}, sweeps, "eta1")
    assert result["tuner"].tolist() == ["g eta1=1", "g eta1=3"]
    assert result["to phi=1.5"].tolist() == [2.0, 3.0]
    assert result["activations"].tolist() == [1.0, 0.0]


def test_figures_render(tmp_path):
    frame = table({("A", 0): BATCH_A, ("A", 1): BATCH_B, ("B", 0): BATCH_B})
    curves = analysis.ratio_curves(frame, optimum=1.0)
    fig = figures.ratio_curve_figure(curves, {"phi=1.5": 1.5})
    assert figures.save(fig, tmp_path / "curves.png").stat().st_size > 0
    hist = analysis.histogram_table(analysis.measured_ratios(frame, 1.0), np.linspace(0.5, 3, 6))
    assert figures.save(figures.histogram_figure(hist), tmp_path / "hist.png").is_file()
    twin = analysis.twin_activations(frame)
    assert figures.save(figures.activations_figure(twin), tmp_path / "act.png").is_file()
    truth = gbo_envs.ground_truth("gbo_envs/DCMotor-v0", resolution=8)
    fig = figures.cost_surface_figure(truth, frame, batch=0)
    assert len([ax for ax in fig.axes if ax.get_visible() and ax.get_label() != "<colorbar>"]) == 2
    assert figures.save(fig, tmp_path / "surface.png").is_file()
