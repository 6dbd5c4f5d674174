"""Statistics of a study's tidy results table (one row per experiment, see :mod:`evaluation.study_runner`).

Definitions (paper, Sec. V):

- optimality ratio ``phi = J / J(theta*)`` with ``J(theta*)`` the ground-truth
  grid optimum (noise-free);
- *minimum observed ratio* after ``n`` plant experiments: the lowest noise-free
  cost among the first ``n`` experiments over ``J(theta*)`` (the issue's "best
  observed noise-free cost / ground-truth optimum", the paper's figures; as
  :meth:`agents.TuningResult.min_true_cost_curve`). ``rule="incumbent"`` gives
  the stricter variant: the noise-free cost of the gains with the lowest
  **measured** cost (:meth:`agents.TuningResult.best_true_cost_curve`). Where an
  env gives no ``true_cost`` the measured cost is used;
- *experiments to threshold*: the first ``n`` whose minimum observed ratio is
  ``<=`` the threshold; a batch that never gets there counts as ``budget + 1``
  and is reported as "never reached: k of n";
- *measured ratios* (histograms): every plant experiment's **measured** (noisy)
  cost over ``J(theta*)``, as the paper's histograms of "all measured
  performance values".
"""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd

import gbo_envs
from evaluation.study_runner import RESULTS_DIR, plan_batches

__all__ = [
    "PAPER_BANDS",
    "load_results",
    "study_ground_truth",
    "resolve_thresholds",
    "tuner_order",
    "ratio_curves",
    "percentile_bands",
    "experiments_to_threshold",
    "threshold_table",
    "measured_ratios",
    "histogram_edges",
    "histogram_table",
    "twin_activations",
    "timing_table",
    "summary_table",
    "best_gains_table",
    "sweep_table",
]

#: The paper's confidence bands (central percentile intervals across batches).
PAPER_BANDS = (0.68, 0.90, 0.95, 0.99)
_ACTIVATION_KEYS = ("activations", "n_activations", "twin_activations")


# -- loading ------------------------------------------------------------------------------------------
def load_results(out: Path | str, study=None) -> pd.DataFrame:
    """All finished batches under ``out/results`` as one table.

    Parameters
    ----------
    out : Path
        The study's output folder.
    study : Study, optional
        Keep only the batches the current spec plans (drops files of an edited spec).

    Returns
    -------
    pandas.DataFrame
        Sorted by tuner (spec order when ``study`` is given), batch and row. Empty if nothing finished.
    """
    folder = Path(out) / RESULTS_DIR
    files = sorted(folder.glob("*.parquet")) if folder.is_dir() else []
    if study is not None:
        wanted = {task.filename for task in plan_batches(study)}
        files = [f for f in files if f.name in wanted]
    if not files:
        return pd.DataFrame()
    frame = pd.concat([pd.read_parquet(f) for f in files], ignore_index=True)
    order = tuner_order(frame, study.labels if study is not None else None)
    frame["_order"] = frame["tuner"].map({label: i for i, label in enumerate(order)})
    frame = frame.sort_values(["_order", "batch", "row"], kind="stable").drop(columns="_order")
    return frame.reset_index(drop=True)


def tuner_order(frame: pd.DataFrame, preferred: list[str] | None = None) -> list[str]:
    """Tuner labels of ``frame``: in ``preferred`` order first, then as they appear."""
    present = list(dict.fromkeys(frame["tuner"])) if len(frame) else []
    first = [label for label in (preferred or []) if label in present]
    return first + [label for label in present if label not in first]


def study_ground_truth(study, out: Path | str | None = None):
    """Ground truth of the study's env at its resolution, cached in ``out/ground_truth.npz``.

    Returns
    -------
    gbo_envs.GroundTruth
    """
    key = json.dumps([study.env_id, study.env_kwargs, study.resolution], sort_keys=True)
    cache = Path(out) / "ground_truth.npz" if out is not None else None
    if cache is not None and cache.is_file():
        data = np.load(cache, allow_pickle=False)
        if str(data["key"]) == key and "gain_units" in data:
            n = int(data["n_axes"])
            return gbo_envs.GroundTruth(gains=data["gains"], cost=float(data["cost"]),
                                        gain_names=tuple(str(s) for s in data["gain_names"]),
                                        axes=tuple(data[f"axis{i}"] for i in range(n)), costs=data["costs"],
                                        gain_units=tuple(str(s) for s in data["gain_units"]))
    truth = gbo_envs.ground_truth(study.env_id, resolution=study.resolution, **study.env_kwargs)
    if cache is not None and truth.costs is not None:  # a grid (a search holds no cost grid to cache)
        cache.parent.mkdir(parents=True, exist_ok=True)
        axes = {f"axis{i}": axis for i, axis in enumerate(truth.axes)}
        np.savez(cache, key=key, gains=truth.gains, cost=truth.cost, gain_names=np.array(truth.gain_names),
                 gain_units=np.array(truth.gain_units), n_axes=len(truth.axes), costs=truth.costs, **axes)
    return truth


def resolve_thresholds(study, truth) -> dict[str, float]:
    """Threshold label -> optimality ratio (controller thresholds evaluated noise-free on the env)."""
    env = None
    ratios = {}
    for threshold in study.thresholds:
        if threshold.ratio is None and env is None:
            env = gym.make(study.env_id, **study.env_kwargs)
        ratios[threshold.label] = threshold.resolve(env, truth.cost)
    return ratios


# -- optimality-ratio curves --------------------------------------------------------------------------
def _plant(frame: pd.DataFrame) -> pd.DataFrame:
    return frame[frame["source"] == "plant"]


def _pivot(plant: pd.DataFrame, column: str, budget: int) -> tuple[np.ndarray, np.ndarray]:
    """``(batches, values)`` with values of shape (n_batches, budget), NaN where missing."""
    batches = np.sort(plant["batch"].unique())
    values = np.full((len(batches), budget), np.nan)
    rows = np.searchsorted(batches, plant["batch"].to_numpy())
    cols = plant["experiment"].to_numpy().astype(int) - 1
    keep = (cols >= 0) & (cols < budget)
    values[rows[keep], cols[keep]] = plant[column].to_numpy(dtype=float)[keep]
    return batches, values


def ratio_curves(frame: pd.DataFrame, optimum: float, budget: int | None = None,
                 order: list[str] | None = None, rule: str = "observed") -> dict[str, np.ndarray]:
    """Minimum observed optimality ratio per batch after each plant experiment.

    Parameters
    ----------
    frame : DataFrame
        Tidy results.
    optimum : float
        Ground-truth ``J(theta*)``.
    budget : int, optional
        Experiments per batch (default: the largest ``experiment`` present).
    order : list of str, optional
        Preferred tuner order.
    rule : {"observed", "incumbent"}, default "observed"
        Lowest noise-free cost observed so far, or the noise-free cost of the
        gains with the lowest measured cost so far (see the module docstring).

    Returns
    -------
    dict of str -> ndarray of shape (n_batches, budget)
        Per tuner label, batches in ascending order, dimensionless.
    """
    if rule not in ("observed", "incumbent"):
        raise ValueError(f"rule: must be 'observed' or 'incumbent', got {rule!r}")
    plant = _plant(frame)
    if budget is None:
        budget = int(plant["experiment"].max()) if len(plant) else 0
    curves = {}
    for label in tuner_order(plant, order):
        sub = plant[plant["tuner"] == label]
        _, cost = _pivot(sub, "cost", budget)
        _, true = _pivot(sub, "true_cost", budget)
        true = np.where(np.isnan(true), cost, true)
        best = np.full(cost.shape[0], np.inf)
        chosen = np.full(cost.shape[0], np.nan)
        curve = np.full(cost.shape, np.nan)
        if rule == "observed":
            curves[label] = np.fmin.accumulate(true, axis=1) / float(optimum)
            curves[label][np.isnan(cost)] = np.nan
            continue
        for e in range(budget):
            better = cost[:, e] < best  # strict: the first of equal measured costs is kept
            best = np.where(better, cost[:, e], best)
            chosen = np.where(better, true[:, e], chosen)
            curve[:, e] = np.where(np.isnan(cost[:, e]), np.nan, chosen)
        curves[label] = curve / float(optimum)
    return curves


def percentile_bands(curves: np.ndarray, levels=PAPER_BANDS) -> dict:
    """Mean and central percentile bands across batches.

    Parameters
    ----------
    curves : ndarray of shape (n_batches, n_experiments)
    levels : sequence of float
        Coverages in (0, 1); level ``l`` spans percentiles ``50 (1 - l)`` to ``50 (1 + l)``.

    Returns
    -------
    dict
        ``"mean"``, ``"median"`` (shape (n_experiments,)) and ``"bands"``: level -> (low, high).
    """
    curves = np.asarray(curves, dtype=float)
    bands = {}
    for level in levels:
        if not 0 < level < 1:
            raise ValueError(f"levels: each must be in (0, 1), got {level}")
        low, high = np.nanpercentile(curves, [50 * (1 - level), 50 * (1 + level)], axis=0)
        bands[float(level)] = (low, high)
    return {"mean": np.nanmean(curves, axis=0), "median": np.nanmedian(curves, axis=0), "bands": bands}


def experiments_to_threshold(curves: np.ndarray, ratio: float, offset: int = 0) -> np.ndarray:
    """Plant experiments until the minimum observed ratio is ``<= ratio``, per batch.

    Parameters
    ----------
    curves : ndarray of shape (n_batches, budget)
    ratio : float
        Optimality-ratio threshold.
    offset : int
        Subtracted from every count (N0 when initial experiments are not counted); floored at 0.

    Returns
    -------
    ndarray of int of shape (n_batches,)
        ``budget + 1 - offset`` for batches that never reach the threshold.
    """
    curves = np.asarray(curves, dtype=float)
    reached = curves <= ratio
    first = np.where(reached.any(axis=1), reached.argmax(axis=1) + 1, curves.shape[1] + 1)
    return np.maximum(first - int(offset), 0)


def threshold_table(curves: dict[str, np.ndarray], thresholds: dict[str, float], offset: int = 0) -> pd.DataFrame:
    """Experiments-to-threshold statistics per tuner and threshold.

    Returns
    -------
    DataFrame
        Columns ``tuner, threshold, ratio, mean, median, best, worst, never, n`` where
        ``never`` counts batches that did not reach the ratio (counted as budget + 1 in the statistics).
    """
    rows = []
    for label, curve in curves.items():
        for name, ratio in thresholds.items():
            counts = experiments_to_threshold(curve, ratio, offset)
            never = int(np.sum(~(curve <= ratio).any(axis=1)))
            rows.append({"tuner": label, "threshold": name, "ratio": float(ratio), "mean": float(counts.mean()),
                         "median": float(np.median(counts)), "best": int(counts.min()), "worst": int(counts.max()),
                         "never": never, "n": int(len(counts))})
    return pd.DataFrame(rows, columns=["tuner", "threshold", "ratio", "mean", "median", "best", "worst", "never", "n"])


# -- histograms ----------------------------------------------------------------------------------------
def measured_ratios(frame: pd.DataFrame, optimum: float, order: list[str] | None = None) -> dict[str, np.ndarray]:
    """Measured cost / ``J(theta*)`` of every plant experiment, per tuner (dimensionless)."""
    plant = _plant(frame)
    return {label: plant.loc[plant["tuner"] == label, "cost"].to_numpy(dtype=float) / float(optimum)
            for label in tuner_order(plant, order)}


def histogram_edges(ratios: dict[str, np.ndarray], bins=20, upper: float | None = None) -> np.ndarray:
    """Bin edges for :func:`histogram_table`: ``bins`` edges as given, or that many equal bins.

    The range runs from the smallest ratio (rounded down to 0.05) to ``upper``
    (default: the 95th percentile of all ratios, at least 1.5).
    """
    if not isinstance(bins, int):
        return np.asarray(bins, dtype=float)
    values = np.concatenate([np.asarray(v, dtype=float) for v in ratios.values()]) if ratios else np.array([1.0])
    values = values[np.isfinite(values)]
    low = np.floor(min(1.0, values.min()) * 20) / 20
    high = float(upper) if upper is not None else max(1.5, float(np.percentile(values, 95)))
    return np.linspace(low, high, int(bins) + 1)


def histogram_table(ratios: dict[str, np.ndarray], edges: np.ndarray) -> pd.DataFrame:
    """Percentage of each tuner's experiments per ratio bin; values past the last edge go in the last bin.

    Returns
    -------
    DataFrame
        Columns ``low, high`` and one percentage column per tuner (each sums to 100).
    """
    edges = np.asarray(edges, dtype=float)
    table = pd.DataFrame({"low": edges[:-1], "high": edges[1:]})
    for label, values in ratios.items():
        clipped = np.clip(np.asarray(values, dtype=float), edges[0], edges[-1])
        counts, _ = np.histogram(clipped, bins=edges)
        table[label] = 100.0 * counts / max(1, len(values))
    return table


# -- twin and time ------------------------------------------------------------------------------------
def twin_activations(frame: pd.DataFrame, order: list[str] | None = None) -> pd.DataFrame:
    """Twin use per batch: ``tuner, batch, twin_evaluations, activations``.

    ``activations`` is the tuner's own count when its result ``info`` has one
    (keys ``activations``, ``n_activations`` or ``twin_activations``), else the
    number of plant experiments preceded by twin evaluations.
    """
    rows = []
    for label in tuner_order(frame, order):
        sub = frame[frame["tuner"] == label]
        for batch, part in sub.groupby("batch", sort=True):
            twin = part[part["source"] == "twin"]
            activations = twin["experiment"].nunique()
            info = _info(part)
            for key in _ACTIVATION_KEYS:
                if isinstance(info.get(key), (int, float)) and not isinstance(info.get(key), bool):
                    activations = info[key]
                    break
            rows.append({"tuner": label, "batch": int(batch), "twin_evaluations": int(len(twin)),
                         "activations": float(activations)})
    return pd.DataFrame(rows, columns=["tuner", "batch", "twin_evaluations", "activations"])


def _info(part: pd.DataFrame) -> dict:
    if "info" not in part or not len(part):
        return {}
    try:
        value = json.loads(part["info"].iloc[0])
    except (TypeError, ValueError):
        return {}
    return value if isinstance(value, dict) else {}


def timing_table(frame: pd.DataFrame, order: list[str] | None = None) -> pd.DataFrame:
    """Tuning time per tuner (s), averaged over batches.

    Columns: ``batch_s`` (wall time of a batch), ``plant_experiment_s`` (one
    plant experiment with no twin evaluation before it: the tuner's ask/tell
    plus the simulated experiment), ``twin_evaluations`` (per batch) and
    ``twin_evaluation_s``: the extra time of experiments preceded by twin
    evaluations over the number of twin evaluations, an estimate of the cost of
    one BO iteration on the twin (twin identification included).
    """
    rows = []
    for label in tuner_order(frame, order):
        sub = frame[frame["tuner"] == label]
        batch_s, plain_s, twin_s, twin_n = [], [], [], []
        for _, part in sub.groupby("batch", sort=True):
            part = part.sort_values("row")
            plant = part[part["source"] == "plant"]
            times = plant["wall_time"].to_numpy(dtype=float)
            durations = np.diff(np.concatenate([[0.0], times]))
            with_twin = plant["experiment"].isin(part.loc[part["source"] == "twin", "experiment"]).to_numpy()
            plain = durations[~with_twin]
            n_twin = int((part["source"] == "twin").sum())
            batch_s.append(float(part["batch_wall_time"].iloc[0]) if "batch_wall_time" in part else times[-1])
            if plain.size:
                plain_s.append(float(plain.mean()))
            twin_n.append(n_twin)
            if n_twin and plain.size:
                twin_s.append(float(np.sum(durations[with_twin] - plain.mean()) / n_twin))
        rows.append({"tuner": label, "batches": len(batch_s), "batch_s": _mean(batch_s),
                     "plant_experiment_s": _mean(plain_s), "twin_evaluations": _mean(twin_n),
                     "twin_evaluation_s": _mean(twin_s)})
    return pd.DataFrame(rows, columns=["tuner", "batches", "batch_s", "plant_experiment_s", "twin_evaluations",
                                       "twin_evaluation_s"])


def _mean(values) -> float:
    return float(np.mean(values)) if len(values) else float("nan")


# -- summaries ----------------------------------------------------------------------------------------
def summary_table(frame: pd.DataFrame, optimum: float, order: list[str] | None = None) -> pd.DataFrame:
    """One row per tuner: ``batches, final_ratio`` (mean minimum observed ratio at the last experiment),
    ``final_ratio_median, mean_measured_ratio`` (mean of all measured ratios), ``activations`` and
    ``twin_evaluations`` (mean per batch), ``batch_wall_time`` (mean, s)."""
    curves = ratio_curves(frame, optimum, order=order)
    ratios = measured_ratios(frame, optimum, order=order)
    twin = twin_activations(frame, order=order)
    rows = []
    for label, curve in curves.items():
        final = curve[:, -1]
        use = twin[twin["tuner"] == label]
        walls = frame.loc[frame["tuner"] == label].groupby("batch")["batch_wall_time"].first()
        rows.append({"tuner": label, "batches": int(curve.shape[0]), "final_ratio": float(np.nanmean(final)),
                     "final_ratio_median": float(np.nanmedian(final)),
                     "mean_measured_ratio": float(np.mean(ratios[label])),
                     "activations": float(use["activations"].mean()),
                     "twin_evaluations": float(use["twin_evaluations"].mean()),
                     "batch_wall_time": float(walls.mean())})
    return pd.DataFrame(rows)


def best_gains_table(frame: pd.DataFrame, optimum: float, gain_names, at_experiment: int | None = None,
                     order: list[str] | None = None) -> pd.DataFrame:
    """Best-measured gains after ``at_experiment`` plant experiments: median over batches.

    Returns
    -------
    DataFrame
        ``tuner``, one column per gain (median over batches), ``true_cost`` and
        ``ratio`` (mean over batches of the noise-free cost of those gains and its ratio).
    """
    plant = _plant(frame)
    if at_experiment is not None:
        plant = plant[plant["experiment"] <= at_experiment]
    rows = []
    for label in tuner_order(plant, order):
        sub = plant[plant["tuner"] == label].sort_values(["batch", "experiment"])
        best = sub.loc[sub.groupby("batch")["cost"].idxmin()]
        true = best["true_cost"].where(best["true_cost"].notna(), best["cost"]).to_numpy(dtype=float)
        row = {"tuner": label}
        row.update({name: float(best[name].median()) for name in gain_names})
        row.update({"true_cost": float(true.mean()), "ratio": float(true.mean() / optimum)})
        rows.append(row)
    return pd.DataFrame(rows, columns=["tuner", *gain_names, "true_cost", "ratio"])


def sweep_table(frame: pd.DataFrame, optimum: float, thresholds: dict[str, float], sweeps: dict[str, dict],
                param: str, offset: int = 0) -> pd.DataFrame:
    """Statistics against one swept parameter (e.g. the paper's eta1 figure).

    Parameters
    ----------
    frame : DataFrame
    optimum : float
    thresholds : dict of str -> float
    sweeps : dict of str -> dict
        Tuner label -> its sweep point (``TunerEntry.sweep``); tuners without ``param`` are left out.
    param : str
    offset : int
        As in :func:`experiments_to_threshold`.

    Returns
    -------
    DataFrame
        ``tuner, <param>, final_ratio, mean_measured_ratio, activations`` and one
        ``to <threshold>`` column (mean experiments) per threshold, sorted by ``param``.
    """
    labels = [label for label, point in sweeps.items() if param in point and label in set(frame["tuner"])]
    if not labels:
        return pd.DataFrame()
    sub = frame[frame["tuner"].isin(labels)]
    summary = summary_table(sub, optimum, order=labels).set_index("tuner")
    curves = ratio_curves(sub, optimum, order=labels)
    rows = []
    for label in labels:
        row = {"tuner": label, param: sweeps[label][param], **summary.loc[label, ["final_ratio",
                                                                                 "mean_measured_ratio",
                                                                                 "activations"]].to_dict()}
        for name, ratio in thresholds.items():
            row[f"to {name}"] = float(experiments_to_threshold(curves[label], ratio, offset).mean())
        rows.append(row)
    table = pd.DataFrame(rows)
    try:
        return table.sort_values(param, kind="stable").reset_index(drop=True)
    except TypeError:
        return table
