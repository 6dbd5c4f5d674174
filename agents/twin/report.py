"""Figures of the twin workbench and its self-contained HTML report (PNGs embedded as base64).

* :func:`compare_figure`: measured against simulated output per experiment, and the error;
* :func:`residual_figure`: whiteness, input cross-correlation (99 % bands) and where the model fails;
* :func:`ladder_figure`: the error ladder, RMSE as effects are added;
* :func:`saturation_figure`: the commanded input u(t) against a fitted saturation limit, its evidence;
* :func:`write_report`: one self-contained HTML page (figures inline as base64 PNG, readable at phone
  width) with the plots, the ranking and the ladder.
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from agents.html_page import image_tag, page, scrolling
from agents.twin.ladder_text import advice, number, pairs_text, params_text, unobservable_lines
from agents.twin.map_figure import map_figure
from agents.twin.model import GreyFit
from agents.twin.ranking import ORDER_RULE
from agents.twin.records import Batch
from agents.twin.static_map import MAP_NAMES
from agents.twin.workbench import Diagnosis, ResidualAnalysis, compare
from gbo_envs.atomic_write import atomic_write
from gbo_envs.lazy_pyplot import pyplot
from gbo_envs.plotting import MEASURED, MODEL, REFERENCE, axis_label, legend_outside, style

__all__ = ["RESIDUAL_PANELS", "compare_figure", "ladder_figure", "residual_figure", "saturation_figure",
           "shown_experiments", "write_report"]


#: Panels of :func:`residual_figure`, in order.
RESIDUAL_PANELS = ("acf", "ccf", "time", "experiment", "input", "output")


def shown_experiments(data: Batch, max_experiments: int = 4) -> np.ndarray:
    """Positions of at most ``max_experiments`` records spread over the data set."""
    return np.unique(np.linspace(0, data.n_records - 1, min(max_experiments, data.n_records)).round().astype(int))


def compare_figure(data: Batch, fits: Sequence[GreyFit], max_experiments: int = 4, y_unit: str = "",
                   experiments: Sequence[int] | None = None):
    """Measured ``y`` above each model's simulated output per experiment, with the errors below.

    Axes: time since the step t (s); output y and error y - y_sim in ``y_unit``.
    The measured trace is solid and dark on top (:data:`gbo_envs.plotting.MEASURED`),
    each model dashed in colour below it.

    Parameters
    ----------
    data : Batch
    fits : sequence of GreyFit
        Models to overlay (e.g. the linear model and the model with the diagnosed effect).
    max_experiments : int, default 4
        Experiments shown (spread over the data set), at most 2 per row.
    y_unit : str
        Unit of the output ("" when unknown).
    experiments : sequence of int, optional
        Positions of the records to show instead (0 for the first record).
    """
    plt = pyplot()
    shown = shown_experiments(data, max_experiments) if experiments is None else np.asarray(experiments, dtype=int)
    if shown.size == 0 or shown.min() < 0 or shown.max() >= data.n_records:
        raise ValueError(f"experiments: record positions in [0, {data.n_records - 1}], got {shown.tolist()}")
    results = [compare(data, fit) for fit in fits]
    columns = min(2, shown.size)
    rows = int(np.ceil(shown.size / columns))
    with style():
        fig, axes = plt.subplots(2 * rows, columns, figsize=(5.4 * columns, 4.2 * rows + 0.6), squeeze=False,
                                 height_ratios=[2, 1] * rows)
        for n, k in enumerate(shown):
            ax, ax_err = axes[2 * (n // columns), n % columns], axes[2 * (n // columns) + 1, n % columns]
            ax_err.sharex(ax)
            m = data.mask[k]
            t = data.t[k][m]
            for i, fit in enumerate(fits):
                ax.plot(t, fit.y_sim[k][m], color=f"C{i}", label=f"model: {fit.spec.label}", **MODEL)
                ax_err.plot(t, data.y[k][m] - fit.y_sim[k][m], color=f"C{i}", lw=0.9)
            ax.plot(t, data.y[k][m], label="measured", **MEASURED)
            fit_text = " / ".join(f"{res.fit_percent[k]:.1f} %" for res in results)
            ax.set_title(f"experiment {int(data.numbers[k])}: fit {fit_text}")
            ax.set_ylabel(axis_label("output y", y_unit))
            ax_err.set_ylabel(axis_label("y - y_sim", y_unit))
            ax_err.set_xlabel(axis_label("time since step t", "s"))
            ax_err.axhline(0.0, **REFERENCE)
        for n in range(shown.size, rows * columns):
            axes[2 * (n // columns), n % columns].set_visible(False)
            axes[2 * (n // columns) + 1, n % columns].set_visible(False)
        handles, labels = axes[0, 0].get_legend_handles_labels()
        fig.legend(handles[::-1], labels[::-1], loc="outside upper center", ncols=min(2, len(labels)))
    return fig


def residual_figure(analysis: ResidualAnalysis, title: str = "", y_unit: str = "", u_unit: str = "",
                    panels: Sequence[str] = RESIDUAL_PANELS):
    """Residual autocorrelation and input cross-correlation with 99 % bands, and the binned residual.

    Axes: lag (samples) against the normalised correlation (-); the binned
    residual (rms and mean, in ``y_unit``) against time in the experiment
    (s), experiment number, input level (``u_unit``) and output level (``y_unit``).

    Parameters
    ----------
    analysis : ResidualAnalysis
    title : str
    y_unit, u_unit : str
        Units of the output and the input ("" when unknown).
    panels : sequence of str, default all of :data:`RESIDUAL_PANELS`
        Which panels to draw, at most 3 per row.
    """
    unknown = [p for p in panels if p not in RESIDUAL_PANELS]
    if unknown or not panels:
        raise ValueError(f"panels: a non-empty selection of {RESIDUAL_PANELS}, got {list(panels)}")
    plt = pyplot()
    columns = min(3, len(panels))
    rows = int(np.ceil(len(panels) / columns))
    with style():
        fig, axes = plt.subplots(rows, columns, figsize=(4.4 * columns, 3.9 * rows), squeeze=False)
        for ax in axes.ravel()[len(panels):]:
            ax.set_visible(False)
        for panel, ax in zip(panels, axes.ravel()):
            _residual_panel(ax, panel, analysis, y_unit, u_unit)
        if title:
            fig.suptitle(title)
    return fig


def _residual_panel(ax, panel: str, analysis: ResidualAnalysis, y_unit: str, u_unit: str) -> None:
    """Draw one panel of :func:`residual_figure` on ``ax``."""
    if panel in ("acf", "ccf"):
        lags, values, color = ((analysis.lags, analysis.acf, "tab:blue") if panel == "acf" else
                               (analysis.ccf_lags, analysis.ccf, "tab:green"))
        ax.bar(lags, values, width=0.8, color=color, label="autocorrelation" if panel == "acf" else
               "cross-correlation with u")
        ax.axhspan(-analysis.band, analysis.band, color="tab:orange", alpha=0.3, label="99 % band")
        ax.set_title(f"residual autocorrelation ({'white' if analysis.white else 'not white'})" if panel == "acf"
                     else f"residual-input correlation ({'independent' if analysis.independent else 'correlated'})")
        ax.set_xlabel(axis_label("lag", "samples"))
        ax.set_ylabel(axis_label("correlation", "-"))
        legend_outside(ax, below=True)
        return
    label = {"time": axis_label("time in experiment", "s"), "experiment": axis_label("experiment", "number"),
             "input": axis_label("input level u", u_unit), "output": axis_label("output level y", y_unit)}[panel]
    b = analysis.bins[panel]
    ax.plot(b["centers"], b["rms"], "o-", label="rms residual")
    ax.plot(b["centers"], b["mean"], "s--", label="mean residual")
    ax.set_xlabel(label)
    ax.set_ylabel(axis_label("residual", y_unit))
    ax.axhline(0.0, **REFERENCE)
    legend_outside(ax, below=True)
    if panel == "experiment":
        ax.xaxis.set_major_locator(pyplot().MaxNLocator(integer=True))
    if panel == "output":
        sign = analysis.bins["velocity_sign"]
        ax.set_title("sign of velocity: " + ", ".join(
            f"{int(c):+d}: rms {r:.3g}" for c, r in zip(sign["centers"], sign["rms"])), fontsize=8)
    else:
        ax.set_title({"time": "residual over the experiment", "experiment": "residual per experiment",
                      "input": "residual against the input level"}[panel])


def ladder_figure(rungs: Sequence[dict], noise_rmse: float | None = None, y_unit: str = ""):
    """Bar chart of the error ladder: RMSE of each model as effects are added.

    Axes: the models (categories); RMSE in ``y_unit``.
    """
    plt = pyplot()
    with style():
        fig, ax = plt.subplots(figsize=(1.5 * len(rungs) + 3.0, 4.2))
        labels = [r["model"] for r in rungs]
        ax.bar(range(len(rungs)), [r["rmse"] for r in rungs], color="tab:blue", label="RMSE (fit)")
        ax.plot(range(len(rungs)), [r["heldout_rmse"] for r in rungs], "o", color="tab:red", label="held-out RMSE")
        if noise_rmse is not None:
            ax.axhline(noise_rmse, color="tab:orange", ls="--",
                       label=f"noise-floor estimate {noise_rmse:.3g} (not a lower bound)")
        ax.set_xticks(range(len(rungs)), labels, rotation=15, ha="right", fontsize=8)
        ax.set_ylabel(axis_label("RMSE", y_unit))
        ax.set_title("error ladder")
        legend_outside(ax, below=True)
    return fig


def saturation_figure(data: Batch, fit: GreyFit, u_unit: str = "", max_experiments: int = 4):
    """The commanded input u(t) of each shown experiment against the fitted saturation limit (``-limit`` too when a
    command goes negative).

    The evidence of a drive limit: where the command goes beyond the band (shaded) the plant gets the limit,
    not the command. Axes: time since the step t (s); commanded input u in ``u_unit``.

    Parameters
    ----------
    data : Batch
    fit : GreyFit
        A model with the ``saturation`` effect.
    u_unit : str
        Unit of the input ("" when unknown).
    max_experiments : int, default 4
        Experiments drawn (spread over the data set).
    """
    limit = fit.effect_params.get("saturation", {}).get("limit")
    if limit is None:
        raise ValueError(f"fit: a model with the saturation effect, got {fit.spec.label}")
    plt = pyplot()
    with style():
        fig, ax = plt.subplots(figsize=(7.5, 4.2))
        for i, k in enumerate(shown_experiments(data, max_experiments)):
            m = data.mask[k]
            ax.plot(data.t[k][m], data.u[k][m], color=f"C{i}", lw=1.2, label=f"u, experiment {int(data.numbers[k])}")
        u = data.u[data.mask]
        levels = [limit] + ([-limit] if u.min() < 0 else [])  # the lower limit only where commands go negative
        span = [min(u.min(), *levels), max(u.max(), *levels)]
        pad = 0.08 * (span[1] - span[0] or abs(limit) or 1.0)
        low, high = span[0] - pad, span[1] + pad
        for i, level in enumerate(levels):
            ax.axhline(level, color="k", ls="--", lw=1.4,
                       label=f"fitted limit ±{number(limit, 4)} {u_unit}".rstrip() if i == 0 else None)
        ax.axhspan(limit, high, color="tab:red", alpha=0.12, label="beyond the limit: clipped")
        if len(levels) > 1:
            ax.axhspan(low, -limit, color="tab:red", alpha=0.12)
        ax.set_ylim(low, high)
        ax.set_xlabel(axis_label("time since step t", "s"))
        ax.set_ylabel(axis_label("commanded input u", u_unit))
        ax.set_title("commanded input against the fitted saturation limit")
        legend_outside(ax)
    return fig


def _grid(items) -> str:
    """Figures side by side on a wide screen, one under the other on a phone."""
    return f"<div class='grid'>{''.join(items)}</div>"


def _cell(value) -> str:
    """Text of a table cell: numbers in fixed point to 4 significant digits, None as a dash."""
    if value is None:
        return "\u2014"
    if isinstance(value, float):
        return number(value, 4)
    return str(value)


def _table(rows: Sequence[dict], columns: Sequence[tuple[str, str]], table_id: str = "", formats=None,
           wrap: bool = False) -> str:
    """An HTML table of ``rows``: ``columns`` are ``(key, header)``; ``formats`` maps a key to its cell's text.

    ``wrap``: the table takes the page's width and its long text cells wrap (class ``wrap``) instead of scrolling.
    """
    formats = formats or {}
    head = "".join(f"<th>{html.escape(header)}</th>" for _, header in columns)
    body = ["<tr>" + "".join(f"<td>{html.escape(formats.get(key, _cell)(row.get(key)))}</td>" for key, _ in columns)
            + "</tr>" for row in rows]
    attrs = (f" id='{table_id}'" if table_id else "") + (" class='wrap'" if wrap else "")
    return scrolling(f"<table{attrs}><tr>{head}</tr>{''.join(body)}</table>")


def _maps(fits: Sequence[GreyFit | None]) -> list[tuple[str, GreyFit]]:
    """``(map name, fit)`` of each static map in ``fits``, the first fit that has it."""
    out: dict[str, GreyFit] = {}
    for fit in fits:
        for name in () if fit is None else fit.spec.effect_names:
            if name in MAP_NAMES and name not in out:
                out[name] = fit
    return list(out.items())


def _saturated(fits: Sequence[GreyFit]) -> GreyFit | None:
    """The first of ``fits`` with a fitted saturation limit."""
    return next((f for f in fits if f is not None and "limit" in f.effect_params.get("saturation", {})), None)


def write_report(out_dir: str | Path, data: Batch, rungs: Sequence[dict], diagnoses: Sequence[Diagnosis],
                 analyses: Sequence[ResidualAnalysis], source: str = "", y_unit: str = "", u_unit: str = "") -> Path:
    """Write ``index.html`` (self-contained) into ``out_dir`` and return its path.

    Parameters
    ----------
    out_dir : str or Path
    data : Batch
    rungs, diagnoses : from :func:`agents.twin.workbench.error_ladder`
    analyses : residual analyses of the first and the last model of the ladder
    source : str
        Name of the data (e.g. the CSV path), shown in the title.
    y_unit, u_unit : str
        Units of the measured output and the input, for the axes ("" when unknown).
    """
    out = Path(out_dir)  # created by atomic_write
    first, last = diagnoses[0], diagnoses[-1]
    fits = [first.current] + ([last.current] if last is not first else [])
    noise = first.noise_rmse
    units = {key: unit for key, unit in (("y", y_unit), ("u", u_unit)) if unit}
    output = first.current.spec.output
    y = y_unit or "units of y"
    next_step = advice(last, last.current.spec.effect_labels, source or "DATA.csv",
                       stopped_at_max=last.best is not None, units=units)

    def rung_params(params) -> str:
        return "; ".join(f"{name}: {params_text(name, values, units, output)}" for name, values in params.items()) \
            or "\u2014"

    def candidate_params(row) -> str:
        return params_text(row["effect"], row.get("params") or {}, units, output, row.get("intervals")) or "\u2014"

    parts = [
        f"<h1>Twin workbench: {html.escape(source)}</h1>",
        f"<p>{data.n_records} experiments, {data.n_samples} samples, dt = {data.dt:g} s; "
        f"{html.escape(first.noise_label)}: {number(noise)} ({html.escape(y)}).</p>",
        "<h2>Error ladder</h2>",
        "<p>RMSE of the linear model, then with the best effect added, then the next, until no effect improves "
        "the held-out error beyond its complexity cost.</p>",
        _table(rungs, [("model", "model"), ("added", "effect added"), ("rmse", f"RMSE of the fit ({y})"),
                       ("heldout_rmse", f"held-out RMSE ({y})"), ("fit_percent", "fit (%)"),
                       ("params", "effect parameters")], table_id="ladder",
               formats={"params": rung_params, "fit_percent": lambda v: f"{v:.1f}"}, wrap=True),
        "<ul>" + "".join(f"<li>{html.escape(r['text'])}</li>" for r in rungs if "text" in r) + "</ul>",
        f"<p><b>{html.escape(next_step)}</b></p>",
        image_tag(ladder_figure(rungs, noise, y_unit=y_unit), "error ladder",
                  "RMSE of each model on the data it was fitted to (bars) and on held-out experiments (dots)."),
        "<h2>Measured vs simulated</h2>",
        "<p>Measured output (solid, dark) above each model (dashed); below, the simulation error.</p>",
        _grid(image_tag(compare_figure(data, fits, y_unit=y_unit, experiments=[k]),
                        f"measured against simulated output, experiment {int(data.numbers[k])}")
              for k in shown_experiments(data)),
    ]
    saturated = _saturated([last.current, first.current, first.fits.get("saturation")])
    if saturated is not None:
        limit = saturated.effect_params["saturation"]["limit"]
        parts += ["<h2>Input against the fitted saturation limit</h2>",
                  image_tag(saturation_figure(data, saturated, u_unit=u_unit), "commanded input against the limit",
                            f"Commanded input u(t) with the limit ±{number(limit, 4)} {u_unit or 'units of u'} "
                            f"fitted in {saturated.spec.label}: beyond it (shaded) the plant gets the limit.")]
    for name, fit in _maps([last.current, first.fits.get(first.best or "")]):
        unit = u_unit if name == "input_map" else y_unit
        parts += [f"<h2>The fitted {html.escape(name.replace('_', ' '))}</h2>",
                  image_tag(map_figure(fit, name, unit=unit), f"fitted {name}",
                            f"The static map of {fit.spec.label} (solid, breakpoints as dots) against the identity "
                            "of the linear model (dashed).")]
    parts += [
        "<h2>Ranking of the effects (first diagnosis)</h2>",
        f"<p>Model: {html.escape(first.current.spec.label)}; best: <b>{html.escape(str(first.best))}</b>; "
        f"validation: {html.escape(first.validation)}; {html.escape(ORDER_RULE)}.</p>",
        _table([{**c, "params": candidate_params(c)} for c in first.candidates],
               [("effect", "effect"), ("verdict", "verdict"), ("rmse", f"held-out RMSE ({y})"),
                ("train_rmse", f"RMSE of the fit ({y})"), ("delta_bic", "delta BIC (-)"),
                ("params", "fitted parameters"), ("evidence", "evidence"), ("note", "note")], table_id="ranking",
               formats={"delta_bic": lambda v: f"{v:.1f}", "note": lambda v: v or ""}, wrap=True),
    ]
    if first.not_tried:
        parts.append(f"<p>{html.escape(first.not_tried[:1].upper() + first.not_tried[1:])}.</p>")
    if last.unobservable:
        parts += ["<h3>Not observable in this data</h3>",
                  "<ul>" + "".join(f"<li>{html.escape(line)}</li>" for line in unobservable_lines(last)) + "</ul>"]
    if first.indistinguishable:
        suggestion = str(first.suggested_experiment or "")
        parts.append(f"<p>Indistinguishable on this data: {html.escape(pairs_text(first.indistinguishable))}. "
                     f"{html.escape(suggestion[:1].upper() + suggestion[1:])}</p>")
    for analysis, fit in zip(analyses, fits):
        parts += [f"<h2>Residuals of {html.escape(fit.spec.label)}</h2>",
                  _grid(image_tag(residual_figure(analysis, y_unit=y_unit, u_unit=u_unit, panels=[panel]),
                                  f"residuals of {fit.spec.label}: {panel}") for panel in RESIDUAL_PANELS),
                  "<p>Worst segments:</p>",
                  _table(analysis.worst, [("experiment", "experiment"), ("t_start", "from t (s)"),
                                          ("t_end", "to t (s)"), ("rms", f"RMS residual ({y})"),
                                          ("mean", f"mean residual ({y})")])]
    path = out / "index.html"
    with atomic_write(path) as handle:
        handle.write(page(f"twin workbench: {source}", "\n".join(parts)))
    return path
