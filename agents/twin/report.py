"""Figures of the twin workbench and its self-contained HTML report (PNGs embedded as base64).

* :func:`compare_figure`: measured against simulated output per experiment, and the error;
* :func:`residual_figure`: whiteness, input cross-correlation (99 % bands) and where the model fails;
* :func:`ladder_figure`: the error ladder, RMSE as effects are added;
* :func:`write_report`: one HTML page with the plots, the ranking and the ladder.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from agents.twin.greybox import GreyData, GreyFit
from agents.twin.ladder_text import advice, unobservable_lines
from agents.twin.workbench import Diagnosis, ResidualAnalysis, compare
from gbo_envs.atomic_write import atomic_write
from gbo_envs.lazy_pyplot import pyplot

__all__ = ["compare_figure", "figure_to_base64", "ladder_figure", "residual_figure", "write_report"]


def compare_figure(data: GreyData, fits: Sequence[GreyFit], max_experiments: int = 4):
    """Overlay of measured ``y`` and each model's simulated output, with the errors below.

    Parameters
    ----------
    data : GreyData
    fits : sequence of GreyFit
        Models to overlay (e.g. the linear model and the model with the diagnosed effect).
    max_experiments : int, default 4
        Experiments shown (spread over the data set).
    """
    plt = pyplot()
    shown = np.unique(np.linspace(0, data.n_records - 1, min(max_experiments, data.n_records)).round().astype(int))
    fig, axes = plt.subplots(2, shown.size, figsize=(4.2 * shown.size, 5.5), squeeze=False, sharex="col")
    for col, k in enumerate(shown):
        m = data.mask[k]
        t = data.t[k][m]
        ax, ax_err = axes[0, col], axes[1, col]
        ax.plot(t, data.y[k][m], color="0.3", lw=0.8, label="measured")
        for fit in fits:
            res = compare(data, fit)
            ax.plot(t, fit.y_sim[k][m], lw=1.2, label=f"{fit.spec.label} ({res.fit_percent[k]:.1f} %)")
            ax_err.plot(t, data.y[k][m] - fit.y_sim[k][m], lw=0.8, label=fit.spec.label)
        ax.set_title(f"experiment {int(data.numbers[k])}")
        ax_err.set_xlabel("t (s)")
        ax.legend(fontsize=7)
    axes[0, 0].set_ylabel("y")
    axes[1, 0].set_ylabel("y - y_sim")
    fig.tight_layout()
    return fig


def residual_figure(analysis: ResidualAnalysis, title: str = ""):
    """Residual autocorrelation and input cross-correlation with 99 % bands, and the binned residual."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5))
    ax = axes[0, 0]
    ax.bar(analysis.lags, analysis.acf, width=0.8, color="tab:blue")
    ax.axhspan(-analysis.band, analysis.band, color="tab:orange", alpha=0.3, label="99 % band")
    ax.set_title(f"residual autocorrelation ({'white' if analysis.white else 'not white'})")
    ax.set_xlabel("lag (samples)")
    ax.legend(fontsize=7)
    ax = axes[0, 1]
    ax.bar(analysis.ccf_lags, analysis.ccf, width=0.8, color="tab:green")
    ax.axhspan(-analysis.band, analysis.band, color="tab:orange", alpha=0.3)
    ax.set_title(f"residual-input cross-correlation ({'independent' if analysis.independent else 'correlated'})")
    ax.set_xlabel("lag (samples)")
    panels = [("time", "time in experiment (s)", axes[0, 2]), ("experiment", "experiment index", axes[1, 0]),
              ("input", "input level u", axes[1, 1]), ("output", "output level y", axes[1, 2])]
    for key, label, ax in panels:
        b = analysis.bins[key]
        ax.plot(b["centers"], b["rms"], "o-", label="rms")
        ax.plot(b["centers"], b["mean"], "s--", label="mean")
        ax.set_xlabel(label)
        ax.axhline(0.0, color="0.6", lw=0.5)
    sign = analysis.bins["velocity_sign"]
    axes[1, 2].set_title("sign of velocity: " + ", ".join(
        f"{int(c):+d}: rms {r:.3g}" for c, r in zip(sign["centers"], sign["rms"])), fontsize=8)
    axes[0, 2].legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def ladder_figure(rungs: Sequence[dict], noise_rmse: float | None = None):
    """Bar chart of the error ladder: RMSE of each model as effects are added."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(1.8 * len(rungs) + 3, 3.8))
    labels = [r["model"] for r in rungs]
    ax.bar(range(len(rungs)), [r["rmse"] for r in rungs], color="tab:blue", label="RMSE (fit to all data)")
    ax.plot(range(len(rungs)), [r["heldout_rmse"] for r in rungs], "o", color="tab:red", label="held-out RMSE")
    if noise_rmse is not None:
        ax.axhline(noise_rmse, color="tab:orange", ls="--",
                   label=f"noise-floor estimate {noise_rmse:.3g} (not a lower bound)")
    ax.set_xticks(range(len(rungs)), labels, rotation=15, fontsize=8)
    ax.set_ylabel("RMSE (units of y)")
    ax.set_title("error ladder")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def figure_to_base64(fig) -> str:
    """PNG of a matplotlib figure as a base64 string (the figure is closed)."""
    plt = pyplot()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _img(fig, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{figure_to_base64(fig)}"/>'


def _table(rows: Sequence[dict], columns: Sequence[str]) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = []
    for row in rows:
        cells = []
        for c in columns:
            v = row.get(c, "")
            if isinstance(v, float):
                v = f"{v:.4g}"
            elif isinstance(v, dict):
                v = ", ".join(f"{k}={x:.4g}" if isinstance(x, float) else f"{k}={x}" for k, x in v.items())
            cells.append(f"<td>{html.escape(str(v))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table><tr>{head}</tr>{''.join(body)}</table>"


def write_report(out_dir: str | Path, data: GreyData, rungs: Sequence[dict], diagnoses: Sequence[Diagnosis],
                 analyses: Sequence[ResidualAnalysis], source: str = "") -> Path:
    """Write ``index.html`` (self-contained) into ``out_dir`` and return its path.

    Parameters
    ----------
    out_dir : str or Path
    data : GreyData
    rungs, diagnoses : from :func:`agents.twin.workbench.error_ladder`
    analyses : residual analyses of the first and the last model of the ladder
    source : str
        Name of the data (e.g. the CSV path), shown in the title.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    first, last = diagnoses[0], diagnoses[-1]
    fits = [first.current] + ([last.current] if last is not first else [])
    noise = first.noise_rmse
    next_step = advice(last, last.current.spec.effect_names, source or "DATA.csv", stopped_at_max=last.best is not None)
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>twin workbench report</title><style>"
        "body{font-family:sans-serif;max-width:1400px;margin:auto;padding:1em}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;padding:3px 8px;font-size:13px}"
        "img{max-width:100%}</style></head><body>",
        f"<h1>Twin workbench: {html.escape(source)}</h1>",
        f"<p>{data.n_records} experiments, {data.n_samples} samples, dt = {data.dt:g} s; "
        f"{html.escape(first.noise_label)}: {'n/a' if noise is None else f'{noise:.4g}'} (units of y).</p>",
        "<h2>Error ladder</h2>",
        "<p>RMSE of the linear model, then with the best effect added, then the next, until no effect improves "
        "the held-out error beyond its complexity cost.</p>",
        _table(rungs, ["model", "added", "rmse", "heldout_rmse", "fit_percent", "params"]),
        "<ul>" + "".join(f"<li>{html.escape(r['text'])}</li>" for r in rungs if "text" in r) + "</ul>",
        f"<p><b>{html.escape(next_step)}</b></p>",
        _img(ladder_figure(rungs, noise), "error ladder"),
        "<h2>Measured vs simulated</h2>",
        _img(compare_figure(data, fits), "compare"),
        "<h2>Ranking of the effects (first diagnosis)</h2>",
        f"<p>Model: {html.escape(first.current.spec.label)}; best: <b>{html.escape(str(first.best))}</b>; "
        f"validation: {html.escape(first.validation)}.</p>",
        _table(first.candidates, ["effect", "rmse", "train_rmse", "delta_bic", "params", "evidence", "note"]),
    ]
    if last.unobservable:
        parts += ["<h3>Not observable in this data</h3>",
                  "<ul>" + "".join(f"<li>{html.escape(line)}</li>" for line in unobservable_lines(last)) + "</ul>"]
    if first.indistinguishable:
        parts.append(f"<p>Indistinguishable on this data: {html.escape(str(first.indistinguishable))}; "
                     f"{html.escape(str(first.suggested_experiment))}.</p>")
    for analysis, fit in zip(analyses, fits):
        parts += [f"<h2>Residuals of {html.escape(fit.spec.label)}</h2>",
                  _img(residual_figure(analysis, fit.spec.label), f"residuals {fit.spec.label}"),
                  "<p>Worst segments:</p>",
                  _table(analysis.worst, ["experiment", "t_start", "t_end", "rms", "mean"])]
    parts.append("</body></html>")
    path = out / "index.html"
    with atomic_write(path) as handle:
        handle.write("\n".join(parts))
    return path
