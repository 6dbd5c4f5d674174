"""Figures of a study: optimality-ratio curves with the paper's bands, histograms, cost surfaces, sweeps.

Every function returns a matplotlib ``Figure`` (Agg backend; nothing is shown)
drawn in the project's style (:func:`gbo_envs.plotting.style`: units on every
axis, legends outside the data); :func:`save` writes one as PNG (atomically) and closes it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from evaluation.analysis import PAPER_BANDS, percentile_bands
from gbo_envs.atomic_write import atomic_write
from gbo_envs.lazy_pyplot import pyplot
from gbo_envs.plotting import axis_label, cost_surface, legend_outside, style

__all__ = [
    "save",
    "ratio_curve_figure",
    "histogram_figure",
    "cost_surface_figure",
    "activations_figure",
    "sweep_figure",
]

_EXPERIMENTS = axis_label("plant experiments", "count")
_RATIO = "optimality ratio J/J*"


def _colors(n: int) -> list:
    cmap = pyplot().get_cmap("tab10" if n <= 10 else "tab20")
    return [cmap(i % cmap.N) for i in range(n)]


def save(fig, path: Path | str, dpi: int = 120) -> Path:
    """Write ``fig`` as PNG to ``path`` (folders created) and close it."""
    path = Path(path)
    with atomic_write(path, "wb") as handle:
        fig.savefig(handle, dpi=dpi, format="png")
    pyplot().close(fig)
    return path


def ratio_curve_figure(curves: dict[str, np.ndarray], thresholds: dict[str, float] | None = None,
                       levels=PAPER_BANDS, bands: bool | None = None, title: str | None = None):
    """Minimum observed optimality ratio vs plant experiments: mean line and percentile bands per tuner.

    Axes: plant experiments (count, from 1); minimum observed optimality ratio J/J* (-), log scale.

    Parameters
    ----------
    curves : dict of str -> ndarray of shape (n_batches, budget)
        From :func:`evaluation.analysis.ratio_curves`.
    thresholds : dict of str -> float, optional
        Drawn as dashed horizontal lines.
    levels : sequence of float
        Band coverages (the paper's 68/90/95/99 %).
    bands : bool, optional
        Draw the bands (default: when at most 3 tuners, else the means only).
    title : str, optional
    """
    plt = pyplot()
    with style():
        fig, ax = plt.subplots(figsize=(7.5, 5.2))
        bands = len(curves) <= 3 if bands is None else bands
        levels = sorted(levels, reverse=True)
        for color, (label, curve) in zip(_colors(len(curves)), curves.items()):
            stats = percentile_bands(curve, levels)
            x = np.arange(1, curve.shape[1] + 1)
            if bands:
                for i, level in enumerate(levels):
                    low, high = stats["bands"][float(level)]
                    ax.fill_between(x, low, high, color=color, alpha=0.10 + 0.06 * i, lw=0,
                                    label=f"{label}: {', '.join(f'{lv:.0%}' for lv in sorted(levels))} bands"
                                    if i == 0 else None)
            ax.plot(x, stats["mean"], color=color, lw=2.2, label=f"{label}: mean of {curve.shape[0]} batches")
        for i, (name, ratio) in enumerate((thresholds or {}).items()):
            ax.axhline(ratio, color="0.3", ls=(0, (4, 2 + i)), lw=1)
            ax.annotate(f"{name} ({ratio:.3g})", (1, ratio), xytext=(2, 2), textcoords="offset points", fontsize=7,
                        color="0.3")
        ax.set_xlabel(_EXPERIMENTS)
        ax.set_ylabel(axis_label(f"minimum observed {_RATIO}", "-"))
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(plt.matplotlib.ticker.FormatStrFormatter("%.2f"))
        ax.yaxis.set_minor_formatter(plt.matplotlib.ticker.FormatStrFormatter("%.2f"))
        ax.tick_params(axis="y", which="minor", labelsize=7)
        ax.grid(True, which="both", alpha=0.3)
        legend_outside(ax, below=True)
        if title:
            ax.set_title(title)
    return fig


def histogram_figure(table: pd.DataFrame, title: str | None = None):
    """Percentage of plant experiments per measured-ratio bin, one bar group per bin.

    Axes: measured optimality ratio J/J* (-); share of the experiments (%).

    Parameters
    ----------
    table : DataFrame
        From :func:`evaluation.analysis.histogram_table` (``low, high`` and one column per tuner).
    """
    plt = pyplot()
    with style():
        fig, ax = plt.subplots(figsize=(7.5, 4.5))
        labels = [c for c in table.columns if c not in ("low", "high")]
        widths = (table["high"] - table["low"]).to_numpy()
        for i, (color, label) in enumerate(zip(_colors(len(labels)), labels)):
            share = widths / len(labels)
            ax.bar(table["low"].to_numpy() + i * share, table[label].to_numpy(), width=share, align="edge",
                   color=color, alpha=0.85, label=label)
        ax.set_xlabel(axis_label(f"measured {_RATIO} (last bin: >= {table['low'].iloc[-1]:.3g})", "-"))
        ax.set_ylabel(axis_label("experiments", "%"))
        ax.grid(False, axis="x")
        legend_outside(ax, below=True)
        if title:
            ax.set_title(title)
    return fig


def cost_surface_figure(truth, frame: pd.DataFrame, batch: int = 0, tuners: list[str] | None = None,
                        title: str | None = None):
    """Each tuner's path through the gains in one batch on the ground-truth cost surface (one panel per tuner).

    Axes: the two gains in their units; colour: cost J (-). Plant experiments
    are filled circles joined in the order of query and numbered from 1, twin
    evaluations hollow circles; the red star is the grid optimum ``J*``.

    Parameters
    ----------
    truth : gbo_envs.GroundTruth
        Two-gain ground truth.
    frame : DataFrame
        Tidy results.
    batch : int
    tuners : list of str, optional
        Labels to draw (default: all in ``frame``).
    """
    plt = pyplot()
    labels = tuners or list(dict.fromkeys(frame["tuner"]))
    cols = min(2, len(labels))
    rows = int(np.ceil(len(labels) / cols))
    names = list(truth.gain_names)
    with style():
        fig, axes = plt.subplots(rows, cols, figsize=(7.2 * cols, 4.6 * rows), squeeze=False)
        for ax, label in zip(axes.ravel(), labels):
            part = frame[(frame["tuner"] == label) & (frame["batch"] == batch)]
            twin = part[part["source"] == "twin"]
            plant = part[part["source"] == "plant"].sort_values("experiment")
            points = {f"twin evaluations ({len(twin)})": twin[names].to_numpy()} if len(twin) else None
            cost_surface(truth, ax=ax, points=points, path=plant[names].to_numpy())
            ax.set_title(f"{label}, batch {batch}")
        for ax in axes.ravel()[len(labels):]:
            ax.set_visible(False)
        if title:
            fig.suptitle(title)
    return fig


def activations_figure(table: pd.DataFrame, title: str | None = None):
    """Twin activations per batch, one box per tuner (from :func:`evaluation.analysis.twin_activations`).

    Axes: tuner (categories); twin activations per batch (count).
    """
    plt = pyplot()
    labels = list(dict.fromkeys(table["tuner"]))
    with style():
        fig, ax = plt.subplots(figsize=(max(5, 1.1 * len(labels) + 2), 4))
        data = [table.loc[table["tuner"] == label, "activations"].to_numpy() for label in labels]
        ax.boxplot(data, showmeans=True)
        ax.set_xticks(range(1, len(labels) + 1), labels, rotation=30, ha="right")
        ax.set_ylabel(axis_label("twin activations per batch", "count"))
        if title:
            ax.set_title(title)
    return fig


def sweep_figure(table: pd.DataFrame, param: str, references: dict[str, dict[str, float]] | None = None,
                 title: str | None = None):
    """The paper's eta1 figure: experiments to each threshold (top); mean measured ratio and activations (bottom).

    Axes: the swept parameter (-); plant experiments (count); mean measured
    optimality ratio J/J* (-) and twin activations per batch (count) on a second axis.

    Parameters
    ----------
    table : DataFrame
        From :func:`evaluation.analysis.sweep_table`.
    param : str
        The swept parameter (x axis; log scale when it spans more than two decades).
    references : dict of str -> dict, optional
        Unswept tuners (e.g. BO): label -> ``{"to <threshold>": mean, "mean_measured_ratio": ...}``,
        drawn as dashed lines.
    """
    plt = pyplot()
    with style():
        fig, (top, bottom) = plt.subplots(2, 1, figsize=(8.5, 6.5), sharex=True)
        x = table[param].to_numpy(dtype=float)
        columns = [c for c in table.columns if c.startswith("to ")]
        colors = _colors(len(columns))
        for color, column in zip(colors, columns):
            top.plot(x, table[column], "o-", color=color, label=f"swept: experiments {column}")
            for label, ref in (references or {}).items():
                if column in ref:
                    top.axhline(ref[column], color=color, ls="--", lw=1, label=f"{label} {column}")
        top.set_ylabel(axis_label("mean plant experiments to threshold", "count"))
        legend_outside(top)
        bottom.plot(x, table["mean_measured_ratio"], "o-", color="tab:blue", label="mean measured ratio")
        for label, ref in (references or {}).items():
            if "mean_measured_ratio" in ref:
                bottom.axhline(ref["mean_measured_ratio"], color="tab:blue", ls="--", lw=1, label=f"{label}")
        bottom.set_ylabel(axis_label(f"mean measured {_RATIO}", "-"), color="tab:blue")
        twin_ax = bottom.twinx()
        twin_ax.plot(x, table["activations"], "s-", color="tab:red", label="twin activations per batch")
        twin_ax.set_ylabel(axis_label("twin activations per batch", "count"), color="tab:red")
        twin_ax.grid(False)
        twin_ax.spines["right"].set_visible(True)
        bottom.set_xlabel(axis_label(param, "-"))
        positive = x[x > 0]
        if positive.size == x.size and positive.size and positive.max() / positive.min() > 100:
            bottom.set_xscale("log")
        lines = bottom.get_legend_handles_labels()
        more = twin_ax.get_legend_handles_labels()
        bottom.legend(lines[0] + more[0], lines[1] + more[1], loc="upper left", bbox_to_anchor=(1.12, 1.0),
                      borderaxespad=0.0)
        if title:
            top.set_title(title)
    return fig
