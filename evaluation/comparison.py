"""Comparison tables of a study of several plants: real experiments to each threshold, tuner against tuner.

A ``[[plants]]`` study (:mod:`evaluation.study`) is summarised from its runs as curves
(:mod:`evaluation.curves`): for each plant, threshold and tuner, the real experiments
until the best gains tried reach the threshold's optimality ratio, mean [95 %
Student-t interval] (misses; a run that never reaches it counts as the experiments
counted + 1), on the seeds the compared tuners share. ``[report] table`` picks the
layout:

- ``"versus"``: one row per plant, threshold and tuner, beside the reference tuner
  (``[report] reference``) on the seeds both ran, and their ratio;
- ``"columns"``: one row per plant (and phase, with ``phases = true``: a plant-changing
  env before and after its change) and threshold, one column per tuner, and the ratio
  of the two tuners in ``[report] ratio``;
- ``"sections"``: one table per plant and threshold, one row per tuner, on the seeds
  every tuner that ran all of the reference's seeds shares (a tuner with fewer: on the
  seeds it shares with the reference), with the ratio to the reference;
- ``"paired"``: one row per plant, tuner and threshold for the tuners beside the
  baselines of ``[report] ratio`` (reference first), on the seeds all three ran, with
  the seed-by-seed difference to the second baseline;
- ``"list"``: one row per plant, threshold and tuner, on the tuner's own seeds.

``[report] columns`` adds columns, each ``"key"`` or ``"key:header"`` with a key of
:data:`COLUMNS` (seconds per run, the tuner's CPU time, twin activations, the twin's
effects, ...), computed over the compared tuner's runs of the row.
:func:`write_comparison` writes ``report.md`` (and ``report.csv`` with
``[report] csv = true``).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
from scipy import stats

import gbo_envs  # noqa: F401  (registers the envs)
from evaluation.curves import change_at, experiments_to_target, load_curves, plant_optimum_cell
from evaluation.references import suite_optima
from evaluation.study_runner import plan_batches
from gbo_envs.atomic_write import atomic_write

__all__ = ["COLUMNS", "comparison_lines", "effects_column", "interval", "threshold_ratios", "write_comparison"]


def interval(counts) -> tuple[float, float, float]:
    """Mean of ``counts`` and its 95 % Student-t interval."""
    counts = np.asarray(counts, dtype=float)
    mean = float(np.mean(counts))
    half = float(stats.t.ppf(0.975, counts.size - 1) * np.std(counts, ddof=1) / np.sqrt(counts.size))
    return mean, mean - half, mean + half


def effects_column(keys) -> str:
    """``"saturation (16), linear (3)"``: each key with its count, most frequent first (ties: first seen)."""
    counts: dict[str, int] = {}
    for key in keys:
        counts[key] = counts.get(key, 0) + 1
    return ", ".join(f"{k} ({v})" for k, v in sorted(counts.items(), key=lambda kv: -kv[1]))


def _cell(counts: np.ndarray, miss: int, word: bool = True) -> tuple[float, str]:
    """Mean and ``"mean [low, high] (k misses)"`` (``(k)`` without the word); one count has no interval."""
    misses = int(np.sum(counts >= miss))
    mean, low, high = interval(counts) if counts.size > 1 else (float(counts[0]),) * 3
    return mean, f"{mean:.1f} [{low:.1f}, {high:.1f}] ({misses}{' misses' if word else ''})"


# -- the data of a row --------------------------------------------------------------------------------
@dataclass
class Row:
    """What a table row's columns are computed from.

    Attributes
    ----------
    plant : str
    runs : list of dict
        The compared tuner's runs of the row (its seeds, in order).
    reference : list of dict
        The reference's runs on the same seeds (empty without one).
    others : dict
        Other tuners' runs on the same seeds, by label.
    counts : dict
        Label -> experiments to the row's threshold per run.
    context : dict
        The table's plant-level facts (e.g. ``optimum_shift``).
    """

    plant: str
    runs: list
    reference: list = field(default_factory=list)
    others: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)
    context: dict = field(default_factory=dict)


def _mean(runs, key: str, digits: int = 1, none: str = "-") -> str:
    values = [run.get(key) for run in runs]
    if any(v is None or (isinstance(v, float) and math.isnan(v)) for v in values):
        return none
    return f"{np.mean(values):.{digits}f}"


def _tuner_cpu(row: Row) -> str:
    runs = row.runs
    if any(_missing(r.get("cpu_seconds")) or _missing(r.get("plant_cpu_seconds")) for r in runs):
        return "-"
    cpu = np.array([r["cpu_seconds"] - r["plant_cpu_seconds"] for r in runs])
    return f"{cpu.mean():.1f} [{cpu.min():.1f}, {cpu.max():.1f}]"


def _missing(value) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


def _twin_effects(row: Row) -> str:
    runs = row.runs
    if not all(r.get("effects") is not None and r.get("activations") is not None for r in runs):
        return "-"
    return effects_column("+".join(r["effects"]) or "linear" for r in runs)


def _last_twin(row: Row) -> str:
    def last(run) -> str:
        changes = run.get("twin_changes") or []
        return "+".join(sorted(changes[-1]["effects"])) if changes else ""

    return effects_column(last(r) or "linear" for r in row.runs)


def _cpu_per_experiment(run) -> float:
    if run.get("cpu_per_experiment") is not None:
        return float(run["cpu_per_experiment"])
    return float(run["cpu_seconds"]) / len(run["curve"])


def _paired(row: Row) -> str:
    labels = list(row.counts)
    return "{:+.1f} [{:+.1f}, {:+.1f}]".format(*interval(row.counts[labels[0]] - row.counts[labels[-1]]))


def _final(row: Row) -> str:
    ref = np.mean([r["curve"][-1] for r in row.reference])
    mine = np.mean([r["curve"][-1] for r in row.runs])
    return f"{ref:.3f} / {mine:.3f}"


def _verdict(row: Row) -> str:
    (low_a, high_a), (low_b, high_b) = (interval(c)[1:] for c in row.counts.values())
    return "does not discriminate" if low_a <= high_b and low_b <= high_a else "discriminates"


#: Extra columns: key -> (default header, function of a :class:`Row`).
COLUMNS: dict[str, tuple[str, Callable[[Row], str]]] = {
    "seconds": ("s/run", lambda row: _mean(row.runs, "seconds")),
    "tuner_cpu": ("tuner CPU s/run", _tuner_cpu),
    "cpu": ("CPU s/run", lambda row: _mean(row.runs, "cpu_seconds")),
    "cpu_per_experiment": ("CPU s / real experiment",
                           lambda row: f"{np.mean([_cpu_per_experiment(r) for r in row.runs]):.2f}"),
    "activations": ("activations", lambda row: _mean(row.runs, "activations")),
    "distrusts": ("distrusts", lambda row: _mean(row.runs, "distrusts")),
    "repeats": ("repeats", lambda row: _mean(row.runs, "repeats")),
    "twin_evaluations": ("twin evaluations / run", lambda row: _mean(row.runs, "twin_evaluations")),
    "fidelity": ("final s_twin", lambda row: f"{np.mean([r['fidelity'][-1] for r in row.runs]):.2f}"),
    "effects": ("twin effects at the end (runs)", _twin_effects),
    "effects_found": ("effects found (runs)",
                      lambda row: effects_column("+".join(r.get("effects") or []) or "linear" for r in row.runs)),
    "last_twin": ("effects of the last twin (runs)", _last_twin),
    "paired": ("paired difference", _paired),
    "final_ratio": ("final r", _final),
    "verdict": ("verdict", _verdict),
    "optimum_shift": ("optimum shift (cells)", lambda row: str(row.context.get("optimum_shift"))),
}


def _columns(study) -> list[tuple[str, Callable[[Row], str]]]:
    out = []
    for spec in study.report.get("columns", []):
        key, _, header = spec.partition(":")
        if key not in COLUMNS:
            raise ValueError(f"[report] columns: unknown column {key!r}; known: {', '.join(COLUMNS)}")
        out.append((header or COLUMNS[key][0], COLUMNS[key][1]))
    return out


# -- thresholds ---------------------------------------------------------------------------------------
def threshold_ratios(study, optima: dict[str, np.ndarray]) -> dict[str, list[tuple[str, float, object]]]:
    """Plant label -> ``[(label, ratio, threshold)]``: a ``ratio`` threshold as given, a controller or tuner
    threshold evaluated on the noise-free plant over its ``J*``."""
    out = {}
    for plant in study.plants:
        rows = []
        env = None
        for threshold in study.plant_thresholds(plant):
            if threshold.ratio is None and env is None:
                env = gym.make(plant.env_id, **plant.env_kwargs)
            rows.append((threshold.label, threshold.resolve(env, float(optima[plant.label][0])), threshold))
        out[plant.label] = rows
    return out


def _header(study, key: str, default: str) -> str:
    return study.report.get("headers", {}).get(key, default)


def _level_name(label: str, ratio: float, threshold) -> str:
    return f"ratio {ratio:g}" if threshold.ratio is not None else f"{label} (ratio {ratio:.3f})"


# -- runs ---------------------------------------------------------------------------------------------
def _index(curves: pd.DataFrame) -> dict:
    """``(plant, tuner)`` -> ``{seed: run}`` with a run a dict of its curves row and its summary."""
    index: dict = {}
    for record in curves.to_dict("records"):
        summary = record.pop("summary", None)
        run = {**record, **(json.loads(summary) if isinstance(summary, str) else {})}
        run["curve"] = np.asarray(run["curve"], dtype=float)
        run["instant"] = None if run.get("instant") is None else np.asarray(run["instant"], dtype=float)
        index.setdefault((record["plant"], record["tuner"]), {})[int(record["seed"])] = run
    return index


def _counts(runs, level: float, start: int = 0, end: int | None = None) -> np.ndarray:
    return np.array([experiments_to_target(r["curve"], level, instant=r["instant"], start=start,
                                           budget=end if end is not None else int(r["budget"])) for r in runs])


# -- layouts ------------------------------------------------------------------------------------------
def _versus(study, index, levels, context) -> tuple[list[str], list[dict]]:
    ref = study.report.get("reference", study.labels[0])
    extras = _columns(study)
    header = [_header(study, "plant", "plant"), "threshold", _header(study, "tuner", "variant"), "seeds",
              "variant: real experiments", f"{ref}, same seeds", f"variant / {ref}", *(h for h, _ in extras)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    records = []
    for plant in study.plants:
        mine = {label: index.get((plant.label, label), {}) for label in study.labels}
        if not mine[ref]:
            continue
        for name, level, threshold in levels[plant.label]:
            for label in study.labels:
                seeds = sorted(set(mine[label]) & set(mine[ref]))
                if label == ref or len(seeds) < 2:
                    continue
                runs = [mine[label][s] for s in seeds]
                refs = [mine[ref][s] for s in seeds]
                miss = int(runs[0]["budget"]) + 1
                (m0, c0), (m1, c1) = _cell(_counts(runs, level), miss), _cell(_counts(refs, level), miss)
                row = Row(plant=plant.label, runs=runs, reference=refs, context=context.get(plant.label, {}))
                cells = [plant.label, _level_name(name, level, threshold), label, str(len(seeds)), c0, c1,
                         f"{m0 / m1:.2f}", *(f(row) for _, f in extras)]
                lines.append("| " + " | ".join(cells) + " |")
                records.append({"plant": plant.label, "threshold": name, "ratio": level, "tuner": label,
                                "seeds": len(seeds), "mean": m0, "vs_reference": m0 / m1})
    return lines, records


def _phases(study, plant, budget: int) -> list[tuple[str | None, int, int]]:
    if not study.report.get("phases"):
        return [(None, 0, budget)]
    at = change_at(plant.env_id, plant.env_kwargs)
    if at is None:
        return [("whole run", 0, budget)]
    return [(f"before the change (experiments 1-{at})", 0, at),
            (f"after the change at experiment {at + 1}", at, budget)]


def _columns_layout(study, index, levels, context) -> tuple[list[str], list[dict]]:
    compared, ref = study.report.get("ratio", study.labels[-1:] + study.labels[:1])
    ratio_label = study.report.get("ratio_label", f"{compared} / {ref}")
    extras = _columns(study)
    phase = bool(study.report.get("phases"))
    head = [_header(study, "plant", "plant"), *(["phase"] if phase else []),
            *[h for h, _ in extras if h.startswith("optimum shift")]]
    tail = [h for h, _ in extras if not h.startswith("optimum shift")]
    seeds_header = _header(study, "seeds", "seeds")
    fixed = ["ratio", *([seeds_header] if seeds_header else [])]
    lines = ["| " + " | ".join([*head, *fixed, *study.labels, ratio_label, *tail]) + " |",
             "|" + "---|" * (len(head) + len(fixed) + 1 + len(study.labels) + len(tail))]
    records = []
    for plant in study.plants:
        mine = {label: index.get((plant.label, label), {}) for label in study.labels}
        seeds = sorted(set.intersection(*(set(m) for m in mine.values())))
        if len(seeds) < 2:
            continue
        budget = int(mine[ref][seeds[0]]["budget"])
        for phase_name, start, end in _phases(study, plant, budget):
            for name, level, threshold in levels[plant.label]:
                counts = {label: _counts([mine[label][s] for s in seeds], level, start, end) for label in study.labels}
                cells, means = [], {}
                for label in study.labels:
                    means[label], cell = _cell(counts[label], end - start + 1)
                    cells.append(cell)
                row = Row(plant=plant.label, runs=[mine[compared][s] for s in seeds],
                          reference=[mine[ref][s] for s in seeds],
                          counts={ref: counts[ref], compared: counts[compared]},
                          context=context.get(plant.label, {}))
                values = {h: f(row) for h, f in extras}
                first = [plant.label, *([phase_name] if phase else []), *[values[h] for h in head[1 + phase:]]]
                lines.append("| " + " | ".join([*first, f"{level:g}" if threshold.ratio is None else str(level),
                                                *([str(len(seeds))] if seeds_header else []), *cells,
                                                f"{means[compared] / means[ref]:.2f}",
                                                *[values[h] for h in tail]]) + " |")
                records += [{"plant": plant.label, "phase": phase_name, "threshold": name, "ratio": level,
                             "tuner": label, "seeds": len(seeds), "mean": means[label],
                             "vs_reference": means[label] / means[ref]} for label in study.labels]
    return lines, records


def _sections(study, index, levels, context) -> tuple[list[str], list[dict]]:
    ref = study.report.get("reference", study.labels[0])
    extras = _columns(study)
    records = []
    for plant in study.plants:
        mine = {label: index.get((plant.label, label), {}) for label in study.labels}
        labels = [label for label in study.labels if mine[label]]
        if not labels:
            continue
        reference = set(mine.get(ref, {}))
        full = [label for label in labels if set(mine[label]) >= reference]
        shared = set.intersection(*(set(mine[label]) for label in full)) if full else set()
        seeds_of = {label: sorted(shared if label in full else set(mine[label]) & reference) for label in labels}
        for name, level, _ in levels[plant.label]:
            for label in labels:
                seeds = seeds_of[label]
                if len(seeds) < 2:
                    continue
                runs = [mine[label][s] for s in seeds]
                counts = _counts(runs, level)
                mean, low, high = interval(counts)
                misses = int(sum(c > len(r["curve"]) for c, r in zip(counts, runs)))
                ref_mean = float(np.mean(_counts([mine[ref][s] for s in seeds], level))) if reference else math.nan
                records.append({"plant": plant.label, "threshold": name, "ratio": level, "tuner": label,
                                "seeds": len(seeds), "mean": mean, "ci_low": low, "ci_high": high, "misses": misses,
                                "vs_reference": mean / ref_mean,
                                "seconds": float(np.mean([r["seconds"] for r in runs])),
                                "_row": Row(plant=plant.label, runs=runs)})
    lines = []
    frame = pd.DataFrame(records)
    for (plant, level), group in frame.groupby(["plant", "ratio"], sort=False) if len(frame) else []:
        lines += [f"### {plant}, ratio {level} ({int(group['seeds'].max())} seeds)", ""]
        lines.append(f"| {_header(study, 'tuner', 'tuner')} | experiments to ratio, mean [95 % CI] (misses) | "
                     f"/ {ref} (same seeds) | seeds | "
                     + " | ".join(h for h, _ in extras) + " |")
        lines.append("|---|---|---|---|" + "---|" * len(extras))
        for rec in group.to_dict("records"):
            lines.append(f"| {rec['tuner']} | {rec['mean']:.1f} [{rec['ci_low']:.1f}, {rec['ci_high']:.1f}] "
                         f"({rec['misses']}) | {rec['vs_reference']:.2f} | {rec['seeds']} | "
                         + " | ".join(f(rec["_row"]) for _, f in extras) + " |")
        lines.append("")
    return lines, [{k: v for k, v in rec.items() if k != "_row"} for rec in records]


def _paired_layout(study, index, levels, context) -> tuple[list[str], list[dict]]:
    baselines = study.report.get("ratio", study.labels[:2])
    extras = _columns(study)
    names = [label for label in study.labels if label not in baselines]
    lines = [f"| {_header(study, 'plant', 'plant')} | ratio | seeds | {_header(study, 'tuner', 'variant')} | "
             "variant: real experiments | "
             + " | ".join(baselines) + " | " + " | ".join(f"/ {b}" for b in baselines) + " | "
             + " | ".join(h for h, _ in extras) + " |", "|" + "---|" * (5 + 2 * len(baselines) + len(extras))]
    records = []
    for plant in study.plants:
        base = {b: index.get((plant.label, b), {}) for b in baselines}
        for label in names:
            mine = index.get((plant.label, label), {})
            seeds = sorted(set(mine).intersection(*(set(b) for b in base.values())))
            if len(seeds) < 2:
                continue
            for name, level, _ in levels[plant.label]:
                cells, means, counts = [], [], {}
                for key, runs_of in ((label, mine), *base.items()):
                    runs = [runs_of[s] for s in seeds]
                    counts[key] = _counts(runs, level)
                    mean, low, high = interval(counts[key])
                    misses = int(np.sum(counts[key] > len(runs[0]["curve"])))
                    cells.append(f"{mean:.1f} [{low:.1f}, {high:.1f}] ({misses} misses)")
                    means.append(mean)
                row = Row(plant=plant.label, runs=[mine[s] for s in seeds],
                          counts={label: counts[label], baselines[-1]: counts[baselines[-1]]})
                lines.append(f"| {plant.label} | {level} | {len(seeds)} | {label} | {' | '.join(cells)} | "
                             + " | ".join(f"{means[0] / m:.2f}" for m in means[1:]) + " | "
                             + " | ".join(f(row) for _, f in extras) + " |")
                records.append({"plant": plant.label, "threshold": name, "ratio": level, "tuner": label,
                                "seeds": len(seeds), "mean": means[0], "vs_reference": means[0] / means[1]})
    return lines, records


def _list_layout(study, index, levels, context) -> tuple[list[str], list[dict]]:
    extras = _columns(study)
    lines = [f"| {_header(study, 'plant', 'plant')} | ratio | {_header(study, 'tuner', 'tuner')} | seeds | "
             "real experiments | " + " | ".join(h for h, _ in extras) + " |",
             "|" + "---|" * (5 + len(extras))]
    records = []
    for plant in study.plants:
        for name, level, threshold in levels[plant.label]:
            for label in study.labels:
                mine = index.get((plant.label, label), {})
                if not mine:
                    continue
                runs = [mine[s] for s in sorted(mine)]
                mean, cell = _cell(_counts(runs, level), int(runs[0]["budget"]) + 1)
                row = Row(plant=plant.label, runs=runs)
                shown = str(level) if threshold.ratio is not None else _level_name(name, level, threshold)
                lines.append(f"| {plant.label} | {shown} | {label} | {len(runs)} | {cell} | "
                             + " | ".join(f(row) for _, f in extras) + " |")
                records.append({"plant": plant.label, "threshold": name, "ratio": level, "tuner": label,
                                "seeds": len(runs), "mean": mean})
    return lines, records


LAYOUTS = {"versus": _versus, "columns": _columns_layout, "sections": _sections, "paired": _paired_layout,
           "list": _list_layout}


def _optimum_shifts(study, out: Path | None) -> dict:
    """Plant -> ``{"optimum_shift": cells}``: the grid cell of its ground-truth optimum against that of the
    study's first plant with the same gains (Chebyshev distance in cells of the study's grid); the cells are
    cached in ``out/optima.json`` (:func:`evaluation.curves.plant_optimum_cell`)."""
    cache = None if out is None else Path(out) / "optima.json"
    cells, names, shifts = {}, {}, {}
    for plant in study.plants:
        cells[plant.label], names[plant.label] = plant_optimum_cell(plant.env_id, plant.env_kwargs,
                                                                    study.resolution, cache)
    for plant in study.plants:
        base = next(p.label for p in study.plants if names[p.label] == names[plant.label])
        shifts[plant.label] = {"optimum_shift": int(max(abs(int(a) - int(b)) for a, b in
                                                        zip(cells[plant.label], cells[base])))}
    return shifts


def comparison_lines(study, curves: pd.DataFrame, optima: dict[str, np.ndarray],
                     out: Path | None = None) -> tuple[list[str], pd.DataFrame]:
    """The Markdown lines of the study's comparison table and its rows as a DataFrame (for the CSV).

    Parameters
    ----------
    study : Study
        A ``[[plants]]`` study.
    curves : DataFrame
        Its runs as curves (:func:`evaluation.curves.load_curves`).
    optima : dict
        ``J*_k`` per plant label.
    out : Path, optional
        The study's folder: its ``optima.json`` caches the ground truths' optimum cells.
    """
    layout = study.report.get("table", "versus")
    if layout not in LAYOUTS:
        raise ValueError(f"[report] table: {layout!r} has no comparison layout; expected one of {list(LAYOUTS)}")
    levels = threshold_ratios(study, optima)
    needs_shift = any(spec.partition(":")[0] == "optimum_shift" for spec in study.report.get("columns", []))
    context = _optimum_shifts(study, out) if needs_shift else {}
    lines, records = LAYOUTS[layout](study, _index(curves), levels, context)
    return lines, pd.DataFrame(records)


def write_comparison(study, out: Path | str, curves: pd.DataFrame | None = None,
                     optima: dict[str, np.ndarray] | None = None) -> Path:
    """Write ``out/report.md`` (the comparison table) and, with ``[report] csv = true``, ``out/report.csv``.

    Returns
    -------
    Path
        The report.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if optima is None:
        budgets: dict[str, int] = {}
        for task in plan_batches(study):
            budgets[task.plant] = max(budgets.get(task.plant, 0), task.budget)
        optima = suite_optima(study, budgets, cache=out / "optima.json")
    curves = load_curves(out, study, optima=optima) if curves is None else curves
    lines, table = comparison_lines(study, curves, optima, out)
    caption = study.report.get("caption", "Real experiments to each optimality ratio, mean [95 % CI] (misses; a "
                                           "miss counts as budget + 1).")
    text = [f"# {study.title}", "", caption, "", *lines, ""]
    if study.notes.strip():
        text += ["## Notes", "", study.notes.strip(), ""]
    sources = curves.groupby("source").size().to_dict() if len(curves) else {}
    text += [f"Generated {time.strftime('%Y-%m-%d')} by `gbo bench {study.name}` from {len(curves)} runs "
             f"({', '.join(f'{n} {s}' for s, n in sources.items())}).", ""]
    path = out / "report.md"
    with atomic_write(path) as handle:
        handle.write("\n".join(text))
    if study.report.get("csv"):
        with atomic_write(out / "report.csv") as handle:
            table.round(4).to_csv(handle, index=False)
    return path
