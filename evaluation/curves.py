"""Runs as curves: one row per tuning run, its best-ratio curve and a short summary, not its experiments.

A study's batch files (:mod:`evaluation.study_runner`) hold every experiment of a
run. The comparisons between tuners need much less: per run the *best-ratio
curve* ``r_k = min_{j <= k} J_k(theta_j) / J*_k`` after each plant experiment
``k`` (``J_k``: the noise-free cost on the plant as it is at experiment ``k``;
``J*_k``: its minimum on the ground-truth grid; on a plant that does not change,
the minimum observed optimality ratio of :mod:`evaluation.analysis`) and each
experiment's own ratio ``J_k(theta_k) / J*_k`` (``instant``), which judges a
plant-changing env from its change on. These *curves* are what the benchmark
suite ships as references and what the comparison tables are computed from;
they are small enough to keep in the repository.

The table's columns and its file (:data:`CURVE_COLUMNS`, :func:`read_curves`, :func:`write_curves`)
are those of :mod:`evaluation.curve_table`.

A study folder may hold a ``curves.parquet`` beside its batch files (runs kept as
curves only, e.g. those of the former benchmark scripts); :func:`load_curves`
reads both, and :func:`evaluation.study_runner.run_study` skips the runs it holds.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd

import gbo_envs  # noqa: F401  (registers the envs)
from agents.jsonable import jsonable
from agents.result import CONSTRAINT_PREFIX
from evaluation.behaviour import plant_behaviour
from evaluation.curve_table import CURVE_COLUMNS, CURVES_FILE, read_curves, write_curves
from evaluation.study_runner import RESULTS_DIR, plan_batches
from gbo_envs.atomic_write import atomic_write
from gbo_envs.gain_grid import grid_axes, grid_points

__all__ = ["CURVE_COLUMNS", "CURVES_FILE", "change_at", "curves_from_results", "experiments_to_target",
           "load_curves", "plant_optima", "plant_optimum_cell", "read_curves", "run_summary", "write_curves"]

#: Keys of a result's ``info`` kept in a run's summary.
SUMMARY_KEYS = ("activations", "distrusts", "repeats", "reinitializations", "twin_evaluations", "fidelity")


def run_summary(info: dict) -> dict:
    """The figures of a tuning result's ``info`` the comparison tables show.

    ``activations, distrusts, repeats, reinitializations, twin_evaluations`` as reported
    (None when the tuner reports none), ``effects``: the effects of the twin at the end
    (sorted names; None without a twin), ``twin_changes``: ``{experiment, effects, rmse}`` of
    every twin fitted, ``fidelity``: the multi-fidelity BO's ``s_twin`` after each step.
    """
    summary = {key: info.get(key) for key in SUMMARY_KEYS if key != "fidelity"}
    effects = info.get("twin_effects")
    summary["effects"] = None if effects is None and info.get("activations") is None else sorted(effects or {})
    summary["twin_changes"] = [{"experiment": c.get("experiment"), "effects": sorted(c.get("effects") or {}),
                                "rmse": c.get("rmse")} for c in info.get("twin_changes") or []]
    trace = info.get("fidelity_trace")
    summary["fidelity"] = None if trace is None else [step.get("fidelity") for step in trace]
    return jsonable(summary)


# -- experiments to a target --------------------------------------------------------------------------
def experiments_to_target(curve, target: float, instant=None, start: int = 0, budget: int | None = None) -> int:
    """Real experiments until a run reaches the optimality ratio ``target``.

    Parameters
    ----------
    curve : sequence of float
        The best-ratio curve ``r_k`` (dimensionless).
    target : float
        Optimality ratio.
    instant : sequence of float, optional
        Each experiment's own ratio; needed when ``start > 0``.
    start : int, default 0
        First experiment (0-based) counted: from a plant change at ``start`` on, only experiments on the
        changed plant count, and the count is the best of them, ``min_{start <= j <= k} J_j(theta_j) / J*_j``
        (a gain measured on the old plant gives no reason to deploy it).
    budget : int, optional
        The run's plant experiments (default: the curve's length).

    Returns
    -------
    int
        ``k - start + 1`` for the first experiment ``k`` that reaches the target, else
        ``budget - start + 1`` (a miss).
    """
    budget = len(curve) if budget is None else int(budget)
    if start:
        ratios = np.fmin.accumulate(np.asarray(instant, dtype=float)[start:budget])
    else:
        ratios = np.asarray(curve, dtype=float)[:budget]
    hits = np.flatnonzero(ratios <= target)
    return int(hits[0]) + 1 if hits.size else budget - start + 1


# -- ground truth per experiment ---------------------------------------------------------------------
def change_at(env_id: str, env_kwargs: dict) -> int | None:
    """First experiment (0-based) on the changed plant of a plant-changing env, None for any other env."""
    schedule = getattr(gym.make(env_id, **env_kwargs).unwrapped, "schedule", None)
    return getattr(schedule, "at", None)


def plant_optima(env_id: str, env_kwargs: dict, budget: int, resolution: int = 100,
                 cache: Path | str | None = None) -> np.ndarray:
    """``J*_k`` for each experiment ``k < budget``: the ground-truth grid minimum on the plant of experiment ``k``.

    A plant that does not change has one ``J*`` (:func:`gbo_envs.ground_truth`); a time-varying one
    (``plant_params_at``) is evaluated on the ``resolution`` x ``resolution`` grid once per distinct
    plant of the episode. Results are cached in the JSON file ``cache`` (keyed by env, kwargs,
    budget, resolution and the plant's behaviour fingerprint, :mod:`evaluation.behaviour`: a change
    of its code that keeps what it does keeps the entry).

    Returns
    -------
    ndarray of shape (budget,)
    """
    key = _optima_key(env_id, env_kwargs, budget, resolution, plant_behaviour(env_id, env_kwargs))
    known = _read_json(cache)
    if key in known:
        return np.asarray(known[key], dtype=float)
    optima = _compute_optima(env_id, env_kwargs, budget, resolution)
    _write_entry(cache, key, optima.tolist())
    return optima


def plant_optimum_cell(env_id: str, env_kwargs: dict, resolution: int = 100,
                       cache: Path | str | None = None) -> tuple[tuple[int, ...], tuple[str, ...]]:
    """The grid cell of the plant's ground-truth optimum (:func:`gbo_envs.ground_truth`) and the gains' names.

    Cached in the JSON file ``cache`` beside :func:`plant_optima`'s entries, under a key of env, kwargs,
    resolution and the plant's behaviour fingerprint: a rig's live grid takes a minute of CPU.

    Returns
    -------
    cell : tuple of int
        Index of the minimum on the ``resolution`` x ``resolution`` grid, one per gain.
    gain_names : tuple of str
    """
    # budget 0 in the key: the cell is the first plant's, whatever the run length
    key = "cell:" + _optima_key(env_id, env_kwargs, 0, resolution, plant_behaviour(env_id, env_kwargs))
    known = _read_json(cache).get(key)
    if known is None:
        truth = gbo_envs.ground_truth(env_id, resolution=resolution, **env_kwargs)
        if truth.costs is None:  # a search (three gains and more): the cell of the grid nearest its optimum
            import gymnasium as gym

            box = gym.make(env_id, **env_kwargs).unwrapped.action_space
            cell = np.rint((truth.gains - box.low) / (box.high - box.low) * (resolution - 1)).astype(int)
        else:
            cell = np.unravel_index(np.argmin(truth.costs), truth.costs.shape)
        known = {"cell": [int(i) for i in cell], "gain_names": list(truth.gain_names)}
        _write_entry(cache, key, known)
    return tuple(known["cell"]), tuple(known["gain_names"])


def _write_entry(cache: Path | str | None, key: str, value) -> None:
    """Add ``key: value`` to the JSON file ``cache`` (atomically; nothing without a file)."""
    if cache is None:
        return
    known = _read_json(cache)
    known[key] = value
    Path(cache).parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(Path(cache)) as handle:
        json.dump(known, handle, indent=1, sort_keys=True)


def _optima_key(env_id: str, env_kwargs: dict, budget: int, resolution: int, plant: str) -> str:
    """The cache key of a plant's optima: env, kwargs, budget, resolution and ``plant`` (its behaviour)."""
    payload = json.dumps([env_id, jsonable(env_kwargs), int(budget), int(resolution), plant], sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def _read_json(path) -> dict:
    if path is None or not Path(path).is_file():
        return {}
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except ValueError:
        return {}


def _compute_optima(env_id: str, env_kwargs: dict, budget: int, resolution: int) -> np.ndarray:
    plant = gym.make(env_id, **env_kwargs).unwrapped
    if not hasattr(plant, "plant_params_at"):
        return np.full(budget, float(gbo_envs.ground_truth(env_id, resolution=resolution, **env_kwargs).cost))
    grid = grid_points(grid_axes(plant.action_space.low, plant.action_space.high, resolution))
    by_params: dict[str, float] = {}
    optima = []
    for k in range(budget):
        params = json.dumps(jsonable(plant.plant_params_at(k)), sort_keys=True)
        if params not in by_params:
            by_params[params] = float(np.min(plant.evaluate(grid, experiment_index=k)[1]))
        optima.append(by_params[params])
    return np.asarray(optima)


# -- batch files -> curves ----------------------------------------------------------------------------
def curves_from_results(frame: pd.DataFrame, optima: dict[str, np.ndarray], tasks: dict | None = None,
                        source: str = "engine") -> pd.DataFrame:
    """One curves row per run of a study's tidy results (:func:`evaluation.analysis.load_results`).

    Parameters
    ----------
    frame : DataFrame
        Tidy batch results (plant and twin rows).
    optima : dict of str -> ndarray
        ``J*_k`` per plant label (:func:`plant_optima`).
    tasks : dict, optional
        ``(plant, tuner, batch)`` -> :class:`~evaluation.study_runner.BatchTask`, for ``key``,
        ``file``, ``env_id``, ``env_kwargs`` and ``budget`` (else read from the frame where it can be).
    source : str
        The ``source`` column.
    """
    rows = []
    if frame.empty:
        return pd.DataFrame(columns=CURVE_COLUMNS)
    plant_rows = frame[frame["source"] == "plant"]
    if "plant" not in plant_rows:
        plant_rows = plant_rows.assign(plant="")
    for (plant, tuner, batch), part in plant_rows.groupby(["plant", "tuner", "batch"], sort=False):
        part = part.sort_values("experiment")
        true = part["true_cost"].to_numpy(dtype=float)
        true = np.where(np.isnan(true), part["cost"].to_numpy(dtype=float), true)
        # on a constrained plant only the experiments that kept every limit count towards the best
        constrained = "feasible" in part and any(part[c].notna().any() for c in part.columns
                                                 if c.startswith(CONSTRAINT_PREFIX))
        broke = part["feasible"].eq(False).to_numpy() if constrained else np.zeros(len(part), dtype=bool)
        if "best_true_cost_now" in part and part["best_true_cost_now"].notna().all():
            now = part["best_true_cost_now"].to_numpy(dtype=float)
        else:
            now = np.fmin.accumulate(np.where(broke, np.inf, true))
        best = np.asarray(optima[plant], dtype=float)
        n = len(part)
        first = part.iloc[0]
        task = (tasks or {}).get((plant, tuner, int(batch)))
        info = _json(first.get("info"))
        rows.append({
            "study": first.get("study", ""), "plant": plant, "tuner": tuner, "tuner_name": first.get("tuner_name"),
            "params": first.get("params", "{}"),
            "env_id": task.env_id if task else None,
            "env_kwargs": json.dumps(jsonable(task.env_kwargs)) if task else None,
            "budget": int(task.budget) if task else int(part["experiment"].max()), "batch": int(batch),
            "seed": int(first["seed"]), "key": task.key if task else None, "file": task.filename if task else None,
            "curve": (now / best[:n]).tolist(), "instant": (true / best[:n]).tolist(), "optimum": float(best[0]),
            "seconds": float(first.get("batch_wall_time", np.nan)),
            "cpu_seconds": float(first.get("batch_cpu_time", np.nan)),
            "plant_cpu_seconds": float(first.get("plant_cpu_time", np.nan)),
            "summary": json.dumps(run_summary(info)), "source": source,
            "violations": int(broke.sum()) if constrained else np.nan})
    return pd.DataFrame(rows, columns=CURVE_COLUMNS)


def _json(text) -> dict:
    if not isinstance(text, str):
        return {}
    try:
        value = json.loads(text)
    except ValueError:
        return {}
    return value if isinstance(value, dict) else {}


def load_curves(out: Path | str, study, optima: dict[str, np.ndarray] | None = None,
                resolution: int | None = None) -> pd.DataFrame:
    """Every finished run of ``study`` under ``out`` as curves: its batch files and its ``curves.parquet``.

    Only the runs the study plans are kept (a batch file of the study overrides a curves row of the
    same run).

    Parameters
    ----------
    out : Path
        The study's folder.
    study : Study
    optima : dict, optional
        ``J*_k`` per plant label (default: :func:`plant_optima`, cached in ``out/optima.json``).
    resolution : int, optional
        Ground-truth grid points per gain (default: the study's).

    Returns
    -------
    DataFrame
        :data:`CURVE_COLUMNS`, in plan order.
    """
    out = Path(out)
    tasks = plan_batches(study)
    by_file = {task.filename: task for task in tasks}
    folder = out / RESULTS_DIR
    files = [folder / name for name in by_file if (folder / name).is_file()]
    kept = read_curves(out / CURVES_FILE)
    kept = kept[kept["file"].isin(set(by_file) - {f.name for f in files})]
    parts = [kept] if len(kept) else []
    if files:
        if optima is None:
            optima = {}
            for plant in study.plants:
                budget = max((t.budget for t in tasks if t.plant == plant.label), default=0)
                if budget:
                    optima[plant.label] = plant_optima(plant.env_id, plant.env_kwargs, budget,
                                                       resolution or study.resolution, out / "optima.json")
        frame = pd.concat([pd.read_parquet(f) for f in files], ignore_index=True)
        if "plant" not in frame or frame["plant"].eq("").any():
            frame["plant"] = study.plants[0].label
        index = {(t.plant or study.plants[0].label, t.label, t.batch): t for t in tasks}
        parts.append(curves_from_results(frame, optima, index))
    if not parts:
        return pd.DataFrame(columns=CURVE_COLUMNS)
    curves = pd.concat(parts, ignore_index=True)
    order = {name: i for i, name in enumerate(by_file)}
    curves = curves.assign(_order=curves["file"].map(order)).sort_values("_order", kind="stable")
    return curves.drop(columns="_order").reset_index(drop=True)
