"""The figure of a fitted static map (:mod:`agents.twin.static_map`) for the workbench's report."""

from __future__ import annotations

from agents.twin.model import GreyFit
from agents.twin.static_map import map_curve
from gbo_envs.lazy_pyplot import pyplot
from gbo_envs.plotting import REFERENCE, axis_label, legend_outside, style

__all__ = ["map_figure"]


def map_figure(fit: GreyFit, name: str, unit: str = ""):
    """The fitted map ``m(x)`` of ``fit``'s ``name`` (``"input_map"`` or ``"output_map"``) with its breakpoints,
    against the identity (the linear model).

    Axes: the map's input (the commanded input u for an input map, the plant output for an output map) in
    ``unit``; its output (the plant input, or the measured output) in ``unit``.

    Raises
    ------
    ValueError
        ``fit`` has no map ``name``.
    """
    if name not in fit.effect_params:
        raise ValueError(f"fit: a model with the {name} effect, got {fit.spec.label}")
    x, m, knots, values = map_curve(fit, name)
    plt = pyplot()
    source, target = (("commanded input u", "plant input m(u)") if name == "input_map" else
                      ("plant output y", "measured output m(y)"))
    with style():
        fig, ax = plt.subplots(figsize=(6.0, 4.4))
        ax.plot(x, x, label="identity (the linear model)", **REFERENCE)
        ax.plot(x, m, color="tab:blue", lw=1.8, label=f"fitted {name.replace('_', ' ')}")
        ax.plot(knots, values, "o", color="tab:blue", label="breakpoints")
        ax.set_xlabel(axis_label(source, unit))
        ax.set_ylabel(axis_label(target, unit))
        ax.set_title(f"fitted {name.replace('_', ' ')} ({fit.spec.label})")
        legend_outside(ax, below=True)
    return fig
