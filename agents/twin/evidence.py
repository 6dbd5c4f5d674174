"""What the data say about each effect: its residual signature, what the data cannot show, and which
experiment would separate two effects that explain the data equally well."""

from __future__ import annotations

import numpy as np

from agents.twin.fidelity import rmse
from agents.twin.greybox import GreyData, GreyFit
from agents.twin.residuals import residuals

__all__ = ["REVEALING_EXPERIMENTS", "SEPARATING_EXPERIMENTS", "effect_evidence", "excitation_notes",
           "separating_experiment", "unobservable_effects"]


#: Experiments that separate two effects which explain the data equally well.
SEPARATING_EXPERIMENTS: dict[frozenset, str] = {
    frozenset({"coulomb_friction", "offset"}): "a speed reversal separates coulomb_friction from offset",
    frozenset({"coulomb_friction", "dead_zone"}): "a slow input ramp through zero at standstill separates "
                                                  "dead_zone (acts on the input) from coulomb_friction (on the speed)",
    frozenset({"coulomb_friction", "stiction"}): "a slow speed reversal with a dwell at zero speed separates "
                                                 "stiction (holds at rest) from coulomb_friction",
    frozenset({"coulomb_friction", "backlash"}): "an input reversal while the speed keeps its sign separates "
                                                 "backlash from coulomb_friction",
    frozenset({"dead_zone", "backlash"}): "an input reversal away from zero input separates backlash from dead_zone",
    frozenset({"dead_zone", "stiction"}): "a reversal at speed separates dead_zone (still active while moving) "
                                          "from stiction",
    frozenset({"drift", "time_delay"}): "repeating the first experiment at the end separates drift from time_delay",
}
_ONE_SIDED = {
    "saturation": "a larger step (commands beyond the fitted limit) separates saturation from {other}",
    "time_delay": "a faster input change (higher controller gain) separates time_delay from {other}",
    "drift": "repeating the first experiment at the end of the session separates drift from {other}",
    "quantization": "a slow output ramp over many sensor levels separates quantization from {other}",
    "cogging": "a slow constant-speed run over several revolutions separates cogging from {other}",
}


#: The experiment that would show an effect :func:`excitation_notes` finds unobservable in the data.
REVEALING_EXPERIMENTS: dict[str, str] = {
    "coulomb_friction": "a step through zero speed (e.g. the reference from +r to -r) makes the friction change sign",
    "stiction": "a slow speed reversal with a dwell at zero speed shows the breakaway",
    "backlash": "an input reversal (a step down after a step up) shows the play",
    "dead_zone": "a step whose input crosses zero (e.g. to a negative reference) shows the dead band",
    "drift": "several experiments over the session, the first repeated at the end, show a drift",
    "offset": "an experiment from a known zero (u = 0 and y = 0 at rest) pins a constant offset; otherwise every "
              "experiment's own rest level absorbs it",
}


def unobservable_effects(notes: dict[str, str]) -> list[dict]:
    """``[{"effect", "reason", "experiment"}]``: the effects of ``notes`` (:func:`excitation_notes`),
    why the data cannot show them, and the experiment that would (:data:`REVEALING_EXPERIMENTS`)."""
    return [{"effect": name, "reason": reason,
             "experiment": REVEALING_EXPERIMENTS.get(name, separating_experiment(name, "the current model"))}
            for name, reason in notes.items()]


def separating_experiment(a: str, b: str) -> str:
    """Which experiment would tell effects ``a`` and ``b`` apart."""
    key = frozenset({a, b})
    if key in SEPARATING_EXPERIMENTS:
        return SEPARATING_EXPERIMENTS[key]
    for name, text in _ONE_SIDED.items():
        if name in key:
            return text.format(other=b if name == a else a)
    return (f"an experiment over a wider range of inputs, speeds and directions (other gains, step sizes and "
            f"signs) separates {a} from {b}")





def excitation_notes(data: GreyData, output: str) -> dict[str, str]:
    """Effects the data cannot show, with the reason.

    Parameters
    ----------
    data : GreyData
    output : {"speed", "position"}
        What ``y`` measures.

    Returns
    -------
    dict
        ``{effect: reason}`` for the effects the records do not excite.
    """
    speed = data.y if output != "position" else np.gradient(data.y, data.dt, axis=1)
    notes = {}
    reversal = np.any((np.max(np.where(data.mask, speed, -np.inf), axis=1) > 0)
                      & (np.min(np.where(data.mask, speed, np.inf), axis=1) < 0))
    if not reversal:
        for name in ("coulomb_friction", "stiction"):
            notes[name] = "no speed reversal in the data: acts as a constant load, absorbed by the rest levels"
    # the play acts on the input path: it shows wherever the input turns back (after an overshoot of the
    # command, as in most PI step responses), whatever the sign of the speed
    step = np.diff(np.where(data.mask, data.u, np.nan), axis=1)
    if not np.any((np.nanmax(step, axis=1, initial=0.0) > 0) & (np.nanmin(step, axis=1, initial=0.0) < 0)):
        notes["backlash"] = "the input never turns back in the data: the play stays closed on one side, " \
                            "absorbed by the rest levels"
    crossing = np.any((np.max(np.where(data.mask, data.u, -np.inf), axis=1) > 0)
                      & (np.min(np.where(data.mask, data.u, np.inf), axis=1) < 0))
    if not crossing:
        notes["dead_zone"] = "the input never crosses zero: a dead zone acts as a constant input offset"
    if data.n_records < 2 or np.ptp(data.index) == 0:
        notes["drift"] = "one experiment: drift between experiments cannot be seen"
    notes["offset"] = "a constant offset is absorbed by the per-experiment rest levels"
    return notes


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    den = np.sqrt(np.sum(a**2) * np.sum(b**2))
    return float(np.sum(a * b) / den) if den > 0 else 0.0


def effect_evidence(name: str, data: GreyData, current: GreyFit, fit: GreyFit) -> str:
    """The residual signature of effect ``name`` in the current model's residual.

    Parameters
    ----------
    name : str
        Catalogue effect.
    data : GreyData
    current : GreyFit
        The model diagnosed.
    fit : GreyFit
        ``current`` with ``name`` added.

    Returns
    -------
    str
        One sentence: where the residual shows the effect, and the share of the residual power it explains.
    """
    m = data.mask
    e = (data.y - current.y_sim)[m]
    delta = (fit.y_sim - current.y_sim)[m]
    r = _corr(e, delta)
    share = 100.0 * max(0.0, 1.0 - fit.rmse**2 / max(current.rmse**2, 1e-300))
    params = fit.effect_params.get(name, {})
    speed = data.y if current.spec.output != "position" else np.gradient(data.y, data.dt, axis=1)
    tail = f"; adding it explains {share:.0f} % of the residual power"
    if name == "saturation":
        limit = params.get("limit", np.inf)
        over = np.abs(data.u[m]) > limit
        ratio = (rmse(e[over]) / max(rmse(e[~over]), 1e-300)) if over.any() and \
            (~over).any() else float("nan")
        return (f"command exceeds {limit:.4g} in {100 * over.mean():.1f} % of samples, where the error grows "
                f"({ratio:.1f}x the rms elsewhere; r={r:.2f})" + tail)
    if name == "dead_zone":
        half = params.get("width", 0.0) / 2
        inside = np.abs(data.u[m]) < half
        return (f"no output change for |u - u0| < {half:.4g} with u0 = 0 ({100 * inside.mean():.1f} % of samples); "
                f"residual matches the dead-zone response (r={r:.2f})" + tail)
    if name == "coulomb_friction":
        rs = _corr(e, np.sign(speed[m]))
        return f"residual correlates with sign of velocity (r={rs:.2f}; through the plant r={r:.2f})" + tail
    if name == "viscous_friction":
        return f"residual correlates with the velocity through the plant (r={r:.2f})" + tail
    if name == "stiction":
        slow = np.abs(speed[m]) <= max(params.get("threshold", 0.0), 1e-12)
        return f"residual concentrated at rest (|speed| <= threshold in {100 * slow.mean():.1f} % of samples; " \
               f"r={r:.2f})" + tail
    if name == "backlash":
        du = np.sign(np.gradient(data.u, axis=1))[m]
        return f"residual follows the direction of input changes (r={_corr(e, du):.2f}; through the play " \
               f"r={r:.2f})" + tail
    if name == "quantization":
        q = params.get("step", 0.0)
        return f"residual steps of size q = {q:.4g} (output levels are multiples of q; r={r:.2f})" + tail
    if name == "drift":
        per = np.array([np.sum(((data.y - current.y_sim) * (current.y_sim - current.y0[:, None]))[k][m[k]])
                        for k in range(data.n_records)])
        rd = _corr(data.index.astype(float), per) if data.n_records > 2 else float("nan")
        return (f"residual grows linearly with experiment index (r={rd:.2f}; rate {params.get('rate', 0):.3g} "
                f"per experiment on {params.get('parameter', 'gain')})" + tail)
    if name == "time_delay":
        ra = residuals(data, current, max_lag=min(60, max(int(data.mask.sum(axis=1).min()) // 4, 1)))
        pos = ra.ccf_lags >= 0
        k = int(ra.ccf_lags[pos][np.argmax(np.abs(ra.ccf[pos]))])
        return (f"cross-correlation peak at lag {k} samples ({k * data.dt:.4g} s); fitted extra delay "
                f"{params.get('delay', 0.0):.4g} s (r={r:.2f})" + tail)
    if name == "offset":
        return f"constant bias: no signature beyond the per-experiment rest levels (r={r:.2f})" + tail
    if name == "cogging":
        return f"residual periodic in position with period {params.get('period', 0.0):.4g} (r={r:.2f})" + tail
    return f"r={r:.2f}" + tail
