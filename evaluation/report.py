"""Report of a study: spec, our numbers beside the paper's, figures, runtime and notes.

:func:`write_report` reads the finished batches under ``OUT/results``, writes the
PNG figures next to ``OUT/report.md`` and links them relatively, so the folder
can be committed (``docs/reports/<study>/``) and read on GitHub. Beside it,
``OUT/report.html`` is the same report as one self-contained page (figures
inline, tables that scroll on a phone; :func:`evaluation.markdown_page.write_html`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd

from evaluation import analysis, figures
from evaluation.comparison import write_comparison
from evaluation.markdown_page import markdown_table, write_html
from evaluation.study import Study
from evaluation.suite import study_leaderboard
from gbo_envs.atomic_write import atomic_write

__all__ = ["write_report", "write_figures", "write_html", "markdown_table"]


def write_figures(study: Study, out: Path, frame: pd.DataFrame, truth, thresholds: dict[str, float]) -> dict:
    """Write the study's PNGs into ``out``; returns figure key -> file name."""
    out = Path(out)
    labels = analysis.tuner_order(frame, study.labels)
    written = {}
    curves = analysis.ratio_curves(frame, truth.cost, budget=study.budget, order=labels)
    fig = figures.ratio_curve_figure(curves, thresholds, bands=study.report.get("bands"),
                                     title=f"{study.name}: minimum observed optimality ratio")
    written["curves"] = figures.save(fig, out / "ratio_curves.png").name

    ratios = analysis.measured_ratios(frame, truth.cost, order=labels)
    edges = analysis.histogram_edges(ratios, study.report.get("histogram_bins", 20), study.report.get("histogram_max"))
    fig = figures.histogram_figure(analysis.histogram_table(ratios, edges),
                                   title=f"{study.name}: measured optimality ratios of all plant experiments")
    written["histogram"] = figures.save(fig, out / "histogram.png").name

    if len(truth.gain_names) == 2:
        batch = int(study.report.get("surface_batch", 0))
        if batch not in set(frame["batch"]):
            batch = int(frame["batch"].min())
        tuners = study.report.get("surface_tuners") or labels[:6]
        fig = figures.cost_surface_figure(truth, frame, batch=batch, tuners=[t for t in tuners if t in labels])
        written["surface"] = figures.save(fig, out / "cost_surface.png").name
        written["surface_batch"] = batch

    twin = analysis.twin_activations(frame, order=labels)
    if twin["twin_evaluations"].sum() > 0:
        fig = figures.activations_figure(twin, title=f"{study.name}: twin activations per batch")
        written["activations"] = figures.save(fig, out / "activations.png").name

    param = _sweep_param(study)
    if param:
        sweeps = {entry.label: entry.sweep for entry in study.tuners}
        table = analysis.sweep_table(frame, truth.cost, thresholds, sweeps, param, study.threshold_offset)
        if len(table) >= 2:
            references = _references(study, frame, truth.cost, thresholds, param)
            fig = figures.sweep_figure(table, param, references, title=f"{study.name}: sweep over {param}")
            written["sweep"] = figures.save(fig, out / "sweep.png").name
            written["sweep_table"] = table
    return written


def _sweep_param(study: Study) -> str | None:
    if "sweep_param" in study.report:
        return study.report["sweep_param"]
    swept = [key for entry in study.tuners for key in entry.sweep]
    return swept[0] if swept and len(set(swept)) == 1 else None


def _references(study: Study, frame, optimum, thresholds, param) -> dict:
    labels = [e.label for e in study.tuners if param not in e.sweep and e.label in set(frame["tuner"])]
    if not labels:
        return {}
    sub = frame[frame["tuner"].isin(labels)]
    curves = analysis.ratio_curves(sub, optimum, budget=study.budget, order=labels)
    summary = analysis.summary_table(sub, optimum, order=labels).set_index("tuner")
    refs = {}
    for label in labels:
        ref = {f"to {name}": float(analysis.experiments_to_threshold(curves[label], ratio,
                                                                     study.threshold_offset).mean())
               for name, ratio in thresholds.items()}
        ref["mean_measured_ratio"] = float(summary.loc[label, "mean_measured_ratio"])
        refs[label] = ref
    return refs


def write_report(study: Study, out: Path | str, frame: pd.DataFrame | None = None) -> Path:
    """Write ``out/report.md`` and its figures from the finished batches under ``out``.

    A study of several plants gets its comparison table instead (:func:`evaluation.comparison.write_comparison`),
    or the leaderboard of its tuners (``[report] table = "leaderboard"``, :func:`evaluation.suite.study_leaderboard`).

    Parameters
    ----------
    study : Study
    out : Path
        The study's output folder (as given to :func:`evaluation.study_runner.run_study`).
    frame : DataFrame, optional
        The tidy results (default: :func:`evaluation.analysis.load_results`).

    Returns
    -------
    Path
        The report file.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if study.per_plant:
        if study.report.get("table") == "leaderboard":
            return study_leaderboard(study, out)["md"]

        path = write_comparison(study, out)
        write_html(path, title=study.title)
        return path
    frame = analysis.load_results(out, study) if frame is None else frame
    lines = [f"# {study.title}", ""]
    if study.description:
        lines += [study.description.strip(), ""]
    lines += [f"Generated {time.strftime('%Y-%m-%d %H:%M')} by `gbo bench {study.name}` from "
              f"`{_rel(study.path)}`.", ""]
    if frame.empty:
        lines += ["No finished batches yet: run `gbo bench` first.", ""]
        return _write_markdown(out / "report.md", lines, study.title)

    truth = analysis.study_ground_truth(study, out)
    thresholds = analysis.resolve_thresholds(study, truth)
    labels = analysis.tuner_order(frame, study.labels)
    curves = analysis.ratio_curves(frame, truth.cost, budget=study.budget, order=labels)
    written = write_figures(study, out, frame, truth, thresholds)

    lines += _setup_section(study, frame, truth, thresholds)
    lines += _threshold_section(study, curves, thresholds)
    lines += ["## Minimum observed optimality ratio", "",
              "Mean over batches (thick line) and the 68/90/95/99 % percentile bands across batches, as in the "
              "paper's figures; dashed lines are the thresholds.", "", f"![ratio curves]({written['curves']})", ""]
    lines += _summary_section(study, frame, truth)
    lines += ["## Measured optimality ratios", "",
              "All plant experiments' measured (noisy) cost over J*, as the paper's histograms.", "",
              f"![histogram]({written['histogram']})", ""]
    lines += _gains_section(study, frame, truth)
    if "surface" in written:
        lines += ["## Queried gains on the cost surface", "",
                  f"Batch {written['surface_batch']}: filled circles are plant experiments (numbered in order), "
                  "hollow circles twin evaluations, the star the grid optimum.", "",
                  f"![cost surface]({written['surface']})", ""]
    if "activations" in written:
        lines += ["## Twin activations", "", f"![activations]({written['activations']})", ""]
    if "sweep" in written:
        table = written["sweep_table"]
        lines += [f"## Sweep over {_sweep_param(study)}", "", f"![sweep]({written['sweep']})", "",
                  markdown_table(list(table.columns), table.values.tolist()), ""]
    lines += _timing_section(study, frame, out)
    if study.paper.get("text"):
        lines += ["## What the paper reports", "", study.paper["text"].strip(), ""]
    if study.notes.strip():
        lines += ["## Notes", "", study.notes.strip(), ""]
    if study.text:
        language = "yaml" if study.path is not None and study.path.suffix in (".yaml", ".yml") else "toml"
        lines += ["## Spec", "", f"```{language}", study.text.rstrip(), "```", ""]
    return _write_markdown(out / "report.md", lines, study.title)


def _write_markdown(path: Path, lines: list[str], title: str) -> Path:
    """Write ``lines`` to ``path`` atomically, and its HTML page beside it (:func:`write_html`)."""
    with atomic_write(path) as handle:
        handle.write("\n".join(lines))
    write_html(path, title=title)
    return path


# -- sections -----------------------------------------------------------------------------------------
def _setup_section(study: Study, frame, truth, thresholds) -> list[str]:
    batches = frame.groupby("tuner")["batch"].nunique()
    done = int(batches.min()) if len(batches) else 0
    names = truth.gain_names
    lines = ["## Setup", "",
             f"- env: `{study.env_id}` with kwargs `{json.dumps(study.env_kwargs)}`",
             f"- batches: {done} finished per tuner (spec: {study.batches}); budget: {study.budget} plant "
             f"experiments per batch; N0 = {study.n_initial}; seeds {study.seed} .. {study.seed + study.batches - 1} "
             "(batch i uses seed + i for the env and every tuner)",
             f"- ground truth ({study.resolution} x {study.resolution} grid): "
             + ", ".join(f"{n} = {g:.4g}" for n, g in zip(names, truth.gains)) + f", J* = {truth.cost:.4g}",
             "- experiments to threshold count the N0 initial experiments" if study.count_initial else
             f"- experiments to threshold exclude the N0 = {study.n_initial} initial experiments (as the paper)",
             "", "Tuners:", ""]
    rows = [[entry.label, f"`{entry.name}`", f"`{json.dumps(entry.params)}`"] for entry in study.tuners]
    lines += [markdown_table(["label", "tuner", "params"], rows), ""]
    if thresholds:
        rows = []
        for threshold in study.thresholds:
            source = "given" if threshold.ratio is not None else "J(" + ", ".join(f"{g:g}" for g in threshold.gains) \
                + ") / J* on the env"
            rows.append([threshold.label, thresholds[threshold.label], threshold.paper_ratio, source])
        lines += ["Thresholds (optimality ratios):", "",
                  markdown_table(["threshold", "ratio (ours)", "ratio (paper)", "from"], rows), ""]
    return lines


def _threshold_section(study: Study, curves, thresholds) -> list[str]:
    if not thresholds:
        return []
    table = analysis.threshold_table(curves, thresholds, study.threshold_offset)
    paper = {(row["tuner"], row["threshold"]): row for row in study.paper.get("thresholds", [])}
    has_paper = bool(paper)
    headers = ["tuner", "threshold", "mean", "best", "worst", "never reached"]
    if has_paper:
        headers += ["paper mean", "paper best", "paper worst", "mean: ours - paper"]
    rows = []
    for _, row in table.iterrows():
        line = [row["tuner"], row["threshold"], row["mean"], row["best"], row["worst"],
                f"{row['never']} of {row['n']}"]
        if has_paper:
            ref = paper.get((row["tuner"], row["threshold"]), {})
            paper_mean = ref.get("mean")
            gap = row["mean"] - paper_mean if isinstance(paper_mean, (int, float)) else None
            line += [paper_mean, ref.get("best"), ref.get("worst"), gap]
        rows.append(line)
    never = (f"budget + 1 = {study.budget + 1}" if not study.threshold_offset else
             f"budget + 1 - N0 = {study.budget + 1 - study.threshold_offset}")
    return ["## Plant experiments to reach each threshold", "",
            f"First plant experiment whose minimum observed ratio is <= the threshold; batches that never reach "
            f"it count as {never}.", "", markdown_table(headers, rows), ""]


def _summary_section(study: Study, frame, truth) -> list[str]:
    labels = analysis.tuner_order(frame, study.labels)
    summary = analysis.summary_table(frame, truth.cost, order=labels)
    headers = ["tuner", "batches", "final ratio (mean)", "final ratio (median)", "mean measured ratio",
               "twin activations / batch", "twin evaluations / batch"]
    rows = summary[["tuner", "batches", "final_ratio", "final_ratio_median", "mean_measured_ratio", "activations",
                    "twin_evaluations"]].values.tolist()
    lines = ["## Summary per tuner", "", markdown_table(headers, rows), ""]
    metrics = study.paper.get("metrics", [])
    if metrics:
        indexed = summary.set_index("tuner")
        rows = [[m["tuner"], m["metric"], m["value"],
                 float(indexed.loc[m["tuner"], m["metric"]]) if m["tuner"] in indexed.index else None]
                for m in metrics]
        lines += ["Beside the paper:", "", markdown_table(["tuner", "metric", "paper", "ours"], rows), ""]
    return lines


def _gains_section(study: Study, frame, truth) -> list[str]:
    names = list(truth.gain_names)
    at = int(study.report.get("gains_at", study.budget))
    labels = analysis.tuner_order(frame, study.labels)
    table = analysis.best_gains_table(frame, truth.cost, names, at_experiment=at, order=labels)
    rows = [["ground truth (grid)", "ours", *truth.gains.tolist(), truth.cost, 1.0]]

    env = None
    for threshold in study.thresholds:
        if threshold.gains is not None and len(threshold.gains) == len(names):
            env = env or gym.make(study.env_id, **study.env_kwargs)
            cost = float(env.unwrapped.evaluate(np.asarray(threshold.gains)[None, :], experiment_index=0)[1][0])
            rows.append([threshold.label, "ours", *threshold.gains, cost, cost / truth.cost])
    for _, row in table.iterrows():
        rows.append([row["tuner"], f"ours, median of {frame.loc[frame['tuner'] == row['tuner'], 'batch'].nunique()} "
                     f"batches at n = {at}", *[row[n] for n in names], row["true_cost"], row["ratio"]])
    paper_rows = study.paper.get("gains", [])
    optimum = next((r.get("cost") for r in paper_rows if "ground truth" in r["label"].lower()), None)
    for row in paper_rows:
        cost = row.get("cost")
        ratio = row.get("ratio", cost / optimum if cost is not None and optimum else None)
        rows.append([row["label"], "paper", *[row.get(n) for n in names], cost, ratio])
    return ["## Tuned gains", "",
            f"Gains with the lowest measured cost after {at} plant experiments (median over batches) and their "
            "noise-free cost. The paper's J has another normalisation scale, so compare ratios, not J.", "",
            markdown_table(["controller", "source", *names, "J (noise-free)", "ratio J / J*"], rows), ""]


def _timing_section(study: Study, frame, out: Path) -> list[str]:
    labels = analysis.tuner_order(frame, study.labels)
    timing = analysis.timing_table(frame, order=labels)
    rows = timing.values.tolist()
    lines = ["## Tuning time", "",
             "Per batch and per simulated plant experiment (tuner ask/tell plus simulation); per twin evaluation: "
             "the extra time of experiments preceded by twin evaluations over their number (includes twin "
             "identification).", "",
             markdown_table(["tuner", "batches", "batch [s]", "plant experiment [s]", "twin evaluations / batch",
                             "twin evaluation [s]"], rows), ""]
    runs = _read_runs(out)
    if runs:
        total = sum(r["wall_time"] for r in runs)
        batches = sum(r["batches_run"] for r in runs)
        last = runs[-1]
        lines += ["## Runtime", "",
                  f"{batches} batches in {total:.1f} s wall time over {len(runs)} run(s); last run: backend "
                  f"`{last['backend']}`, {last['workers']} worker(s), {last['cpu_count']} cores, "
                  f"{last['wall_time']:.1f} s for {last['batches_run']} batches.", ""]
    return lines


def _read_runs(out: Path) -> list[dict]:
    path = Path(out) / "runs.jsonl"
    if not path.is_file():
        return []
    runs = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            runs.append(json.loads(line))
        except ValueError:
            continue
    return runs


def _rel(path: Path | None) -> str:
    if path is None:
        return "(in memory)"
    try:
        return str(Path(path).resolve().relative_to(Path(__file__).resolve().parents[1]))
    except ValueError:
        return str(path)
