"""The base linear model of the workbench's pipeline, and the linear part profiled under given effect blocks.

:func:`linear_fit` is the pipeline's second stage (records, **linear fit**, candidates,
fits, ranking, report): the paper's SRIVC identification (:func:`agents.twin.identify.identify_linear`)
of the records, with the rest levels the records show pinned (:mod:`agents.twin.initial`),
refined by simulation error. :func:`profile` identifies the linear part on the plant input
that given actuator blocks make of the recorded command: the starting values of the
candidates (:mod:`agents.twin.candidates`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from agents.thread_limits import single_thread
from agents.twin.identify import DelaySearch, IdentifyOptions, LinearIdentification, SrivcOptions, identify
from agents.twin.least_squares import Problem, fit_problems, make_problem
from agents.twin.model import GreyFit, ModelSpec, effect_offset
from agents.twin.records import Batch

__all__ = ["PROFILE_EFFECTS", "PROFILE_SAMPLES", "STATEFUL_ACTUATORS", "linear_fit", "profile", "step_start"]


@single_thread()
def linear_fit(data: Batch, spec: ModelSpec | None = None, refine: bool = True) -> GreyFit:
    """Base linear model: SRIVC with a delay of at most one sample, then refined by simulation error.

    Where SRIVC diverges at every delay (data far from any linear model, e.g. a drive that does not
    move below 60 % of its range), the simulation-error fit starts from :func:`step_start` instead.

    Parameters
    ----------
    data : Batch
    spec : ModelSpec, optional
        Orders and output kind (its effects are ignored); default 2 poles, no zero.
    refine : bool, default True
        Polish the SRIVC estimate by least squares on the simulation error (:func:`fit_problems`).
    """
    spec = ModelSpec() if spec is None else ModelSpec(spec.n_poles, spec.n_zeros, spec.n_integrators, spec.output)
    options = IdentifyOptions(n_poles=spec.n_poles, n_zeros=spec.n_zeros, n_integrators=spec.n_integrators,
                              delay_search=DelaySearch(max_delay=data.dt, refine_delay=False))
    try:
        fit = identify(data, options, rest_levels=data.initial.rest_levels)
    except RuntimeError:  # SRIVC diverged at every delay
        problem = step_start(data, spec)
    else:
        theta = np.concatenate([fit.params, [fit.delay]])
        y0, u0 = fit.rest_levels[:, 0], fit.rest_levels[:, 1]
        v_rest = fit.plant(spec.output).discretize(data.dt).equilibrium(y0)[1]
        problem = make_problem(data, spec, theta, y0, v_rest - u0, np.arange(data.n_records))
    fit_problems(data, [problem], max_iter=30 if refine else 0)  # the delay is refined here, in [0, dt]
    return problem.fit(data)


def step_start(data: Batch, spec: ModelSpec) -> Problem:
    """A start for the linear part without SRIVC: ``n`` equal real poles and the records' static gain.

    ``G(s) = K p^(n-k) / (s^k (s + p)^(n-k))`` (``k`` integrators, no zero): ``K`` is the least-squares
    ratio of the output's change (for an integrating output, of its slope) to the input's change from
    each record's first sample, and ``p`` the best of a geometric grid from 1 / T to 1000 / T (``T`` the
    longest record, s) by simulation error, at rest levels from the records (pinned where the data show them).
    """
    y, u, mask = data.y, data.u, data.mask
    rows = np.arange(data.n_records)
    out = np.gradient(y, data.dt, axis=1) if spec.n_integrators else y - y[:, :1]
    du = np.where(mask, u - u[:, :1], 0.0)
    gain = float(np.sum(np.where(mask, out, 0.0) * du) / max(float(np.sum(du**2)), 1e-300)) or 1.0
    span = float(mask.sum(axis=1).max() * data.dt)
    free = spec.n_poles - spec.n_integrators
    y0 = y[:, 0].copy()
    best = None
    for p in np.geomspace(1.0 / span, 1000.0 / span, 13):
        den = np.poly(np.full(free, -p)) if free else np.array([1.0])
        theta = np.concatenate([np.zeros(spec.n_zeros), [gain * p**free], den[1:], [0.0]])
        plant = spec.plant(theta)
        v_rest = plant.discretize(data.dt).equilibrium(y0)[1]
        problem = make_problem(data, spec, theta, y0, v_rest - u[:, 0], rows)
        fit_problems(data, [problem], max_iter=0)
        if best is None or problem.cost < best.cost:
            best = problem
    return best


#: Actuator effects whose starting value is found on the SRIVC profile: for a given effect parameter the
#: plant input ``v = A(u, speed)`` is computed from the records (speed from the measured output) and the
#: linear part identified from ``(v, y)`` by SRIVC; the parameter with the lowest simulation error wins.
PROFILE_EFFECTS = ("saturation", "dead_zone", "coulomb_friction", "backlash", "stiction")


#: Actuator blocks with a state (the play's position, the rotor's angle): stepped sample by sample through a
#: record; the others are maps of the input and the speed, applied to the whole record at once.
STATEFUL_ACTUATORS = frozenset({"backlash", "cogging"})
#: Longest record (samples) that the profile identifies whole; longer records are decimated to it, the
#: input averaged over each hold (:func:`agents.twin.records.decimate_records`): the profile ranks the
#: starting values of a fit, which is then made on every sample.
PROFILE_SAMPLES = 4096


def _srivc_start(spec: ModelSpec, linear: np.ndarray | None, delay: float | None) -> tuple | None:
    """``identify_linear``'s ``start`` from a linear part ``[b_0 .. b_m, a_1 .. a_{n-k}]`` (SRIVC's order is
    ``[a.., b..]``), at the fixed ``delay``; ``None`` without one, with a delay search or an unusable one."""
    if linear is None or delay is None or not np.all(np.isfinite(linear)) or not np.any(linear):
        return None
    return np.concatenate([linear[spec.n_zeros + 1 :], linear[: spec.n_zeros + 1]]), delay


def _records_through(data: Batch, blocks: Sequence, output: str) -> Batch:
    """The records with ``u`` replaced by the plant input of the actuator ``blocks`` (speed from the measured y).

    A ``drift`` of the plant's gain scales each record's input by its factor
    (the same as scaling the numerator), so it is profiled the same way; a ``compliance`` multiplies the plant
    by its factor ``F(s)`` (``F(0) = 1``), so the input is filtered by it (Tustin).
    """
    u = data.u.copy()
    for block in blocks:
        if block.name == "drift" and block.parameter == "gain":
            u = u * np.array([block.factor(k)[0] for k in data.index])[:, None]
        if block.name == "compliance" and np.isfinite(block.frequency):  # G F u = G (F u): the factor on the input
            from scipy.signal import bilinear, lfilter  # scipy.signal takes 0.3 s to import: only where needed

            num, den = bilinear(*block.factor(), fs=1.0 / data.dt)
            u = u[:, :1] + lfilter(num, den, u - u[:, :1], axis=1)  # F(0) = 1: the rest input kept
    speed = data.y if output != "position" else np.gradient(data.y, data.dt, axis=1)
    actuators = [b for b in blocks if b.side == "actuator"]
    for block in actuators:
        block.reset(data.n_records, None, data.dt)
    if any(b.name in STATEFUL_ACTUATORS for b in actuators):
        # heavy dependency: numba (kept off the diagnose start-up path)
        from gbo_envs.physics import kernels

        stepped = kernels.step_actuators(actuators, u, speed, data.dt)  # compiled: the same numbers
        if stepped is not None:
            u = stepped
        else:  # a block the kernels do not know
            for k in range(data.u.shape[1]):
                v = u[:, k]
                for block in actuators:
                    v = block.actuate(v, speed[:, k])
                u[:, k] = v
    else:  # maps of (u, speed): every sample at once, the same values
        for block in actuators:
            u = block.actuate(u, speed)
    return data.with_input(u)


def _rest_through(data: Batch, blocks: Sequence, output: str) -> np.ndarray:
    """``(y0, v0)`` per record: the pinned rest level and the plant input of the rest command through the
    actuator ``blocks`` (at the rest's speed: ``y0``, or 0 for a position); ``NaN`` rows where estimated."""
    rest = data.initial.rest_levels.copy()
    pinned = data.initial.pinned
    if pinned.any():
        v = rest[:, 1].copy()
        speed = rest[:, 0] if output != "position" else np.zeros(data.n_records)
        for block in blocks:
            if block.side == "actuator":
                block.reset(data.n_records, None, data.dt)
                v = block.actuate(np.where(pinned, v, 0.0), np.where(pinned, speed, 0.0))
        rest[pinned, 1] = v[pinned]
    return rest


def profile(data: Batch, spec: ModelSpec, theta: np.ndarray, max_delay: float | None = None,
            max_iter: int = 20, tol: float = 1e-6, delay_step: float | None = None,
            warm: np.ndarray | None = None) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """SRIVC fit of the linear part on the plant input implied by ``spec``'s actuator blocks at ``theta``.

    Parameters
    ----------
    data : Batch
    spec : ModelSpec
    theta : ndarray of shape (n_global,)
        Global parameters; the effect parameters are kept.
    max_delay : float, optional
        Search the delay up to this many s (default: the delay of ``theta`` plus any ``time_delay``, fixed).
    max_iter, tol
        SRIVC iterations and tolerance (:func:`agents.twin.identify.identify_linear`).
    delay_step : float, optional
        Spacing of the delay search in s (default one sample), refined between the best's neighbours.
    warm : ndarray of shape (spec.n_linear,), optional
        A linear part ``[b_0 .. b_m, a_1 .. a_{n-k}]`` to start SRIVC from (at a fixed delay) instead of the
        state-variable-filter fit: a scan over an effect parameter starts each point from its neighbour's fit.

    Returns
    -------
    rmse : float
        Simulation-error RMSE of the SRIVC fit, units of ``y`` (``inf`` when it fails).
    theta_global : ndarray
        ``theta`` with the linear part (and, with ``max_delay``, the delay) replaced by the SRIVC estimate.
    y0, bias : ndarray of shape (n_records,)
        Rest levels and plant-input biases of the SRIVC fit.
    """
    try:
        blocks = spec.blocks(theta)
    except ValueError:
        return np.inf, theta, np.zeros(data.n_records), np.zeros(data.n_records)
    nl = spec.n_linear
    if max_delay is None:
        delay = float(theta[nl] + sum(b.delay for b in blocks if b.name == "time_delay"))
    else:
        delay, max_delay = None, float(max_delay)
    try:  # a plant input the blocks make non-finite is refused by the records (ValueError): no fit there
        records = _records_through(data, blocks, spec.output)
        rest = _rest_through(data, blocks, spec.output)  # pinned records: their rest command through the blocks
        if int(data.lengths.max()) > PROFILE_SAMPLES:  # the mean input over each hold: the same impulse
            records = records.thinned(PROFILE_SAMPLES, mean_input=True)
        options = IdentifyOptions(n_poles=spec.n_poles, n_zeros=spec.n_zeros, n_integrators=spec.n_integrators,
                                  delay_search=DelaySearch(delay=delay, max_delay=max_delay, delay_step=delay_step),
                                  solver=SrivcOptions(max_iter=max_iter, tol=tol, hold="zoh"))
        fit: LinearIdentification = identify(records, options, rest_levels=rest, start=_srivc_start(spec, warm, delay))
    except (ValueError, RuntimeError, np.linalg.LinAlgError):
        return np.inf, theta, np.zeros(data.n_records), np.zeros(data.n_records)
    out = theta.copy()
    out[: nl] = fit.params
    y0, u0 = fit.rest_levels[:, 0], fit.rest_levels[:, 1]
    v_rest = fit.plant(spec.output).discretize(data.dt).equilibrium(y0)[1]
    if max_delay is not None:
        base_delay = min(fit.delay, data.dt) if "time_delay" in spec.effect_names else fit.delay
        out[nl] = base_delay
        if "time_delay" in spec.effect_names:
            out[nl + 1 + effect_offset(spec, "time_delay")] = fit.delay - base_delay
    return float(fit.rmse_abs), out, y0, v_rest - u0
