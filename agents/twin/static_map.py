"""Static maps as candidates of a diagnosis: an input map (Hammerstein) or an output map (Wiener), piecewise linear.

MATLAB's ``nlhw`` with a ``pwlinear`` estimator is the anchor: straight lines between breakpoints, fitted
together with the linear part (:mod:`gbo_envs.physics.static_map`), the breakpoints estimated as ``pwlinear``
estimates them. Here the map has five breakpoints over the range of its signal (the commanded input ``u`` for
an input map, the measured output ``y`` for an output map), widened by :data:`RANGE_MARGIN` on each side. Two
of the values are held on the identity, since the linear part already carries the gain and the rest levels
the offset (a map ``c m(x) + e`` and a linear part ``G / c`` replay alike):

* a signal of one sign: the outer two, ``m(k_0) = k_0`` and ``m(k_4) = k_4``; ``k_1 .. k_3`` and
  ``v_1 .. v_3`` are fitted;
* a signal that takes both signs: the breakpoint ``k_1`` is put at zero with ``m(0) = 0``, and
  ``m(k_4) = k_4``; ``k_2, k_3`` and ``v_0, v_2, v_3`` are fitted. A drive or a sensor that works in one
  direction only is ``v_0 = 0``: nothing below zero.

A fitted breakpoint starts where :func:`map_options` places it and moves at most :data:`KNOT_REACH` of the
way to its neighbours' starts, so the breakpoints stay in order. A kink of the map between two starting
breakpoints (a drive whose gain falls above 3 V, placed at 2.6 and 4 V) is then found where it is, not
smeared over the segments around it.

The maps are tried after the catalogue (:func:`map_candidates`, and :func:`agents.twin.ranking.rank` puts a
good catalogue effect first unless the map clearly explains and predicts more).
"""

from __future__ import annotations

import numpy as np

from agents.twin.fidelity import rmse
from agents.twin.model import GreyFit, fitted_parameters, output_error
from agents.twin.records import Batch
from agents.twin.simulation import simulate_sets
from gbo_envs.physics.static_map import N_KNOTS, STATIC_MAPS, piecewise_linear

__all__ = ["KNOT_REACH", "MAP_NAMES", "RANGE_MARGIN", "identity_theta", "map_curve", "map_evidence", "map_options",
           "map_size", "map_starts"]

#: The static maps tried: an input map and an output map (:data:`gbo_envs.physics.static_map.STATIC_MAPS`).
MAP_NAMES: tuple[str, ...] = tuple(STATIC_MAPS)
#: Share of the signal's range by which the breakpoints reach beyond it on each side: a model's output goes
#: where a one-way or clipping sensor does not show it.
RANGE_MARGIN = 0.1
#: A signal takes both signs when it goes beyond this share of its range on each side of zero.
SIGN_SHARE = 0.02
#: Share of the gap to each neighbouring breakpoint's start that a fitted breakpoint may move: below one
#: half, two neighbours cannot meet.
KNOT_REACH = 0.45


def _signal(name: str, data: Batch) -> np.ndarray:
    return (data.u if name == "input_map" else data.y)[data.mask]


def map_options(name: str, data: Batch) -> dict:
    """The breakpoints and held values of map ``name`` on ``data`` (the block's options, module docstring).

    The outer breakpoints are the signal's extremes (an output map's widened by :data:`RANGE_MARGIN` of the
    range: the model's output goes where a one-way or clipping sensor does not show it), the inner ones at
    its quartiles (of its positive part, for a signal of both signs), where the data are: the map is
    resolved where it acts.

    Returns
    -------
    dict
        ``{"k0".."k4"}`` (units of the map's signal), the held values and, for a signal of both signs,
        ``"variant": "zero"``.
    """
    x = _signal(name, data)
    lo, hi = float(np.min(x)), float(np.max(x))
    span = max(hi - lo, 1e-12 * max(abs(hi), 1.0))
    margin = RANGE_MARGIN * span if name == "output_map" else 0.0
    a, b = lo - margin, hi + margin
    if lo < -SIGN_SHARE * span and hi > SIGN_SHARE * span or (lo <= 0.0 < hi and name == "output_map"):
        inner = _inner(x[x > 0.0], 0.0, b, 2)
        knots = [a, 0.0, *inner, b]
        return {**{f"k{i}": float(k) for i, k in enumerate(knots)}, "v1": 0.0, "v4": float(b), "variant": "zero"}
    knots = [a, *_inner(x, a, b, 3), b]
    return {**{f"k{i}": float(k) for i, k in enumerate(knots)}, "v0": float(a), "v4": float(b)}


def _inner(x: np.ndarray, a: float, b: float, n: int) -> list[float]:
    """``n`` inner breakpoints between ``a`` and ``b``: the quantiles of ``x`` at ``1/(n+1) .. n/(n+1)``, or
    evenly spaced where those come closer than a tenth of the range to one another or to the ends."""
    even = list(np.linspace(a, b, n + 2)[1:-1])
    if x.size < 4 * n:
        return even
    q = list(np.quantile(x, np.arange(1, n + 1) / (n + 1)))
    return q if np.min(np.diff([a, *q, b])) > 0.1 * (b - a) else even


def _knots(options) -> np.ndarray:
    options = dict(options)
    return np.array([options[f"k{i}"] for i in range(N_KNOTS)])


def identity_theta(name: str, options) -> np.ndarray:
    """The fitted parameters of map ``name`` with ``options`` that make it the identity: its breakpoints, and
    the values there equal to them (``options`` holds the breakpoints, fitted ones included)."""
    knots = _knots(options)
    return np.array([knots[int(p[1:])] for p, _ in fitted_parameters(name, options)])


def map_starts(name: str, options, data: Batch) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """Starting values, bounds and scales of the fitted values of map ``name`` (as
    :func:`agents.twin.guesses.effect_starts` gives them for an effect).

    The identity, and for a signal of both signs also the one-way map (``v_0 = 0``). The values stay within
    the breakpoints' range widened by its length on each side; a breakpoint within :data:`KNOT_REACH` of the
    gaps to its neighbours. A breakpoint that ``options`` lacks (one given as a fitted value, which the fit
    then starts from) is placed on ``data`` (:func:`map_options`).
    """
    options = dict(options)
    if any(f"k{i}" not in options for i in range(N_KNOTS)):
        options = map_options(name, data) | options
    knots = _knots(options)
    span = knots[-1] - knots[0]
    names = [p for p, _ in fitted_parameters(name, options)]
    start = identity_theta(name, options)
    lower, upper, scale = np.full(start.size, knots[0] - span), np.full(start.size, knots[-1] + span), \
        np.full(start.size, 0.25 * span)
    for j, p in enumerate(names):
        if p.startswith("k"):
            i = int(p[1:])
            lower[j] = knots[i] - KNOT_REACH * (knots[i] - knots[i - 1])
            upper[j] = knots[i] + KNOT_REACH * (knots[i + 1] - knots[i])
            scale[j] = 0.25 * min(knots[i] - knots[i - 1], knots[i + 1] - knots[i])
    starts = [start]
    if options.get("variant") == "zero":
        one_way = start.copy()
        one_way[names.index("v0")] = 0.0
        starts.append(one_way)
    return starts, lower, upper, scale


def map_curve(fit: GreyFit, name: str, n: int = 201) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(x, m(x), knots, values)``: the fitted map of ``fit`` over its breakpoints' range, and the breakpoints."""
    params = fit.effect_params[name]
    knots = np.array([params[f"k{i}"] for i in range(N_KNOTS)])
    values = np.array([params[f"v{i}"] for i in range(N_KNOTS)])
    x = np.linspace(knots[0], knots[-1], n)
    return x, piecewise_linear(x, knots, values), knots, values


def map_size(data: Batch, fit: GreyFit, name: str) -> float:
    """RMS change of the output (units of ``y``) when the map of ``fit`` is made the identity, all else kept."""
    spec = fit.spec
    theta0 = fit.theta.copy()
    pos = spec.n_linear + 1 + sum(len(fitted_parameters(n_, o)) for n_, o in spec.effects[: spec.effect_names.index(
        name)])
    identity = identity_theta(name, fit.effect_params[name])  # at the fitted breakpoints
    theta0[pos : pos + identity.size] = identity
    rows = np.arange(data.n_records)
    sims = simulate_sets(data, [(spec, np.concatenate([th, fit.nuisance()]), rows) for th in (fit.theta, theta0)])
    size = rmse(output_error(sims[0], sims[1], data.mask, spec, data.closed_loop), mask=data.mask)
    return size if np.isfinite(size) else 0.0


def map_evidence(name: str, data: Batch, current: GreyFit, fit: GreyFit) -> str:
    """The fitted map in words: its local gain (slope) on each segment inside the data, and a one-way zero."""
    x, _, knots, values = map_curve(fit, name)
    slopes = np.diff(values) / np.diff(knots)
    sig = _signal(name, data)
    lo, hi = float(np.min(sig)), float(np.max(sig))
    inside = [i for i in range(slopes.size) if knots[i + 1] > lo and knots[i] < hi]
    what = "input" if name == "input_map" else "output"
    side = "the drive (Hammerstein: before the linear part)" if name == "input_map" else \
        "the sensor (Wiener: after the linear part)"
    text = (f"a static {what} map in {side}: slope " + ", ".join(
        f"{slopes[i]:.3g} on [{knots[i]:.3g}, {knots[i + 1]:.3g}]" for i in inside))
    if dict(fit.spec.effects[fit.spec.effect_names.index(name)][1]).get("variant") == "zero" and \
            abs(slopes[0]) < 0.1 * max(np.max(np.abs(slopes[1:])), 1e-300):
        text += f"; nothing below zero: the {'drive' if name == 'input_map' else 'sensor'} works one way only"
    change = 100.0 * (fit.rmse / current.rmse - 1.0) if current.rmse > 0 else 0.0  # < 0: the error falls
    return text + f" (RMSE {current.rmse:.3g} -> {fit.rmse:.3g}, {change:+.0f} %)"
