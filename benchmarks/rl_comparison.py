"""RL (on the plant and trained on the nominal model) against BO and guided BO, in real experiments.

Runs the shipped studies ``evaluation/studies/rl_comparison.toml`` (DCMotor-v0)
and ``rl_comparison_rig.toml`` (DCMotorRig-v0) through the evaluation study
runner (:func:`evaluation.study_runner.run_study`: parallel batches, each saved
at once, a rerun resumes), then reports per env and method the plant
experiments needed to reach optimality ratio 1.1 and 1.05
(``phi = J_true(gains with the lowest measured cost) / J(theta*)``, the
``"incumbent"`` rule of :func:`evaluation.analysis.ratio_curves`); a run that
never gets there is counted as ``budget + 1`` and the table says so. Prints the
Markdown table, then the summary as one JSON line (last line).

Usage::

    python benchmarks/rl_comparison.py --seeds 3 --budget 50
    python benchmarks/rl_comparison.py --seeds 10 --budget 50 --rl-budget 100 --out out/rl_comparison

Ctrl-C stops it and prints what finished; rerunning with the same ``--out`` resumes.
The full report of one study is ``gbo bench rl_comparison``.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.analysis import (
    load_results,
    ratio_curves,
    resolve_thresholds,
    study_ground_truth,
    threshold_table,
    twin_activations,
)
from evaluation.study import Study, TunerEntry, load_study
from evaluation.study_runner import run_study

#: The shipped studies of the comparison, one per env.
STUDIES = ("rl_comparison", "rl_comparison_rig")


def configure(study: Study, seeds: int, budget: int, rl_budget: int | None = None, pretrain_steps: int | None = None,
              include_ppo: bool = False, resolution: int | None = None) -> list[Study]:
    """The study with ``seeds`` batches and these budgets, split into one study per plant budget.

    Parameters
    ----------
    study : Study
        A shipped RL comparison study.
    seeds : int
        Batches (seeds ``seed .. seed + seeds - 1``), ``>= 1``.
    budget : int
        Plant experiments per run of the BO methods (and of RL unless ``rl_budget``), ``>= 1``.
    rl_budget : int, optional
        Plant experiments per RL run.
    pretrain_steps : int, optional
        Model experiments of the train-on-model RL before deployment (default: the spec's).
    include_ppo : bool, default False
        Add PPO on the plant besides SAC.
    resolution : int, optional
        Ground-truth grid points per gain (default: the spec's), ``>= 2``.
    """
    if int(budget) < 1:
        raise ValueError(f"budget: must be an integer >= 1, got {budget}")
    tuners = []
    for entry in study.tuners:
        if pretrain_steps is not None and "pretrain_steps" in entry.params:
            entry = replace(entry, params={**entry.params, "pretrain_steps": int(pretrain_steps)})
        tuners.append(entry)
    if include_ppo:
        tuners.append(TunerEntry(name="rl", label="RL PPO (plant)", params={"algorithm": "ppo", "mode": "plant"},
                                 group="RL PPO (plant)"))
    if resolution is not None and int(resolution) < 2:
        raise ValueError(f"resolution: must be an integer >= 2, got {resolution}")
    study = replace(study.with_batches(seeds), budget=int(budget), tuners=tuple(tuners),
                    resolution=study.resolution if resolution is None else int(resolution))
    rl_budget = int(budget) if rl_budget is None else int(rl_budget)
    if rl_budget == study.budget:
        return [study]
    if rl_budget < 1:
        raise ValueError(f"rl_budget: must be an integer >= 1, got {rl_budget}")
    rl = tuple(entry for entry in tuners if entry.name == "rl")
    others = tuple(entry for entry in tuners if entry.name != "rl")
    return [part for part in (replace(study, tuners=others), replace(study, tuners=rl, budget=rl_budget))
            if part.tuners]


def summarise(study: Study, out: Path) -> dict[str, Any]:
    """Per method of ``study``: experiments to each ratio threshold, model experiments and final ratio.

    Returns
    -------
    dict
        ``env_id``, ``optimum`` (``J(theta*)``) and ``rows``: one dict per method
        with ``method, budget, n_runs, model_experiments, twin_evaluations,
        final_ratio_mean`` and, per threshold label, ``mean, median, reached``.
    """
    frame = load_results(out, study)
    truth = study_ground_truth(study, out)
    thresholds = resolve_thresholds(study, truth)
    rows = []
    if len(frame):
        curves = ratio_curves(frame, truth.cost, budget=study.budget, order=study.labels, rule="incumbent")
        table = threshold_table(curves, thresholds)
        twins = twin_activations(frame, order=study.labels)
        for label, curve in curves.items():
            info = [json.loads(text) for text in frame.loc[frame["tuner"] == label].groupby("batch")["info"].first()]
            row: dict[str, Any] = {
                "method": label, "budget": study.budget, "n_runs": int(curve.shape[0]),
                "model_experiments": int(np.mean([i.get("model_experiments", 0) for i in info])),
                "twin_evaluations": float(twins.loc[twins["tuner"] == label, "twin_evaluations"].mean()),
                "final_ratio_mean": float(np.nanmean(curve[:, -1]))}
            for stats in table[table["tuner"] == label].itertuples():
                row[stats.threshold] = {"mean": stats.mean, "median": stats.median, "reached": stats.n - stats.never}
            rows.append(row)
    return {"env_id": study.env_id, "optimum": float(truth.cost), "thresholds": list(thresholds), "rows": rows}


def markdown_table(summaries: list[dict[str, Any]]) -> str:
    """The summaries as one Markdown table, saying plainly when a threshold was never reached."""
    thresholds = list(dict.fromkeys(t for s in summaries for t in s["thresholds"]))
    header = ["env", "method", "plant budget", "model exps (RL pre-training) / twin evals (mean)"]
    header += [f"real exps to {t} (mean / median, reached)" for t in thresholds] + ["final phi (mean)"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for summary in summaries:
        for row in summary["rows"]:
            budget, n = row["budget"], row["n_runs"]
            cells = [summary["env_id"].split("/")[-1], row["method"], str(budget),
                     f"{row['model_experiments']} / {row['twin_evaluations']:.0f}"]
            for threshold in thresholds:
                stats = row[threshold]
                if stats["reached"] == 0:
                    cells.append(f"never within {budget} (0/{n}; counted as {budget + 1})")
                else:
                    note = "" if stats["reached"] == n else f"; misses counted as {budget + 1}"
                    cells.append(f"{stats['mean']:.1f} / {stats['median']:.0f} ({stats['reached']}/{n}{note})")
            cells.append(f"{row['final_ratio_mean']:.3f}")
            lines.append("| " + " | ".join(cells) + " |")
    notes = [f"J(theta*) {s['env_id'].split('/')[-1]} = {s['optimum']:.4f}"
             for s in {s["env_id"]: s for s in summaries}.values()]
    return "\n".join(lines) + ("\n\n" + "; ".join(notes) if notes else "")


def compare(studies: list[Study], out: Path, workers: int | None = None, progress: bool = True) -> dict[str, Any]:
    """Run every study under ``out/<study name>`` (resuming finished batches) and summarise each.

    Returns
    -------
    dict
        ``summaries`` (:func:`summarise` of each study), ``batches_run`` (batches
        run by this call) and ``interrupted`` (Ctrl-C: later studies were not run).
    """
    summaries, batches_run, interrupted = [], 0, False
    for study in studies:
        folder = Path(out) / study.name
        if not interrupted:
            run = run_study(study, folder, workers=workers, progress=progress)
            batches_run, interrupted = batches_run + run.completed, run.interrupted
        summaries.append(summarise(study, folder))
    return {"interrupted": interrupted, "batches_run": batches_run, "summaries": summaries}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--studies", nargs="*", default=list(STUDIES), help="shipped study names or spec paths")
    parser.add_argument("--seeds", type=int, default=3, help="seeds (batches) per method")
    parser.add_argument("--budget", type=int, default=50, help="plant experiments per BO / guided-BO run")
    parser.add_argument("--rl-budget", type=int, default=None, help="plant experiments per RL run (default: --budget)")
    parser.add_argument("--pretrain-steps", type=int, default=None, help="model experiments of train-on-model RL")
    parser.add_argument("--ppo", action="store_true", help="add PPO (plant mode)")
    parser.add_argument("--resolution", type=int, default=None, help="ground-truth grid points per gain")
    parser.add_argument("--out", type=Path, default=Path("out/rl_comparison"), help="results folder (resume)")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default: all cores)")
    args = parser.parse_args(argv)
    studies = [part for name in args.studies
               for part in configure(load_study(name), args.seeds, args.budget, args.rl_budget, args.pretrain_steps,
                                     args.ppo, args.resolution)]
    comparison = compare(studies, args.out, workers=args.workers)
    print(markdown_table(comparison["summaries"]))
    if comparison["interrupted"]:
        print("\ninterrupted: the table holds the finished runs; rerun with the same --out to resume")
    print(json.dumps(comparison))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
