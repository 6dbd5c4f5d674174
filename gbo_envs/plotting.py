"""The project's one plotting module: its style, axis helpers and the figures of plants and tuning runs.

Every figure of the project (here, :mod:`agents.twin.report`,
:mod:`evaluation.figures`, :mod:`evaluation.demo`) is drawn inside
:func:`style` and labels its axes with :func:`axis_label`, so that every axis
carries its unit and every legend sits outside the data (:func:`legend_outside`).
Measured data is drawn with :data:`MEASURED` (solid, dark, on top) and a model
with :data:`MODEL` (dashed, coloured, below).
"""

from __future__ import annotations

from collections.abc import Iterable
from contextlib import contextmanager

import numpy as np

from gbo_envs.lazy_pyplot import pyplot

__all__ = [
    "STYLE",
    "MEASURED",
    "MODEL",
    "REFERENCE",
    "COST_LABEL",
    "style",
    "axis_label",
    "legend_outside",
    "response_figure",
    "figure_to_rgb",
    "cost_surface",
    "convergence_curves",
    "convergence_figure",
]

#: rcParams of every figure: constrained layout (room for outside legends), light grid, readable fonts.
STYLE = {
    "figure.constrained_layout.use": True,
    "figure.dpi": 100,
    "savefig.dpi": 120,
    "font.size": 9,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "legend.fontsize": 8,
    "legend.frameon": False,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "lines.linewidth": 1.3,
}
#: Line style of measured data: solid, dark, above every model.
MEASURED = {"color": "0.1", "ls": "-", "lw": 1.4, "zorder": 3}
#: Line style of a model (its colour comes from the colour cycle): dashed, below the measured data.
MODEL = {"ls": "--", "lw": 1.3, "zorder": 2}
#: Line style of a reference or a target.
REFERENCE = {"color": "0.45", "ls": ":", "lw": 1.0, "zorder": 1}
#: Axis label of the cost.
COST_LABEL = "cost J (-)"


@contextmanager
def style():
    """Context in which figures are drawn in the project's style (:data:`STYLE`).

    Examples
    --------
    >>> from gbo_envs.plotting import style
    >>> with style():
    ...     pass  # create and save figures here
    """
    with pyplot().rc_context(STYLE):
        yield


def axis_label(quantity: str, unit: str | None) -> str:
    """``"quantity (unit)"``; a dimensionless quantity reads ``"quantity (-)"``.

    A unit that holds parentheses itself goes in brackets:
    ``"gain Kp [(input units)/(rad/s)]"``.

    Parameters
    ----------
    quantity : str
        What the axis shows, e.g. ``"output y"``.
    unit : str or None
        Its unit; ``None`` or ``""`` when unknown (the label then says so).
    """
    if not unit:
        return f"{quantity} (units unknown)"
    return f"{quantity} [{unit}]" if "(" in unit else f"{quantity} ({unit})"


def legend_outside(ax, below: bool = False, **kwargs):
    """Legend to the right of ``ax`` (or below it), outside the data (constrained layout makes room for it).

    Parameters
    ----------
    ax : matplotlib Axes
    below : bool, default False
        Under the x tick labels and axis label, in up to 2 columns, instead of on the right.
    **kwargs
        Passed to ``ax.legend``.

    Returns
    -------
    matplotlib.legend.Legend or None
        None when nothing on ``ax`` has a label.
    """
    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return None
    options = {"loc": "upper left", "bbox_to_anchor": (1.01, 1.0), "borderaxespad": 0.0}
    if below:
        options = {"loc": "upper center", "bbox_to_anchor": (0.5, -0.1), "borderaxespad": 0.0,
                   "ncols": min(2, len(handles))}
    options.update(kwargs)
    legend = ax.legend(handles, labels, **options)
    if below and "bbox_to_anchor" not in kwargs:
        _below_the_labels(ax, legend)
    return legend


def _below_the_labels(ax, legend, gap_px: float = 4.0, rounds: int = 3) -> None:
    """Move ``legend`` just under the tick labels and x label of ``ax`` (they vary with rotation and size).

    The layout shrinks the axes to make room for the legend, which moves the
    labels in axes coordinates, so the anchor is found again a few times.
    """
    legend.set_in_layout(False)
    for _ in range(rounds):
        ax.figure.draw_without_rendering()
        renderer = ax.figure.canvas.get_renderer()
        box = ax.get_window_extent(renderer)
        texts = [text for text in (ax.xaxis.label, *ax.get_xticklabels()) if text.get_visible() and text.get_text()]
        bottom = min((text.get_window_extent(renderer).y0 for text in texts), default=box.y0)
        legend.set_bbox_to_anchor((0.5, (bottom - gap_px - box.y0) / box.height), transform=ax.transAxes)
        legend.set_in_layout(True)


def response_figure(loop, response, labels=None, title: str | None = None, output_unit: str | None = None,
                    input_unit: str | None = None):
    """Figure with the output ``y`` and command ``u`` of a :class:`~gbo_envs.closed_loop.StepResponse`.

    Axes: output ``y`` in ``output_unit``, command ``u`` in ``input_unit``, time since the step in s.

    Parameters
    ----------
    loop : ClosedLoop
        The loop that produced ``response`` (for the reference and the 2 % band).
    response : StepResponse or None
        None draws empty axes (no experiment yet).
    labels : list of str, optional
        One label per response row.
    title : str, optional
    output_unit, input_unit : str, optional
        Units of ``y`` (e.g. ``"rad/s"``) and ``u`` (e.g. ``"A"``).
    """
    plt = pyplot()
    with style():
        fig, (ax_y, ax_u) = plt.subplots(2, 1, sharex=True, figsize=(7.5, 5))
        if response is not None:
            for i in range(response.y.shape[0]):
                label = labels[i] if labels else ("step response" if i == 0 else None)
                line = ax_y.plot(response.t, response.y[i], label=label)[0]
                ax_u.plot(response.t, response.u[i], color=line.get_color(), label=label)
            ax_y.plot(response.t, response.r, label="reference", **REFERENCE)
            band = 0.02 * abs(loop.step_height)
            ax_y.axhspan(loop.r2 - band, loop.r2 + band, color="0.9", zorder=0, label="2 % band")
        ax_y.set_ylabel(axis_label("output y", output_unit))
        ax_u.set_ylabel(axis_label("command u", input_unit))
        ax_u.set_xlabel(axis_label("time since step t", "s"))
        legend_outside(ax_y)
        ax_y.set_title(title or "step response")
    return fig


def figure_to_rgb(fig) -> np.ndarray:
    """Render a figure to an ``uint8`` array of shape (height, width, 3) and close it."""
    plt = pyplot()
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return image


def cost_surface(truth, ax=None, points=None, path=None, levels: int = 30):
    """Heat map of a :class:`~gbo_envs.ground_truth.GroundTruth` cost surface with ``J*`` marked.

    Axes: the two gains in their units (``truth.gain_units``); colour bar: cost J (-).

    Parameters
    ----------
    truth : GroundTruth
        Two-gain ground truth.
    ax : matplotlib Axes, optional
    points : dict of str -> ndarray of shape (n, 2), optional
        Labelled gains to overlay as hollow circles (e.g. twin evaluations).
    path : ndarray of shape (n, 2), optional
        A tuner's plant experiments in the order it ran them: drawn as a line
        through numbered points (numbered from 1), its last point marked.
    levels : int
        Number of contour levels.
    """
    plt = pyplot()
    if len(truth.axes) != 2:
        raise ValueError(f"truth: cost surfaces are drawn for 2 gains, got {len(truth.axes)}")
    with style():
        if ax is None:
            _, ax = plt.subplots(figsize=(7, 5))
        x, y = truth.axes
        contour = ax.contourf(x, y, truth.costs.T, levels=levels, cmap="viridis", zorder=0)
        ax.figure.colorbar(contour, ax=ax, label=COST_LABEL)
        ax.grid(False)
        for label, gains in (points or {}).items():
            gains = np.atleast_2d(gains)
            ax.plot(gains[:, 0], gains[:, 1], "o", mfc="none", mec="w", ms=6, mew=1.0, zorder=2, label=label)
        if path is not None:
            path = np.atleast_2d(np.asarray(path, dtype=float))
            ax.plot(path[:, 0], path[:, 1], "-", color="w", lw=0.8, alpha=0.8, zorder=3)
            ax.plot(path[:, 0], path[:, 1], "o", color="tab:orange", mec="k", ms=5, zorder=4, clip_on=False,
                    label=f"tuner's path ({len(path)} experiments)")
            for n, (g0, g1) in enumerate(path, start=1):
                ax.annotate(str(n), (g0, g1), fontsize=6, color="w", xytext=(3, 3), textcoords="offset points",
                            zorder=5)
            ax.plot(*path[-1], "s", mfc="none", mec="tab:red", ms=9, mew=1.5, zorder=4, clip_on=False,
                    label="last experiment")
        ax.plot(*truth.gains, "*", color="tab:red", mec="w", ms=15, zorder=6, label=f"optimum J* = {truth.cost:.3f}")
        units = tuple(truth.gain_units) or (None, None)
        ax.set_xlabel(axis_label(f"gain {truth.gain_names[0]}", units[0]))
        ax.set_ylabel(axis_label(f"gain {truth.gain_names[1]}", units[1]))
        legend_outside(ax, below=True)
    return ax


def convergence_curves(runs, optimum: float | None = None) -> dict[str, np.ndarray]:
    """Best cost after each plant experiment of many runs, grouped by tuner.

    Parameters
    ----------
    runs : iterable of TuningResult, or DataFrame
        Tuning results (their ``tuner`` and plant rows), or a runs table with
        the columns ``tuner``, ``experiment`` (1-based), a run column (``seed``
        or ``batch``) and ``true_cost`` (or ``cost``), plant rows only when a
        ``source`` column is present.
    optimum : float, optional
        ``J*``: the curves become optimality ratios ``J / J*`` of the lowest
        noise-free cost so far; without it, the lowest measured cost so far.

    Returns
    -------
    dict of str -> ndarray of shape (n_runs, n_experiments)
        One row per run (shorter runs padded with their last value).
    """
    grouped: dict[str, list[np.ndarray]] = {}
    for tuner, costs in _run_costs(runs, use_true=optimum is not None):
        if costs.size:
            grouped.setdefault(tuner, []).append(np.fmin.accumulate(costs))
    if not grouped:
        raise ValueError("runs: no plant experiment in any run")
    scale = 1.0 if optimum is None else float(optimum)
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"optimum: must be a finite cost > 0, got {optimum}")
    curves = {}
    for tuner, rows in grouped.items():
        width = max(row.size for row in rows)
        curves[tuner] = np.array([np.pad(row, (0, width - row.size), mode="edge") for row in rows]) / scale
    return curves


def _run_costs(runs, use_true: bool) -> Iterable[tuple[str, np.ndarray]]:
    """``(tuner, costs of its plant experiments in order)`` per run."""
    if hasattr(runs, "columns"):  # a DataFrame
        frame = runs
        if "source" in frame.columns:
            frame = frame[frame["source"] == "plant"]
        run_column = next((c for c in ("seed", "batch", "run") if c in frame.columns), None)
        if "tuner" not in frame.columns or "experiment" not in frame.columns or run_column is None:
            raise ValueError("runs: a runs table needs the columns tuner, experiment and seed (or batch), "
                             f"got {list(frame.columns)}")
        column = "true_cost" if use_true and "true_cost" in frame.columns else "cost"
        for (tuner, _), part in frame.groupby(["tuner", run_column], sort=False):
            yield str(tuner), part.sort_values("experiment")[column].to_numpy(dtype=float)
        return
    key = "true_cost" if use_true else "cost"
    for result in runs:
        if not hasattr(result, "plant_rows"):
            raise TypeError(f"runs: expected TuningResult objects or a DataFrame, got {type(result).__name__}")
        yield result.tuner, np.array([row.get(key, row["cost"]) for row in result.plant_rows], dtype=float)


def convergence_figure(runs, optimum: float | None = None, level: float = 0.95, ax=None,
                       title: str | None = None):
    """Mean best cost (or optimality ratio) against plant experiments over many runs, with a confidence band.

    Axes: plant experiments (count, from 1); minimum observed optimality ratio
    ``J / J*`` (-) when ``optimum`` is given, else best measured cost J (-).
    The band is the ``level`` confidence interval of the mean over the runs
    (Student t); a tuner with one run gets no band.

    Parameters
    ----------
    runs : iterable of TuningResult, or DataFrame
        See :func:`convergence_curves`.
    optimum : float, optional
        Ground-truth ``J*``.
    level : float, default 0.95
        Coverage of the band, in (0, 1).
    ax : matplotlib Axes, optional
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    from scipy import stats

    if not 0.0 < float(level) < 1.0:
        raise ValueError(f"level: must be in (0, 1), got {level}")
    curves = convergence_curves(runs, optimum)
    plt = pyplot()
    with style():
        if ax is None:
            _, ax = plt.subplots(figsize=(7.5, 4.2))
        for tuner, curve in curves.items():
            x = np.arange(1, curve.shape[1] + 1)
            mean = curve.mean(axis=0)
            line = ax.plot(x, mean, lw=2, label=f"{tuner}: mean of {curve.shape[0]} runs")[0]
            if curve.shape[0] > 1:
                half = stats.t.ppf(0.5 + level / 2, curve.shape[0] - 1) * curve.std(axis=0, ddof=1) / np.sqrt(
                    curve.shape[0])
                ax.fill_between(x, mean - half, mean + half, color=line.get_color(), alpha=0.2, lw=0,
                                label=f"{tuner}: {level:.0%} confidence band of the mean")
        if optimum is not None:
            ax.axhline(1.0, label="optimum (ratio 1)", **REFERENCE)
        ax.set_xlabel(axis_label("plant experiments", "count"))
        ax.xaxis.set_major_locator(plt.MaxNLocator(integer=True))
        ax.set_ylabel(axis_label("minimum observed optimality ratio J/J*", "-") if optimum is not None
                      else axis_label("best measured cost J", "-"))
        ax.set_title(title or "convergence over runs")
        legend_outside(ax)
    return ax.figure
