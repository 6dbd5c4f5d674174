"""One-off: the former benchmark scripts' run logs as curves of the engine's studies and suite references.

For each log ``benchmarks/results/*_runs.jsonl`` and the study that replaces its script
(``evaluation/studies/<study>.toml``), every logged run becomes a curves row
(:mod:`evaluation.curves`) of the run the study plans for the same plant, tuner and
seed: its best-ratio curve as logged, the ``J*`` it was divided by, its timings and
the tuner's figures, and the commit that wrote the line (``git blame``). They are
written to ``docs/reports/<study>/curves.parquet``; ``gbo bench <study> --report-only
--out docs/reports/<study>`` then regenerates the table.

``--references`` adds the logged runs of reference tuners on the suite's plants and
seeds to ``evaluation/references/`` (those the suite has no engine run of), each with
the fingerprint of the code at its commit (:mod:`evaluation.fingerprint`).

``--check N`` reruns N seeds of every (study, plant, tuner) through the engine
(:func:`evaluation.study_runner.run_batch`) and compares the curves with the logged
ones bit for bit (the engine's curve divided by the logged ``J*``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
sys.path.insert(0, str(ROOT))

from evaluation.curves import CURVE_COLUMNS, read_curves, write_curves  # noqa: E402
from evaluation.study import load_study  # noqa: E402
from evaluation.study_runner import plan_batches  # noqa: E402

TRUTH = json.loads((RESULTS / "ground_truth.json").read_text())
MOVING = json.loads((RESULTS / "time_varying_optima.json").read_text())

#: study -> [(log, the log's label of the tuner -> the study's label, plant field, label field)]
LOGS = {
    "guided_bo_ablation": [("guided_bo_ablation_runs.jsonl", None, "plant", "variant")],
    "effect_aware": [("effect_aware_runs.jsonl", None, "plant", "tuner")],
    "time_varying": [("time_varying_runs.jsonl", None, "plant", "variant")],
    "guided_bo_oracle": [("guided_bo_oracle_runs.jsonl", None, "plant", "variant")],
    "mf_bo": [("mf_bo_runs.jsonl", None, "plant", "variant"),
              ("guided_bo_ablation_runs.jsonl", {"bo": "bo", "guided-bo": "guided-bo"}, "plant", "variant")],
    "peers": [("peers_runs.jsonl", None, "env", "row"),
              ("guided_bo_ablation_runs.jsonl", {"guided-bo": "guided-bo", "bo, envelope settling": "bo-envelope"},
               "plant", "variant")],
    "discrimination": [("discrimination_runs.jsonl", None, "env", "tuner")],
}
#: the suite's reference tuners taken from logs: reference label -> [(study, study label)]
REFERENCE_LOGS = {
    "guided-bo": [("guided_bo_ablation", "guided-bo"), ("time_varying", "guided-bo")],
    "mf-bo": [("mf_bo", "mf-bo")],
    "botorch": [("peers", "botorch")],
    "optuna-gp": [("peers", "optuna-gp")],
    "skopt": [("peers", "skopt")],
    "bayes-opt": [("peers", "bayes-opt")],
}


def blame(name: str) -> list[str]:
    """The commit that wrote each line of ``benchmarks/results/<name>``."""
    out = subprocess.run(["git", "-C", str(ROOT), "blame", "--line-porcelain", f"benchmarks/results/{name}"],
                         capture_output=True, text=True, check=True).stdout
    commits, current = [], None
    for line in out.splitlines():
        head = line.split(" ")
        if len(head[0]) == 40 and all(c in "0123456789abcdef" for c in head[0]) and len(head) >= 3:
            current = head[0]
        elif line.startswith("\t"):
            commits.append(current)
    return commits


def optimum(log: str, run: dict, plant: str) -> float:
    if "optimum" in run:
        return float(run["optimum"])
    if log == "time_varying_runs.jsonl":
        return float(MOVING[plant][0])
    return float(TRUTH[plant]["cost"])


def summary(run: dict) -> dict:
    keys = ("activations", "distrusts", "repeats", "reinitializations", "twin_evaluations", "effects", "twin_changes",
            "fidelity", "cpu_per_experiment")
    out = {key: run[key] for key in keys if key in run}
    if isinstance(out.get("twin_changes"), list):
        out["twin_changes"] = [{"experiment": c.get("experiment"), "effects": sorted(c.get("effects") or {}),
                                "rmse": c.get("rmse")} for c in out["twin_changes"]]
    return out


def convert(study_name: str) -> pd.DataFrame:
    """The logged runs of a study as curves rows, one per planned run (the study's own log first)."""
    study = load_study(study_name)
    tasks = {(t.plant, t.label, t.seed): t for t in plan_batches(study)}
    rows: dict = {}
    for log, mapping, plant_key, label_key in LOGS[study_name]:
        lines = (RESULTS / log).read_text().splitlines()
        commits = blame(log)
        mine: dict = {}
        for line, commit in zip(lines, commits):
            run = json.loads(line)
            plant = run[plant_key].rsplit("/", 1)[-1]
            label = run[label_key] if mapping is None else mapping.get(run[label_key])
            task = tasks.get((plant, label, run["seed"]))
            if task is None:
                continue
            best = optimum(log, run, plant)
            mine[(plant, label, run["seed"])] = {
                "study": study.name, "plant": plant, "tuner": label, "tuner_name": task.tuner,
                "params": json.dumps(task.params), "env_id": task.env_id, "env_kwargs": json.dumps(task.env_kwargs),
                "budget": task.budget, "batch": task.batch, "seed": task.seed, "key": task.key, "file": task.filename,
                "curve": [float(v) for v in run["ratios"]],
                "instant": run.get("instant", run.get("true_ratios")), "optimum": best,
                "seconds": float(run.get("seconds", np.nan)), "cpu_seconds": float(run.get("cpu_seconds", np.nan)),
                "plant_cpu_seconds": float(run.get("plant_cpu_seconds", np.nan)),
                "summary": json.dumps(summary(run)),
                "source": f"benchmarks/results/{log}" + (f" ({run['source']})" if run.get("source") else ""),
                "commit": commit}
        for key, row in mine.items():  # the study's own log first; later logs only fill what it lacks
            rows.setdefault(key, row)
    order = {(t.plant, t.label, t.seed): i for i, t in enumerate(tasks.values())}
    frame = pd.DataFrame(sorted(rows.values(), key=lambda r: order[(r["plant"], r["tuner"], r["seed"])]))
    return frame


def write_study(study_name: str, frame: pd.DataFrame) -> Path:
    out = ROOT / "docs" / "reports" / study_name
    out.mkdir(parents=True, exist_ok=True)
    path = write_curves(frame.reindex(columns=CURVE_COLUMNS), out / "curves.parquet")
    (out / "study.toml").write_text((ROOT / "evaluation" / "studies" / f"{study_name}.toml").read_text())
    return path


def references(converted: dict[str, pd.DataFrame]) -> None:
    """Add the logged runs of reference tuners to the shipped references (where they have no engine run)."""
    from evaluation import fingerprint
    from evaluation.references import FINGERPRINT_COLUMNS, plant_hash, reference_file, write_references
    from evaluation.suite import load_suite

    suite = load_suite("standard")
    tasks = {(t.plant, t.label, t.seed): t for t in plan_batches(suite)}
    hashes: dict = {}
    for label, sources in REFERENCE_LOGS.items():
        entry = suite.tuner(label)
        parts = []
        for study_name, study_label in sources:
            frame = converted[study_name]
            for row in frame[frame["tuner"] == study_label].to_dict("records"):
                task = tasks.get((row["plant"], label, row["seed"]))
                if task is None:
                    continue
                commit = row["commit"]
                if (commit, label, task.env_id) not in hashes:
                    tree = fingerprint.SourceTree(commit)
                    hashes[(commit, label, task.env_id)] = (
                        fingerprint.source_hash(fingerprint.tuner_modules(entry.name, tree), tree),
                        plant_hash(task.env_id, tree))
                tuner_hash, plant = hashes[(commit, label, task.env_id)]
                parts.append({**row, "study": suite.name, "tuner": label, "tuner_name": entry.name,
                              "params": json.dumps(task.params), "key": task.key, "file": task.filename,
                              "batch": task.batch, "tuner_hash": tuner_hash, "plant_hash": plant,
                              "source": row["source"]})
        new = pd.DataFrame(parts)
        path = reference_file(label)
        old = read_curves(path)
        if len(old):
            new = new[~new["file"].isin(set(old["file"]))]
            new = pd.concat([old, new], ignore_index=True)
        order = {p.label: i for i, p in enumerate(suite.plants)}
        new = new.sort_values(["plant", "batch"], key=lambda s: s.map(order) if s.name == "plant" else s,
                              kind="stable")
        write_references(new.reindex(columns=CURVE_COLUMNS + FINGERPRINT_COLUMNS), path)
        print(f"reference {label}: {len(new)} runs in {path.relative_to(ROOT)}")


def check(study_name: str, frame: pd.DataFrame, seeds: int) -> list[dict]:
    """Rerun ``seeds`` seeds of every plant and tuner of the study and compare the curves with the logged ones."""
    from evaluation.study_runner import best_true_cost_now, run_batch  # noqa: F401

    study = load_study(study_name)
    tasks = {(t.plant, t.label, t.seed): t for t in plan_batches(study)}
    picked = defaultdict(list)
    for row in frame.to_dict("records"):
        if len(picked[(row["plant"], row["tuner"])]) < seeds:
            picked[(row["plant"], row["tuner"])].append(row)
    out = []
    for (plant, label), rows in picked.items():
        for row in rows:
            result = run_batch(tasks[(plant, label, row["seed"])])
            part = result[result["source"] == "plant"].sort_values("experiment")
            best = np.asarray(MOVING[plant], dtype=float)[: len(part)] if plant in MOVING else row["optimum"]
            curve = part["best_true_cost_now"].to_numpy(dtype=float) / best
            logged = np.asarray(row["curve"], dtype=float)
            same = curve.shape == logged.shape and bool(np.array_equal(curve, logged))
            gap = float(np.max(np.abs(curve - logged))) if curve.shape == logged.shape else None
            out.append({"study": study_name, "plant": plant, "tuner": label, "seed": row["seed"],
                        "commit": row["commit"][:10], "identical": same,
                        "within_1e-12": gap is not None and gap < 1e-12, "max_abs_diff": gap,
                        "seconds": round(float(part["batch_wall_time"].iloc[0]), 1)})
            print(json.dumps(out[-1]), flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--studies", nargs="+", default=list(LOGS), choices=list(LOGS))
    parser.add_argument("--references", action="store_true", help="also add the logged reference runs")
    parser.add_argument("--check", type=int, default=0, metavar="N", help="rerun N seeds per plant and tuner")
    parser.add_argument("--check-tuners", nargs="*", help="only these tuner labels in --check")
    parser.add_argument("--check-plants", nargs="*", help="only these plant labels in --check")
    parser.add_argument("--no-write", action="store_true", help="do not write the studies' curves (with --check)")
    args = parser.parse_args()
    converted = {}
    for name in dict.fromkeys([*args.studies, *(s for v in REFERENCE_LOGS.values() for s, _ in v)]
                              if args.references else args.studies):
        converted[name] = convert(name)
        if name in args.studies and not args.no_write:
            print(f"{name}: {len(converted[name])} runs -> {write_study(name, converted[name]).relative_to(ROOT)}")
    if args.references:
        references(converted)
    if args.check:
        results = []
        for name in args.studies:
            frame = converted[name]
            if args.check_tuners:
                frame = frame[frame["tuner"].isin(args.check_tuners)]
            if args.check_plants:
                frame = frame[frame["plant"].isin(args.check_plants)]
            results += check(name, frame, args.check)
        print(json.dumps({"checked": len(results), "identical": sum(r["identical"] for r in results),
                          "within_1e-12": sum(r["within_1e-12"] for r in results)}))


if __name__ == "__main__":
    main()
