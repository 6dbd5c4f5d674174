"""The leaderboard of the benchmark suite: experiments to the target per plant, one aggregate, runtime ECDFs.

For every tuner and plant of the suite, over the seeds it ran:

- the **mean real experiments to the target** (a run that never reaches it counts as
  its budget + 1 and as a *miss*) with the 95 % bootstrap percentile interval of the mean
  (:func:`mean_interval`: it stays within the counts' range, which a Student-t interval of
  three seeds does not), the misses, and the **ratio to the reference tuner** (``bo``): the tuner's mean over the
  reference's mean on the seeds both ran;
- **one aggregate over the suite**: the geometric mean over the plants of those ratios to
  ``bo`` (1 is ``bo``'s data efficiency, 0.5 needs half its experiments), with a 95 %
  bootstrap interval (the seeds of every plant resampled together for the tuner and
  ``bo``, :attr:`Leaderboard.n_bootstrap` times), and beside it the share of (plant, seed)
  pairs whose target the tuner reached within the budget;
- the **runtime ECDF** of experiments-to-target as in COCO: the fraction of (plant, seed)
  pairs reached within ``x`` real experiments, over all plants and per plant.

Tuners rank by :data:`RANKING_RULE`: the share solved first (a tuner that never reaches a
target is not ahead of one that does, whatever its ratio of misses), then the aggregate.
:class:`Leaderboard` computes it from curves
(:mod:`evaluation.curves`); :func:`write_leaderboard` writes ``leaderboard.md``,
``leaderboard.csv``, ``leaderboard.html`` and the ECDF figures.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from evaluation.curves import experiments_to_target
from evaluation.figures import save
from evaluation.markdown_page import write_html
from gbo_envs.atomic_write import atomic_write
from gbo_envs.lazy_pyplot import pyplot
from gbo_envs.plotting import MEASURED, axis_label, legend_outside, style

__all__ = ["RANKING_RULE", "Leaderboard", "PlantTarget", "mean_interval", "write_leaderboard"]

#: How the aggregate table is ordered, printed above it.
RANKING_RULE = ("Ranked by the share of (plant, seed) pairs solved (higher first), then by the geometric mean "
                "vs the reference (lower first): a tuner that reaches fewer targets ranks below one that reaches "
                "more, whatever its ratio.")
#: Line styles and markers of the ECDF curves, cycled, so that curves drawn over each other stay apart.
LINE_STYLES = ("-", "--", "-.", ":")
MARKERS = ("o", "s", "^", "v", "D", "x", "P", "*")


@dataclass(frozen=True)
class PlantTarget:
    """How one plant's runs are judged.

    Attributes
    ----------
    label : str
    target : float
        Optimality ratio ``J / J*`` to reach (dimensionless).
    budget : int
        Plant experiments per run.
    start : int
        First experiment counted (0-based; the plant change of a plant-changing env judged after it).
    """

    label: str
    target: float
    budget: int
    start: int = 0

    @property
    def miss(self) -> int:
        """The count of a run that never reaches the target: the experiments counted + 1."""
        return self.budget - self.start + 1


def mean_interval(counts, confidence: float = 0.95, n_resamples: int = 2000,
                  seed: int = 0) -> tuple[float, float, float]:
    """Mean of ``counts`` and its bootstrap percentile interval (one count: the mean three times).

    :func:`scipy.stats.bootstrap` with ``method="percentile"``: the quantiles of the means of
    ``n_resamples`` resamples (seeded by ``seed``), so the interval stays within the range of the
    counts (a count of experiments is never negative). BCa is not used: on three seeds of equal counts
    it is undefined.

    Parameters
    ----------
    counts : array_like of shape (n_seeds,)
        Real experiments to the target (count).
    confidence : float, default 0.95
    n_resamples : int, default 2000
    seed : int, default 0

    Returns
    -------
    mean, low, high : float
        In counts.
    """
    counts = np.asarray(counts, dtype=float)
    mean = float(np.mean(counts))
    if counts.size < 2 or np.all(counts == counts[0]):
        return mean, mean, mean
    ci = stats.bootstrap((counts,), np.mean, confidence_level=confidence, method="percentile",
                         n_resamples=n_resamples, rng=np.random.default_rng(seed)).confidence_interval
    return mean, float(ci.low), float(ci.high)


class Leaderboard:
    """Experiments to the target per tuner and plant, the aggregate over the suite and the runtime ECDF.

    Parameters
    ----------
    reference : str, default "bo"
        The tuner every other is compared with (its label in the curves).
    confidence : float, default 0.95
        Coverage of the intervals.
    n_bootstrap : int, default 2000
        Bootstrap resamples of the aggregate's interval.
    seed : int, default 0
        Seed of the bootstrap.

    Attributes
    ----------
    counts_ : DataFrame
        One row per run: ``tuner, plant, seed, count`` (real experiments to the target, ``miss`` for a run
        that never reaches it), ``solved`` and ``violations`` (experiments that broke a constraint of a
        constrained plant, NaN on a plant without constraints).
    table_ : DataFrame
        Per tuner and plant: ``tuner, plant, target, seeds, mean, ci_low, ci_high, misses, vs_reference,
        violations`` (mean per run; NaN without constraints), ``status``.
    aggregate_ : DataFrame
        Per tuner, ranked: ``rank, tuner, plants, geo_mean_vs_reference, ci_low, ci_high, solved, pairs,
        status``.
    plants_ : list of PlantTarget
    tuners_ : list of str
        In the order of the aggregate.
    """

    def __init__(self, *, reference: str = "bo", confidence: float = 0.95, n_bootstrap: int = 2000,
                 seed: int = 0) -> None:
        self.reference = reference
        self.confidence = confidence
        self.n_bootstrap = n_bootstrap
        self.seed = seed

    def fit(self, curves: pd.DataFrame, plants: list[PlantTarget], status: dict | None = None,
            order: list[str] | None = None) -> Leaderboard:
        """Count every run's experiments to its plant's target and summarise.

        Parameters
        ----------
        curves : DataFrame
            Curves rows (:data:`evaluation.curves.CURVE_COLUMNS`): ``tuner, plant, seed, curve, instant``.
        plants : list of PlantTarget
            The suite's plants, in order; runs of other plants are ignored.
        status : dict, optional
            ``(tuner, plant)`` -> a word for the table (e.g. ``"stale"``); default ``""``.
        order : list of str, optional
            Tuner order for ties and for the per-plant tables (default: as they appear).

        Returns
        -------
        Leaderboard
            ``self``.
        """
        by_label = {plant.label: plant for plant in plants}
        rows = []
        for run in curves.itertuples(index=False):
            plant = by_label.get(run.plant)
            if plant is None:
                continue
            count = experiments_to_target(run.curve, plant.target, instant=run.instant, start=plant.start,
                                          budget=plant.budget)
            rows.append({"tuner": run.tuner, "plant": run.plant, "seed": int(run.seed), "count": count,
                         "solved": count < plant.miss, "violations": float(getattr(run, "violations", np.nan))})
        self.counts_ = pd.DataFrame(rows, columns=["tuner", "plant", "seed", "count", "solved", "violations"])
        tuners = list(dict.fromkeys([*(order or []), *self.counts_["tuner"]]))
        tuners = [t for t in tuners if t in set(self.counts_["tuner"])]
        self.plants_ = list(plants)
        status = status or {}
        counts = {key: part.set_index("seed")["count"] for key, part in self.counts_.groupby(["tuner", "plant"])}
        broken = {key: part["violations"] for key, part in self.counts_.groupby(["tuner", "plant"])}
        table = []
        for plant in plants:
            ref = counts.get((self.reference, plant.label))
            for tuner in tuners:
                mine = counts.get((tuner, plant.label))
                if mine is None:
                    table.append({"tuner": tuner, "plant": plant.label, "target": plant.target, "seeds": 0,
                                  "mean": np.nan, "ci_low": np.nan, "ci_high": np.nan, "misses": 0,
                                  "vs_reference": np.nan, "violations": np.nan,
                                  "status": status.get((tuner, plant.label), "no runs")})
                    continue
                mean, low, high = mean_interval(mine.to_numpy(), self.confidence, self.n_bootstrap, self.seed)
                shared = mine.index.intersection(ref.index) if ref is not None else []
                vs = (mine[shared].mean() / ref[shared].mean()) if len(shared) else np.nan
                table.append({"tuner": tuner, "plant": plant.label, "target": plant.target, "seeds": int(mine.size),
                              "mean": mean, "ci_low": low, "ci_high": high,
                              "misses": int((mine >= plant.miss).sum()), "vs_reference": float(vs),
                              "violations": _mean_violations(broken[(tuner, plant.label)]),
                              "status": status.get((tuner, plant.label), "")})
        self.table_ = pd.DataFrame(table, columns=["tuner", "plant", "target", "seeds", "mean", "ci_low", "ci_high",
                                                   "misses", "vs_reference", "violations", "status"])
        self.aggregate_ = self._aggregate(tuners, counts, status)
        self.tuners_ = list(self.aggregate_["tuner"])
        return self

    def _aggregate(self, tuners: list[str], counts: dict, status: dict) -> pd.DataFrame:
        rng = np.random.default_rng(self.seed)
        rows = []
        for tuner in tuners:
            logs, samples, plants = [], [], 0
            for plant in self.plants_:
                mine, ref = counts.get((tuner, plant.label)), counts.get((self.reference, plant.label))
                if mine is None or ref is None:
                    continue
                shared = mine.index.intersection(ref.index)
                if not len(shared):
                    continue
                a, b = mine[shared].to_numpy(dtype=float), ref[shared].to_numpy(dtype=float)
                plants += 1
                logs.append(math.log(a.mean() / b.mean()))
                picks = rng.integers(0, len(shared), size=(self.n_bootstrap, len(shared)))
                samples.append(np.log(a[picks].mean(axis=1) / b[picks].mean(axis=1)))
            solved = self.counts_[self.counts_["tuner"] == tuner]["solved"]
            level = (1 - self.confidence) / 2
            if plants:
                boot = np.exp(np.mean(samples, axis=0))
                geo, low, high = math.exp(np.mean(logs)), *np.quantile(boot, [level, 1 - level])
            else:
                geo = low = high = np.nan
            flags = sorted({status[(tuner, p.label)] for p in self.plants_ if status.get((tuner, p.label))})
            rows.append({"tuner": tuner, "plants": plants, "geo_mean_vs_reference": geo, "ci_low": float(low),
                         "ci_high": float(high), "solved": float(solved.mean()) if len(solved) else np.nan,
                         "pairs": int(len(solved)), "status": ", ".join(flags)})
        frame = pd.DataFrame(rows, columns=["tuner", "plants", "geo_mean_vs_reference", "ci_low", "ci_high", "solved",
                                            "pairs", "status"])
        frame = frame.sort_values(["solved", "geo_mean_vs_reference"], ascending=[False, True], kind="stable",
                                  na_position="last").reset_index(drop=True)  # RANKING_RULE
        frame.insert(0, "rank", np.arange(1, len(frame) + 1))
        return frame

    def to_pandas(self) -> pd.DataFrame:
        """The per-plant table (:attr:`table_`), one row per tuner and plant."""
        return self.table_.copy()

    def ecdf(self, plant: str | None = None) -> pd.DataFrame:
        """The runtime ECDF: ``tuner, experiments, fraction`` of (plant, seed) pairs reached within that many
        real experiments, for ``experiments`` 1 .. the largest budget (or on one ``plant``)."""
        counts = self.counts_ if plant is None else self.counts_[self.counts_["plant"] == plant]
        budgets = [p.miss - 1 for p in self.plants_ if plant is None or p.label == plant]
        xs = np.arange(1, max(budgets, default=1) + 1)
        rows = []
        for tuner in self.tuners_:
            mine = counts[counts["tuner"] == tuner]
            if not len(mine):
                continue
            reached = mine["count"].to_numpy()[mine["solved"].to_numpy()]
            fraction = np.searchsorted(np.sort(reached), xs, side="right") / len(mine)
            rows += [{"tuner": tuner, "experiments": int(x), "fraction": float(f)} for x, f in zip(xs, fraction)]
        return pd.DataFrame(rows, columns=["tuner", "experiments", "fraction"])

    def plot(self, plant: str | None = None, highlight: str | None = None, ax=None):
        """The runtime ECDF over the suite (or one plant): one step line per tuner, x on a log axis.

        Axes: real experiments to the target (count, log scale); fraction of (plant, seed) pairs that
        reached it (-). ``highlight`` (the researcher's tuner) is drawn thick and dark. Every tuner has its
        own line style and marker (:data:`LINE_STYLES`, :data:`MARKERS`), and a curve equal to one drawn
        before it is labelled ``"(same as ...)"`` in the legend: a curve is never hidden without a word.

        Returns
        -------
        matplotlib.figure.Figure
        """
        data = self.ecdf(plant)
        with style():
            if ax is None:
                fig, ax = pyplot().subplots(figsize=(7.5, 4.2))
            else:
                fig = ax.figure
            cmap = pyplot().get_cmap("tab10")
            drawn: dict[str, np.ndarray] = {}
            for i, tuner in enumerate(self.tuners_):
                mine = data[data["tuner"] == tuner]
                if not len(mine):
                    continue
                fraction = mine["fraction"].to_numpy()
                same = [name for name, other in drawn.items() if np.array_equal(other, fraction)]
                drawn[tuner] = fraction
                label = f"{tuner} (same as {', '.join(same)})" if same else tuner
                kwargs = dict(MEASURED, lw=2.4) if tuner == highlight else {"color": cmap(i % 10), "lw": 1.3}
                kwargs.update(ls=LINE_STYLES[i % len(LINE_STYLES)], marker=MARKERS[i % len(MARKERS)], ms=4,
                              markevery=(i % 3, 3))  # markers of coinciding curves at different experiments
                ax.step(mine["experiments"], fraction, where="post", label=label, **kwargs)
            ax.set_xscale("log")
            top = int(data["experiments"].max()) if len(data) else 1
            ticks = [t for t in (1, 2, 3, 5, 10, 20) if t < top] + [top]
            ax.set_xticks(ticks, [str(t) for t in ticks])
            ax.minorticks_off()
            ax.set_ylim(-0.02, 1.02)
            ax.set_xlabel(axis_label("real experiments to the target", "count"))
            pairs = "(plant, seed) pairs" if plant is None else "seeds"
            ax.set_ylabel(axis_label(f"fraction of {pairs} at the target", "-"))
            where = "all plants" if plant is None else plant
            ax.set_title(f"Runtime ECDF, {where}")
            legend_outside(ax)
        return fig


def _mean_violations(values: pd.Series) -> float:
    """Mean violations per run, NaN when no run has constraints."""
    values = values.dropna()
    return float(values.mean()) if len(values) else np.nan


# -- files --------------------------------------------------------------------------------------------
def _cell(row) -> str:
    if not row["seeds"]:
        return "—"
    return f"{row['mean']:.1f} [{row['ci_low']:.1f}, {row['ci_high']:.1f}]"


def _number(value, digits: int = 2) -> str:
    return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def _name(tuner: str, highlight: str | None) -> str:
    """The tuner's cell: the researcher's own in bold with a marker (its HTML row gets the class ``highlight``)."""
    return f"**{tuner}** ◀ yours" if tuner == highlight else tuner


def leaderboard_markdown(board: Leaderboard, title: str, intro: list[str], figures: dict[str, str],
                         notes: list[str], highlight: str | None = None) -> list[str]:
    """The lines of ``leaderboard.md``; the row of ``highlight`` (the researcher's tuner) in bold."""
    ref = board.reference
    level = f"{100 * board.confidence:.0f} %"
    lines = [f"# {title}", "", *intro, ""]
    lines += ["## Ranking", "",
              f"Aggregate: the geometric mean over the plants of each tuner's mean real experiments to the target "
              f"over `{ref}`'s on the same seeds (below 1: fewer experiments than `{ref}`), with its "
              f"{level} bootstrap interval ({board.n_bootstrap} resamples of the seeds); solved: the "
              "share of (plant, seed) pairs whose target was reached within the budget.", "",
              RANKING_RULE.replace("the reference", f"`{ref}`"), "",
              f"| rank | tuner | vs {ref} (geometric mean) | {level} interval | solved | plants | "
              "status |", "|---|---|---|---|---|---|---|"]
    for row in board.aggregate_.to_dict("records"):
        lines.append(f"| {row['rank']} | {_name(row['tuner'], highlight)} | {_number(row['geo_mean_vs_reference'])} | "
                     f"[{_number(row['ci_low'])}, {_number(row['ci_high'])}] | "
                     f"{_number(100 * row['solved'], 0)} % of {row['pairs']} | {row['plants']} | "
                     f"{row['status'] or 'current'} |")
    lines.append("")
    if "ecdf" in figures:
        lines += ["## Runtime ECDF", "",
                  "Fraction of (plant, seed) pairs whose target is reached within x real experiments, x on a log "
                  "axis (COCO's runtime distribution); a curve that ends below 1 has misses.", "",
                  f"![runtime ECDF over the suite]({figures['ecdf']})", ""]
        if "ecdf_plants" in figures:
            lines += [f"![runtime ECDF per plant]({figures['ecdf_plants']})", ""]
    lines += ["## Per plant", "",
              f"Mean real experiments to the target with its {level} bootstrap percentile interval "
              f"(`scipy.stats.bootstrap`, {board.n_bootstrap} resamples of the seeds, seed {board.seed}; it stays "
              f"within the range of the counts); a miss counts as the experiments counted + 1; `/ {ref}`: the mean "
              f"over `{ref}`'s on the same seeds. A plant with constraints has a column more, the violations per "
              "run: the mean number of its experiments that broke a constraint (only the feasible ones reach the "
              "target).", ""]
    for plant in board.plants_:
        part = board.table_[board.table_["plant"] == plant.label]
        counted = f"experiments {plant.start + 1}-{plant.budget} (after the plant change)" if plant.start else \
            f"budget {plant.budget}"
        constrained = bool(part["violations"].notna().any())
        lines += [f"### {plant.label}: ratio {plant.target:g}, {counted}", "",
                  f"| tuner | experiments to {plant.target:g} | misses | / {ref} | "
                  f"{'violations per run | ' if constrained else ''}seeds | status |",
                  "|---|---|---|---|" + ("---|" if constrained else "") + "---|---|"]
        for row in part.to_dict("records"):
            broke = f"{_number(row['violations'], 1)} | " if constrained else ""
            lines.append(f"| {_name(row['tuner'], highlight)} | {_cell(row)} | {row['misses']} | "
                         f"{_number(row['vs_reference'])} | {broke}"
                         f"{row['seeds']} | {row['status'] or 'current'} |")
        lines.append("")
    if notes:
        lines += ["## Notes", "", *[f"- {note}" for note in notes], ""]
    return lines


def write_leaderboard(board: Leaderboard, out: Path | str, title: str, intro: list[str] | None = None,
                      notes: list[str] | None = None, highlight: str | None = None,
                      meta: dict | None = None) -> dict[str, Path]:
    """Write ``leaderboard.md``, ``leaderboard.csv``, ``leaderboard.html`` and the ECDF PNGs into ``out``.

    Parameters
    ----------
    board : Leaderboard
        Fitted.
    out : Path
    title : str
    intro, notes : list of str, optional
        Paragraphs above the tables; bullet points at the end.
    highlight : str, optional
        The researcher's tuner: drawn thick in the ECDFs, in bold with a marker in the tables, and its
        HTML rows of class ``highlight``.
    meta : dict, optional
        Written as ``leaderboard.json`` beside (the command, suite, references' commits).

    Returns
    -------
    dict
        ``"md", "csv", "html", "ecdf", "ecdf_plants", "json"`` -> paths.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"ecdf": save(board.plot(highlight=highlight), out / "leaderboard_ecdf.png")}
    if len(board.plants_) > 1:
        paths["ecdf_plants"] = save(_plant_grid(board, highlight), out / "leaderboard_ecdf_plants.png")
    lines = leaderboard_markdown(board, title, intro or [], {k: v.name for k, v in paths.items()}, notes or [],
                                 highlight)
    paths["md"] = out / "leaderboard.md"
    with atomic_write(paths["md"]) as handle:
        handle.write("\n".join(lines))
    paths["html"] = write_html(paths["md"], title=title, highlight=highlight)
    table = board.table_.assign(kind="plant")
    aggregate = board.aggregate_.rename(columns={"geo_mean_vs_reference": "vs_reference"}).assign(
        kind="suite", plant="all", mean=np.nan, target=np.nan, seeds=np.nan, misses=np.nan, violations=np.nan)
    frame = pd.concat([aggregate, table], ignore_index=True)[
        ["kind", "rank", "tuner", "plant", "target", "seeds", "mean", "ci_low", "ci_high", "misses", "vs_reference",
         "violations", "solved", "pairs", "plants", "status"]]
    paths["csv"] = out / "leaderboard.csv"
    with atomic_write(paths["csv"]) as handle:
        frame.to_csv(handle, index=False, float_format="%.6g")
    if meta is not None:
        paths["json"] = out / "leaderboard.json"
        with atomic_write(paths["json"]) as handle:
            json.dump({**meta, "written": time.strftime("%Y-%m-%dT%H:%M:%S")}, handle, indent=1)
    return paths


def _plant_grid(board: Leaderboard, highlight: str | None):
    """Small multiples: the runtime ECDF of every plant."""
    n = len(board.plants_)
    cols = 3 if n > 4 else n
    rows = math.ceil(n / cols)
    with style():
        fig, axes = pyplot().subplots(rows, cols, figsize=(4.2 * cols, 2.9 * rows), squeeze=False)
        for i, (ax, plant) in enumerate(zip(axes.flat, board.plants_)):
            board.plot(plant=plant.label, highlight=highlight, ax=ax)
            ax.set_title(f"{plant.label} (ratio {plant.target:g})", fontsize=9)
            same = [line.get_label() for line in ax.get_lines() if " (same as " in line.get_label()]
            if same:  # the legend is shared: each panel names its own coinciding curves
                ax.text(0.98, 0.03, "\n".join(same), transform=ax.transAxes, ha="right", va="bottom", fontsize=7,
                        bbox={"facecolor": "white", "alpha": 0.85, "lw": 0})
            legend = ax.get_legend()
            if legend is not None and i != cols - 1:
                legend.remove()
            elif legend is not None:
                for text in legend.get_texts():
                    text.set_text(text.get_text().split(" (same as ")[0])
            if i % cols:
                ax.set_ylabel("")
            if i < n - cols:
                ax.set_xlabel("")
        for ax in list(axes.flat)[n:]:
            ax.set_visible(False)
    return fig
