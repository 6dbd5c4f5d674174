"""What the data say about each effect: its residual signature, what the data cannot show, and which
experiment would separate two effects that explain the data equally well."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from agents.twin.coast_down import coast_downs, speed_tolerance
from agents.twin.fidelity import rmse
from agents.twin.guesses import residual_frequencies
from agents.twin.model import GreyFit
from agents.twin.modes import RESONANCE_DAMPING, Mode, plant_modes
from agents.twin.records import Batch
from agents.twin.residuals import residuals

__all__ = ["DRIFT_MIN_RECORDS", "REVEALING_EXPERIMENTS", "SEPARATING_EXPERIMENTS", "both_directions", "comes_to_rest",
           "effect_evidence", "excitation_notes", "order_change", "separating_experiment", "unobservable_effects"]


#: Fewest experiments, in time order, from which a drift can be told from the differences between
#: experiments (a trend over the session needs points on both sides of its middle and one to spare).
DRIFT_MIN_RECORDS = 5


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
    frozenset({"compliance", "pole_pair"}): "the same resonance: compliance is a coupling between two inertias "
                                            "(its static gain kept, a zero from its damping), pole_pair any extra "
                                            "mode; the speed measured on the motor's side of the coupling (an "
                                            "anti-resonance) separates them",
}
_ONE_SIDED = {
    "saturation": "a larger step (commands beyond the fitted limit) separates saturation from {other}",
    "time_delay": "a faster input change (higher controller gain) separates time_delay from {other}",
    "drift": "repeating the first experiment at the end of the session separates drift from {other}",
    "quantization": "a slow output ramp over many sensor levels separates quantization from {other}",
    "cogging": "a slow constant-speed run over several revolutions separates cogging from {other}",
    "compliance": "a step with a faster controller, which rings the coupling's resonance, or the speed measured on "
                  "the other side of the coupling, separates compliance from {other}",
}


#: The experiment that would show an effect :func:`excitation_notes` finds unobservable in the data.
REVEALING_EXPERIMENTS: dict[str, str] = {
    "coulomb_friction": "a step through zero speed (e.g. the reference from +r to -r) makes the friction change sign",
    "stiction": "a slow speed reversal with a dwell at zero speed shows the breakaway",
    "backlash": "an input reversal (a step down after a step up) shows the play",
    "dead_zone": "a step whose input crosses zero (e.g. to a negative reference), or an experiment that shows its "
                 "rest at zero input before the step, shows the dead band",
    "drift": f"at least {DRIFT_MIN_RECORDS} experiments over the session, the first repeated at the end, show a "
             "drift",
    "offset": "an experiment that starts at rest and shows it (the input held before the step, e.g. u = 0 and "
              "y = 0 for a while) pins a constant offset; otherwise every experiment's own rest level absorbs it",
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





def excitation_notes(data: Batch, output: str) -> dict[str, str]:
    """Effects the data cannot show, with the reason, judged on all experiments together.

    An effect that acts on a record as a constant load or input offset (a friction whose
    speed keeps its sign, a dead zone whose input keeps its sign, an offset) is absorbed
    by the free rest level and plant-input bias of a record whose rest the data do not show
    (:mod:`agents.twin.initial`, ``"steady"``/``"moving"``), but not by a record that shows
    its rest (``"rest"``): its rest level and command are measured, and the model must hold
    them. So, with ``speed`` the mechanical speed (``y``, or ``dy/dt`` for a position):

    * ``coulomb_friction``, ``stiction``: observable when a record reverses its speed, when
      a record shows its rest (a start from standstill shows the breakaway; a rest at speed
      shows the friction as a load, which several directions tell from an offset), when a
      record's speed comes to rest after moving (:func:`comes_to_rest`: the friction then holds), or
      when a record coasts down to standstill at zero drive (:mod:`agents.twin.coast_down`: the
      friction alone decelerates it, and stops it in finite time);
    * ``dead_zone``: when a record's input crosses zero, or a record shows its rest;
    * ``offset``: when a record shows its rest;
    * ``backlash``: when a record's input turns back;
    * ``drift``: with at least :data:`DRIFT_MIN_RECORDS` experiments in time order.

    Speeds and inputs count as crossing zero only beyond the output's noise (and the
    input's own scale), so that noise around standstill is not a reversal.

    Parameters
    ----------
    data : Batch
    output : {"speed", "position"}
        What ``y`` measures.

    Returns
    -------
    dict
        ``{effect: reason}`` for the effects the records do not excite.
    """
    mask = data.mask
    speed = data.y if output != "position" else np.gradient(data.y, data.dt, axis=1)
    speed_tol = speed_tolerance(speed, mask)
    u_tol = 1e-6 * max(float(np.max(np.abs(data.u[mask]))), 1e-300)
    reversal = bool(np.any(_both_signs(speed, mask, speed_tol)))
    crossing = bool(np.any(_both_signs(data.u, mask, u_tol)))
    shown = data.initial.pinned
    notes = {}
    if not reversal and not shown.any() and not np.any(comes_to_rest(speed, mask, speed_tol)) \
            and not np.any(coast_downs(data, output, speed_tol)):
        for name in ("coulomb_friction", "stiction"):
            notes[name] = ("no speed reversal in any experiment, no coast-down at zero drive and no experiment that "
                           "shows its rest: friction acts as a constant load, absorbed by each experiment's "
                           "estimated rest level")
    # the play acts on the input path: it shows wherever the input turns back (after an overshoot of the
    # command, as in most PI step responses), whatever the sign of the speed
    step = np.diff(np.where(mask, data.u, np.nan), axis=1)
    if not np.any((np.nanmax(step, axis=1, initial=0.0) > 0) & (np.nanmin(step, axis=1, initial=0.0) < 0)):
        notes["backlash"] = "the input never turns back in the data: the play stays closed on one side, " \
                            "absorbed by the rest levels"
    if not crossing and not shown.any():
        notes["dead_zone"] = ("the input never crosses zero and no experiment shows its rest: a dead zone acts as "
                              "a constant input offset, absorbed by each experiment's estimated rest level")
    if np.unique(data.index).size < DRIFT_MIN_RECORDS:
        notes["drift"] = (f"{np.unique(data.index).size} experiment(s): a drift over the session needs at least "
                          f"{DRIFT_MIN_RECORDS} experiments in time order to be told from the differences between "
                          "experiments")
    if not shown.any():
        notes["offset"] = ("no experiment shows its rest before the excitation: a constant offset is absorbed by "
                           "each experiment's estimated rest level")
    return notes


def both_directions(data: Batch, output: str) -> bool:
    """Whether the data show the mechanism moving both ways with its loads pinned: a record that reverses its
    speed, or records that show their rest (:mod:`agents.twin.initial`) with speeds of both signs between them.

    Only then can a friction level per direction (``coulomb_friction``'s ``asymmetry``) be told from a
    single level: elsewhere each record's estimated rest absorbs its own level.
    """
    mask = data.mask
    speed = data.y if output != "position" else np.gradient(data.y, data.dt, axis=1)
    tol = speed_tolerance(speed, mask)
    if np.any(_both_signs(speed, mask, tol)):
        return True
    shown = data.initial.pinned
    if not shown.any():
        return False
    high = np.max(np.where(mask, speed, -np.inf), axis=1)[shown] > tol
    low = np.min(np.where(mask, speed, np.inf), axis=1)[shown] < -tol
    return bool(high.any() and low.any())


#: Samples a speed must stay within its noise, after moving, for a record to come to rest (:func:`comes_to_rest`).
REST_SAMPLES = 20


def comes_to_rest(speed: np.ndarray, mask: np.ndarray, tol: float) -> np.ndarray:
    """Per record, whether the speed moves beyond ``tol`` and later stays within it for :data:`REST_SAMPLES`
    samples in a row (a slider that arrives and sticks), bool of shape (n_records,).

    There a friction no longer acts as a constant load: at standstill it holds against any smaller force,
    where a load (an unobserved rest command) would push on, so the model must explain it (the cascade of
    LinearMotorCascadeRig-v0: a 0.5 A friction whose slider sticks short of the target was taken for a
    0.97 A dead zone of the current).
    """
    out = np.zeros(speed.shape[0], dtype=bool)
    for k in range(speed.shape[0]):
        s = np.abs(speed[k][mask[k]])
        moving = np.flatnonzero(s > tol)
        if moving.size == 0:
            continue
        still = s[moving[0]:] <= tol
        run = np.diff(np.concatenate([[0], still.astype(int), [0]]))
        starts, ends = np.flatnonzero(run == 1), np.flatnonzero(run == -1)
        out[k] = bool(np.any(ends - starts >= REST_SAMPLES))
    return out


def _both_signs(x: np.ndarray, mask: np.ndarray, tol: float) -> np.ndarray:
    """Per record, whether ``x`` goes beyond ``+tol`` and below ``-tol`` (bool, shape (n_records,))."""
    high = np.max(np.where(mask, x, -np.inf), axis=1) > tol
    low = np.min(np.where(mask, x, np.inf), axis=1) < -tol
    return high & low


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    den = np.sqrt(np.sum(a**2) * np.sum(b**2))
    return float(np.sum(a * b) / den) if den > 0 else 0.0


def order_change(name: str, current: GreyFit, fit: GreyFit) -> dict[str, dict]:
    """What an order candidate (:data:`agents.twin.candidates.ORDER_CANDIDATES`) added, as parameters with units.

    ``pole_pair``: the added pair's ``frequency`` (rad/s) and ``damping`` (the most lightly damped complex
    pair of the grown plant); ``pole``: the added lag's ``time_constant`` (s); ``zero``: the added zero's
    ``time_constant`` (s, ``1/|z|``, negative for a zero in the right half plane). ``{}`` when the grown
    plant has no such root.
    """
    poles = np.roots(fit.plant.den)
    zeros = np.roots(fit.plant.num) if len(fit.plant.num) > 1 else np.array([])
    if name == "pole_pair":
        pairs = poles[poles.imag > 1e-12]
        if not pairs.size:
            return {}
        pair = pairs[np.argmin(-pairs.real / np.abs(pairs))]
        return {"frequency": {"value": float(np.abs(pair)), "unit": "rad/s"},
                "damping": {"value": float(-pair.real / np.abs(pair)), "unit": "1"}}
    if name == "pole":
        old = np.roots(current.plant.den)
        new = [p for p in poles if p.imag == 0.0 and p.real < 0.0 and np.min(np.abs(old - p), initial=np.inf) > 1e-6]
        fast = min(new, key=lambda p: abs(p.real), default=None)
        return {} if fast is None else {"time_constant": {"value": float(-1.0 / fast.real), "unit": "s"}}
    if name == "zero":
        real = zeros[np.abs(zeros.imag) < 1e-12].real
        if not real.size:
            return {}
        z = real[np.argmin(np.abs(real))]
        return {"time_constant": {"value": float(-1.0 / z) if z != 0.0 else float("inf"), "unit": "s"}}
    return {}


#: The unit of a position in the evidence texts, by what ``y`` measures (cogging's period is one).
POSITION_UNITS = {"speed": "(units of y times s: the position of a speed loop, rad for y in rad/s)",
                  "position": "(units of y)"}
#: Damping ratios below this ring visibly: called a resonance.
RESONANT_DAMPING = 0.3


def mode_text(what: str, frequency: float, damping: float) -> str:
    """A second-order mode ``what`` (a noun phrase) in words that match its damping ratio ``damping`` (-) at
    ``frequency`` (rad/s).

    Below :data:`RESONANT_DAMPING` it resonates; up to 1 it is damped; from 1 on its two poles are real and
    nothing oscillates, so it is not called a resonance (a "resonance with damping 2" contradicts itself); below
    the least damping of :data:`agents.twin.modes.RESONANCE_DAMPING` it is a numerical mode (a pole pair at
    220 rad/s with damping 0.0025 fitted a record's noise, not a mode).
    """
    if damping < RESONANCE_DAMPING[0]:
        return (f"{what} at {frequency:.3g} rad/s with damping {damping:.2g}, below what a resonance has "
                f"({RESONANCE_DAMPING[0]:g}): a numerical mode, not a resonance")
    if damping < RESONANT_DAMPING:
        return f"{what} resonating at {frequency:.3g} rad/s ({frequency / (2 * np.pi):.3g} Hz) with damping " \
            f"{damping:.2g}"
    if damping < 1.0:
        return f"{what} at {frequency:.3g} rad/s, damped (damping {damping:.2g})"
    return f"{what} at {frequency:.3g} rad/s, overdamped (damping {damping:.2g} >= 1: no resonance)"


def ringing(data: Batch, current: GreyFit, modes: Sequence[Mode] | None = None) -> str:
    """Where the residual of ``current`` rings, in words: the strongest plant mode it shows (of ``modes``, else
    :func:`agents.twin.modes.plant_modes`, in rad/s and Hz), else its periodogram's peak
    (:func:`agents.twin.guesses.residual_frequencies`)."""
    if modes is None:
        modes = plant_modes(data, current, n_modes=1)
    if modes:
        m = modes[0]
        return (f"residual rings at {m.frequency:.3g} rad/s ({m.hertz:.3g} Hz), a mode of the plant: it follows the "
                f"plant input through it ({m.share:.0f} % of its power)")
    rings = residual_frequencies(data, current, n_peaks=1)
    return f"residual rings at {rings[0]:.3g} rad/s ({rings[0] / (2 * np.pi):.3g} Hz)" if rings else \
        "residual oscillates"


def zero_text(tau: float) -> str:
    """A zero of time constant ``tau`` (s) in words: ``tau < 0`` is a right-half-plane zero, which makes the response
    first move the wrong way (an inverse response, a lag, not a lead); ``tau > 0`` a lead."""
    if tau < 0:
        return (f"the response first moves against the step: an inverse response (a right-half-plane zero of time "
                f"constant {abs(tau):.3g} s)")
    return f"the response leads the model: a zero of time constant {tau:.3g} s"


def _order_evidence(name: str, data: Batch, current: GreyFit, fit: GreyFit, tail: str,
                    modes: Sequence[Mode] | None) -> str:
    change = order_change(name, current, fit)
    if name == "pole_pair" and change:
        w, zeta = change["frequency"]["value"], change["damping"]["value"]
        return f"{ringing(data, current, modes)}: {mode_text('a second mode of the linear part', w, zeta)}" + tail
    if name == "pole" and change:
        return f"the response lags the model: an extra lag of time constant {change['time_constant']['value']:.3g} s" \
            + tail
    if name == "zero" and change:
        return zero_text(change["time_constant"]["value"]) + tail
    return f"a {name.replace('_', ' ')} in the linear part" + tail


def effect_evidence(name: str, data: Batch, current: GreyFit, fit: GreyFit, modes: Sequence[Mode] | None = None) -> str:
    """The residual signature of effect ``name`` in the current model's residual.

    Parameters
    ----------
    name : str
        Catalogue effect.
    data : Batch
    current : GreyFit
        The model diagnosed.
    fit : GreyFit
        ``current`` with ``name`` added.
    modes : sequence of Mode, optional
        The plant's modes in the residual of ``current`` (:func:`agents.twin.modes.plant_modes`; default: scanned
        here where the evidence names them).

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
    if fit.spec.n_linear != current.spec.n_linear:  # an order candidate: the linear part grew
        return _order_evidence(name, data, current, fit, tail, modes)
    if name == "saturation":
        limit = params.get("limit", np.inf)
        over = np.abs(data.u[m]) > limit
        if not over.any() or over.all():  # no samples on one side: no ratio to give (it printed "nanx")
            where = "never exceeds" if not over.any() else "exceeds"
            return (f"the command {where} the fitted limit {limit:.4g} in every sample: the residual cannot show "
                    f"a clipping (r={r:.2f})" + tail)
        ratio = rmse(e[over]) / max(rmse(e[~over]), 1e-300)
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
        return (f"residual periodic in position with period {params.get('period', 0.0):.4g} "
                f"{POSITION_UNITS[current.spec.output]} (r={r:.2f})") + tail
    if name == "compliance":
        mode = mode_text("a flexible coupling", params.get("frequency", 0.0), params.get("damping", 0.0))
        return f"{ringing(data, current, modes)}: {mode} (r={r:.2f})" + tail
    return f"r={r:.2f}" + tail
