"""Matplotlib figures for plant envs: step responses and cost surfaces."""

from __future__ import annotations

import numpy as np

from gbo_envs.lazy_pyplot import pyplot

__all__ = ["response_figure", "figure_to_rgb", "cost_surface"]


def response_figure(loop, response, labels=None, title: str | None = None):
    """Figure with the output ``y`` and command ``u`` of a :class:`~gbo_envs.closed_loop.StepResponse`.

    Parameters
    ----------
    loop : ClosedLoop
        The loop that produced ``response`` (for the reference and the 2 % band).
    response : StepResponse or None
    labels : list of str, optional
        One label per response row.
    """
    plt = pyplot()
    fig, (ax_y, ax_u) = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
    if response is not None:
        for i in range(response.y.shape[0]):
            label = labels[i] if labels else None
            ax_y.plot(response.t, response.y[i], label=label)
            ax_u.plot(response.t, response.u[i])
        ax_y.plot(response.t, response.r, "k--", lw=1, label="reference")
        band = 0.02 * abs(loop.step_height)
        ax_y.axhspan(loop.r2 - band, loop.r2 + band, color="0.9", label="2 % band")
    ax_y.set_ylabel("output y")
    ax_u.set_ylabel("command u")
    ax_u.set_xlabel("time since step [s]")
    if response is not None:
        ax_y.legend(loc="lower right", fontsize=8)
    if title:
        ax_y.set_title(title)
    fig.tight_layout()
    return fig


def figure_to_rgb(fig) -> np.ndarray:
    """Render a figure to an ``uint8`` array of shape (height, width, 3) and close it."""
    plt = pyplot()
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return image


def cost_surface(truth, ax=None, points=None, levels: int = 30):
    """Contour plot of a :class:`~gbo_envs.ground_truth.GroundTruth` cost surface.

    Parameters
    ----------
    truth : GroundTruth
    ax : matplotlib Axes, optional
    points : dict of str -> ndarray of shape (n, 2), optional
        Labelled gains to overlay (e.g. a tuner's queries).
    levels : int
        Number of contour levels.
    """
    plt = pyplot()
    if len(truth.axes) != 2:
        raise ValueError(f"truth: cost surfaces are drawn for 2 gains, got {len(truth.axes)}")
    if ax is None:
        _, ax = plt.subplots(figsize=(6, 5))
    x, y = truth.axes
    contour = ax.contourf(x, y, truth.costs.T, levels=levels, cmap="viridis")
    ax.figure.colorbar(contour, ax=ax, label="expected cost J (dimensionless)")
    ax.plot(*truth.gains, "r*", ms=14, label=f"optimum J* = {truth.cost:.3f}")
    for label, gains in (points or {}).items():
        gains = np.atleast_2d(gains)
        ax.plot(gains[:, 0], gains[:, 1], "o", mfc="none", label=label)
    units = tuple(truth.gain_units) or ("", "")
    ax.set_xlabel(f"{truth.gain_names[0]} ({units[0]})" if units[0] else truth.gain_names[0])
    ax.set_ylabel(f"{truth.gain_names[1]} ({units[1]})" if units[1] else truth.gain_names[1])
    ax.legend(loc="upper right", fontsize=8)
    return ax
