"""The error ladder and a diagnosis in words: what each added effect bought, and what to do next.

Every step of the ladder reads as one line, e.g.::

    + coulomb_friction (torque 4.9 ± 0.3 V, 95 % CI [4.6, 5.2]): RMSE 0.41 → 0.025 rad/s (-94 %, 16×),
      fit 71.0 % → 98.0 %

RMSE and fit % are both on the fitted data (the training error of the model), each
with its before and after; the held-out error that decides the ranking is reported
apart. The intervals come from :func:`agents.twin.diagnose.effect_intervals`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from agents.twin.residual_shape import FAR_FROM_FLOOR, residual_shape, shape_text, tried_general
from gbo_envs.physics.effects import EFFECTS, describe_effect

__all__ = ["advice", "format_interval", "number", "pairs_text", "params_text", "rung_text", "unit_text",
           "unobservable_lines"]

#: Significant digits of a quantity in the texts and tables (the noise floor, RMSEs, parameters).
DIGITS = 3


def number(value, digits: int = DIGITS) -> str:
    """``value`` in fixed-point notation to ``digits`` significant digits (``-12800``, ``0.0929``); never ``1e+04``.

    None and NaN give ``"n/a"``; infinities ``"inf"`` / ``"-inf"``; integers, booleans and words as they are.
    """
    if value is None:
        return "n/a"
    if isinstance(value, (bool, str, np.bool_)) or isinstance(value, (int, np.integer)):
        return str(value)
    value = float(value)
    if math.isnan(value):
        return "n/a"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return np.format_float_positional(value, precision=digits, unique=False, fractional=False, trim="-")


def params_text(effect: str, params: Mapping, units: Mapping[str, str] | None = None, output: str = "speed",
                intervals: Mapping | None = None) -> str:
    """An effect's fitted parameters with their units: ``"limit = 159.9 V"``, ``"frequency = 66.7 rad/s"``.

    The units are the catalogue's (:func:`gbo_envs.physics.describe_effect`) in the data's units
    (:func:`unit_text`), or those of ``intervals`` (a grown order's ``{"value", "unit"}``).
    """
    catalogue = {p.name: p.unit for p in describe_effect(effect)} if effect in EFFECTS else {}
    cells = []
    for name, value in params.items():
        unit = (intervals or {}).get(name, {}).get("unit") or catalogue.get(name, "")
        text = unit_text(unit, units, output) if unit else ""
        cells.append(f"{name.replace('_', ' ')} = {number(value, 4)}" + (f" {text}" if text else ""))
    return ", ".join(cells)


def pairs_text(pairs) -> str:
    """Pairs of candidates in words: ``"zero and pole pair; Coulomb friction and stiction"``."""
    return "; ".join(" and ".join(name.replace("_", " ") for name in pair) for pair in pairs)



def unit_text(catalogue_unit: str, units: Mapping[str, str] | None = None, output: str = "speed") -> str:
    """A catalogue unit (``"input units"``, ``"output units"``, ``"speed units"``, ...) in the data's units.

    Parameters
    ----------
    catalogue_unit : str
        :attr:`gbo_envs.physics.EffectParameter.unit`.
    units : mapping, optional
        ``{"y": unit of the output, "u": unit of the input}`` (e.g. ``{"y": "rad/s", "u": "V"}``);
        without one, the catalogue's words stay.
    output : {"speed", "position"}
        What ``y`` measures (speed units are ``y``'s, or ``y``'s per second for a position).
    """
    units = units or {}
    y, u = units.get("y"), units.get("u")
    speed = None if y is None else (y if output != "position" else f"{y}/s")
    position = None if y is None else (y if output == "position" else (y[:-2] if y.endswith("/s") else f"{y}·s"))
    words = {"input units": u, "output units": y, "speed units": speed,
             "input units per speed unit": None if u is None or speed is None else f"{u}/({speed})",
             "position units (rad for a speed loop in rad/s)": position or "position units"}
    if catalogue_unit in ("1", "-"):  # dimensionless: no unit after the number
        return ""
    return words.get(catalogue_unit) or catalogue_unit


def _y_unit(units: Mapping[str, str] | None) -> str:
    return (units or {}).get("y") or "(units of y)"


def format_interval(name: str, ci: Mapping, unit: str) -> str:
    """``"limit 159.9 ± 0.04 V, 95 % CI [159.9, 160]"``, or ``"step 0.77 rad/s (grid fit, no interval)"``."""
    value, std = ci.get("value"), ci.get("std")
    if std == "n/a":  # a property of a grown structure (a resonance's frequency): no interval of its own
        return f"{name} {value:.4g} {unit}".rstrip()
    if std is None or not math.isfinite(std):
        how = "grid fit, no interval" if std is None else "not determined by these data"
        return f"{name} {value:.4g} {unit} ({how})".replace("  ", " ")
    half = ci["high"] - value
    digits = max(0, 1 - math.floor(math.log10(half))) if half > 0 else 3  # two significant digits of the half-width
    return (f"{name} {value:.{digits}f} ± {half:.2g} {unit}, 95 % CI [{ci['low']:.{digits}f}, "
            f"{ci['high']:.{digits}f}]").replace(" ,", ",")


def rung_text(rung: Mapping, units: Mapping[str, str] | None = None, output: str = "speed") -> str:
    """One ladder step in words and numbers (see the module docstring); the first rung states the start."""
    y = _y_unit(units)
    before = rung.get("before")
    if before is None:
        return f"{rung['model']}: RMSE {number(rung['rmse'])} {y}, fit {rung['fit_percent']:.1f} %"
    params = "; ".join(format_interval(name, ci, unit_text(ci.get("unit", ""), units, output))
                       for name, ci in (rung.get("added_params") or {}).items())
    change = 100.0 * (rung["rmse"] / before["rmse"] - 1.0)
    return (f"+ {rung['added']}" + (f" ({params})" if params else "") + f": RMSE {number(before['rmse'])} → "
            f"{number(rung['rmse'])} {y} ({change:+.0f} %, {rung['rmse_factor']:.3g}×), "
            f"fit {before['fit_percent']:.1f} % → {rung['fit_percent']:.1f} %")


def unobservable_lines(diagnosis) -> list[str]:
    """One line per effect the data cannot show: why, and the experiment that would show it."""
    return [f"{u['effect']} is not observable here ({u['reason']}); to test it: {u['experiment']}"
            for u in diagnosis.unobservable]


def advice(diagnosis, effects: Sequence[str], data: str = "DATA.csv", stopped_at_max: bool = False,
           units: Mapping[str, str] | None = None) -> str:
    """The last line of a diagnosis or a ladder: what the user should do next.

    Parameters
    ----------
    diagnosis : Diagnosis
        The last diagnosis made (of the model with ``effects``).
    effects : sequence of str
        Effects of that model.
    data : str
        The data's name in the commands suggested.
    stopped_at_max : bool
        The ladder stopped at its ``max_steps`` although ``diagnosis.best`` still helps.

    When no candidate helps but the model's RMSE is above :data:`agents.twin.residual_shape.FAR_FROM_FLOOR`
    noise floors, the advice does not just stop: it says what the residual looks like and which general
    candidates were tried (:func:`agents.twin.residual_shape.shape_text`).
    """
    y = _y_unit(units)
    best = next((c for c in getattr(diagnosis, "candidates", ()) if c["effect"] == diagnosis.best), None)
    if best is not None and best.get("kind") == "order":  # the linear part grows: its orders, not --effects
        spec = diagnosis.fits[diagnosis.best].spec
        flags = f"--poles {spec.n_poles} --zeros {spec.n_zeros}" + (f" --integrators {spec.n_integrators}"
                                                                      if spec.n_integrators else "")
        more = f" --effects {','.join(effects)}" if effects else ""
        what = diagnosis.best.replace("_", " ")
        if stopped_at_max:
            return (f"next: a {what} still improves the model; raise --max-steps, or run "
                    f"`gbo twin diagnose {data} {flags}{more}` to look for a further effect")
        return f"next: grow the linear part by a {what}, then look further: `gbo twin diagnose {data} {flags}{more}`"
    if diagnosis.best is not None:
        more = ",".join([*effects, diagnosis.best_label])
        if stopped_at_max:
            return (f"next: {diagnosis.best} still improves the model; raise --max-steps, or run "
                    f"`gbo twin diagnose {data} --effects {more}` to look for a further effect")
        return (f"next: add {diagnosis.best}, then look for a further effect: "
                f"`gbo twin diagnose {data} --effects {more}`")
    pairs = [p for p in diagnosis.indistinguishable if all(e not in {u["effect"] for u in diagnosis.unobservable}
                                                           for e in p)]
    if pairs:
        return f"next: {pairs[0][0]} and {pairs[0][1]} explain the data equally well; {diagnosis.suggested_experiment}"
    noise = diagnosis.noise_rmse
    if noise is not None and diagnosis.current.rmse <= 1.5 * noise:
        return (f"stop: the model is at the noise floor (RMSE {number(diagnosis.current.rmse)} {y}, noise-floor "
                f"estimate {number(noise)} {y}); no further effect can be told from measurement noise")
    far = noise is not None and noise > 0 and diagnosis.current.rmse > FAR_FROM_FLOOR * noise
    data_ = getattr(diagnosis, "data_", None)
    if far and data_ is not None:  # not at the floor: what the residual looks like, and what was tried
        shape = residual_shape(data_, diagnosis.current, getattr(diagnosis, "modes", None))
        tried = tried_general(getattr(diagnosis, "candidates", []))
        return (f"no candidate passes the rules, but the model is not at the noise floor: "
                f"{shape_text(shape, tried, noise, units)}. Look at the residuals (`gbo twin resid {data}"
                + (f" --effects {','.join(effects)}" if effects else "") + "`), try the model orders (--poles, "
                "--zeros), or record an experiment that excites what the residual shows"
                + _unseen_tail(diagnosis))
    tail = _unseen_tail(diagnosis)
    return (f"stop adding catalogue effects: none improves the held-out error beyond its complexity cost "
            f"(RMSE {number(diagnosis.current.rmse)} {y}" + ("" if noise is None else f", noise floor estimate "
            f"{number(noise)} {y}") + "); look at the residuals (`gbo twin resid " + data +
            (f" --effects {','.join(effects)}" if effects else "") + "`) or the model orders (--poles, --zeros)"
            + tail)


def _unseen_tail(diagnosis) -> str:
    """The advice's note on the effects the data cannot show (empty when there are none)."""
    if not diagnosis.unobservable:
        return ""
    return (f"; {len(diagnosis.unobservable)} effect(s) cannot be seen in these data (listed above), run the "
            f"experiments named there to test them")
