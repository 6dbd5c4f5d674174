"""Twin workbench: compare a twin with measurements, analyse its residuals, diagnose the missing effect.

* :func:`fit_model`: grey-box fit of a model structure (:mod:`agents.twin.greybox`),
  started from the SRIVC fit of the linear part and data-based effect guesses;
* :func:`compare`: fit % (NRMSE as MATLAB's ``compare``) and RMSE per experiment and overall;
* :func:`residuals`: whiteness, input cross-correlation and where the model fails;
* :func:`diagnose`: every catalogued effect tried as an addition, ranked on held-out experiments;
* :func:`error_ladder`: add the best effect, diagnose again, until nothing helps.

Conventions (generic closed-loop data, nothing of the DC motor assumed): each
record starts at rest; the base linear model has ``n_poles`` poles and an input
delay of at most one sample (the computation delay of a digital loop; a longer
dead time is the ``time_delay`` effect); each record has its own rest level
``y0`` and plant-input bias (SRIVC's rest input in disguise).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from agents.twin.estimator import TwinEstimator
from agents.twin.greybox import FITTED_PARAMETERS, GreyData, GreyFit, ModelSpec, Problem, fit_problems, simulate_sets
from gbo_envs.physics.effects import EFFECT_NAMES, EFFECTS, build_effect

__all__ = ["CompareResult", "Diagnosis", "ResidualAnalysis", "SEPARATING_EXPERIMENTS", "compare", "data_scales",
           "diagnose", "effect_starts", "error_ladder", "fit_model", "heldout_rss", "linear_fit", "noise_floor",
           "fit_twin_effects", "predict_twin_effects", "quantization_step", "residuals", "rmse_twin_effects",
           "separating_experiment"]

Z99 = 2.58  # two-sided 99 % quantile of the standard normal


def _single_thread(fn):
    """Run ``fn`` with one BLAS thread: its many tiny matrix exponentials only contend for threads."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapper


# -- scales and starting values -------------------------------------------------------------------
def data_scales(data: GreyData, output: str = "speed") -> dict[str, float]:
    """Magnitudes read from the data: input, output, speed and time scales (for guesses and bounds)."""
    u = data.u[data.mask]
    y = data.y[data.mask]
    speed = data.y if output != "position" else np.gradient(data.y, data.dt, axis=1)
    return {
        "u_max": float(np.max(np.abs(u))) or 1.0,
        "u_scale": float(np.percentile(np.abs(u), 95)) or float(np.max(np.abs(u))) or 1.0,
        "y_span": float(np.ptp(y)) or 1.0,
        "speed": float(np.max(np.abs(speed[data.mask]))) or 1.0,
        "horizon": float(data.mask.sum(axis=1).min() * data.dt),
    }


def quantization_step(y: np.ndarray, mask: np.ndarray | None = None) -> tuple[float | None, float]:
    """Resolution of a quantized measurement from the histogram of its sample-to-sample changes.

    Returns
    -------
    step : float or None
        The smallest common step of the output's changes, ``None`` if the changes are not multiples of one step.
    share : float
        Fraction of the non-zero changes within 5 % of a whole multiple of ``step``.
    """
    d = np.abs(np.diff(y, axis=-1))
    if mask is not None:
        d = d[mask[..., 1:]]
    d = d[d > 1e-12 * max(float(np.max(np.abs(y))), 1.0)]
    if d.size < 20:
        return None, 0.0
    low = np.percentile(d, 5)
    near = d[(d > 0.5 * low) & (d < 1.5 * low)]
    q = float(np.median(near)) if near.size else float(low)
    ratio = d / q
    share = float(np.mean(np.abs(ratio - np.round(ratio)) < 0.05))
    return (q if share > 0.8 else None), share


def noise_floor(data: GreyData) -> float | None:
    """Measurement-noise floor of ``y`` in output units, from its second differences.

    White noise ``e`` of std ``sigma`` gives ``var(Delta^2 e) = 6 sigma^2``, while the
    smooth response of a sampled plant contributes little to ``Delta^2 y``; the
    median of ``(Delta^2 y)^2`` (robust to the few kinks at steps and limits)
    divided by ``6 * 0.4549`` (median of chi-square with 1 degree of freedom) is
    ``sigma^2``. A quantized output with no visible noise (more than half of the
    second differences exactly zero) gives the quantization floor ``q / sqrt(12)``
    instead; ``None`` when neither can be estimated.
    """
    d2 = np.diff(data.y, n=2, axis=1)[data.mask[:, 2:]]
    if d2.size < 10:
        return None
    scale = max(float(np.max(np.abs(data.y[data.mask]))), 1.0)
    if np.mean(np.abs(d2) <= 1e-12 * scale) < 0.5:
        return float(np.sqrt(np.median(d2**2) / (6.0 * 0.4549)))
    q = quantization_step(data.y, data.mask)[0]
    return None if q is None else float(q / np.sqrt(12.0))


def effect_starts(name: str, data: GreyData, base: GreyFit, with_starts: bool = True) -> tuple[
        list[np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """Starting values, bounds and scales of the fitted parameters of effect ``name``, from the data.

    ``with_starts=False`` skips the (for quantization and drift, costlier) starting values.

    Returns
    -------
    starts : list of ndarray of shape (n_effect_params,)
    lower, upper, scale : ndarray of shape (n_effect_params,)
    """
    sc = data_scales(data, base.spec.output)
    u_max, us, speed, horizon, dt = sc["u_max"], sc["u_scale"], sc["speed"], sc["horizon"], data.dt
    rest = float(np.max(np.abs(_rest_command(base))))
    fractions = np.array([0.005, 0.015, 0.05, 0.15, 0.4])
    if name == "time_delay":
        top = max(min(0.25 * horizon, 60 * dt), 2 * dt)
        grid = np.unique(np.concatenate([np.arange(1, 6) * dt, np.geomspace(dt, top, 24)]))
        return [np.array([g]) for g in grid], np.array([0.0]), np.array([top]), np.array([dt])
    if name == "saturation":
        q = np.percentile(np.abs(data.u[data.mask]), [50, 70, 80, 90, 95, 98, 99, 99.5, 99.9])
        grid = np.unique(np.concatenate([q, u_max * np.array([0.6, 0.7, 0.8, 0.9, 0.95, 0.99])]))
        lo = min(rest * 1.0001, 0.5 * u_max)  # the base model's rest input is only a rough guide
        grid = grid[(grid > lo) & (grid < u_max)]
        if grid.size == 0:
            grid = np.array([0.5 * (lo + u_max)]) if u_max > lo else np.array([1.001 * lo])
        return [np.array([g]) for g in grid], np.array([lo]), np.array([1.05 * u_max]), np.array([us])
    if name in ("dead_zone", "backlash"):
        return [np.array([f * us]) for f in fractions], np.array([0.0]), np.array([2 * us]), np.array([us])
    if name == "coulomb_friction":
        return [np.array([f * us]) for f in fractions[:-1]], np.array([0.0]), np.array([us]), np.array([us])
    if name == "viscous_friction":
        c = us / speed
        return [np.array([f * c]) for f in (0.01, 0.05, 0.2)], np.array([0.0]), np.array([2 * c]), np.array([c])
    if name == "stiction":
        starts = [np.array([f * us, g * speed]) for f in (0.01, 0.05, 0.2) for g in (0.002, 0.02)]
        return starts, np.array([0.0, 0.0]), np.array([us, 0.2 * speed]), np.array([us, 0.05 * speed])
    if name == "quantization":
        q, _ = quantization_step(data.y, data.mask)
        grid = _quantization_scan(data, base, sc["y_span"]) if with_starts else []
        if q is not None:
            grid = [q] + grid
        grid = grid or [0.01 * sc["y_span"]]
        return [np.array([g]) for g in grid], np.array([0.0]), np.array([0.2 * sc["y_span"]]), \
            np.array([sc["y_span"] * 0.01])
    if name == "drift":
        k = max(int(np.ptp(data.index)), 1)
        slope = _gain_trend(data, base) if with_starts else 0.0
        total = np.array([0.003, 0.01, 0.03, 0.1, 0.3])  # relative change over the session
        grid = sorted({float(np.clip(slope, -0.9 / k, 1.0 / k)), *(total / k), *(-total / k)})
        return [np.array([g]) for g in grid], np.array([-0.9 / k]), np.array([1.0 / k]), np.array([0.01 / k])
    if name == "offset":
        return [np.array([f * us]) for f in (-0.05, 0.05)], np.array([-us]), np.array([us]), np.array([us])
    if name == "cogging":
        travel = float(np.median(np.sum(np.abs(data.y if base.spec.output != "position" else np.gradient(
            data.y, dt, axis=1)) * data.mask, axis=1) * dt))
        periods = np.geomspace(max(speed * 4 * dt, travel / 2000), max(travel / 4, speed * 8 * dt), 12)
        starts = [np.array([0.02 * us, p, ph]) for p in periods[::2] for ph in (0.0, np.pi / 2)]
        return starts, np.array([0.0, periods[0] / 2, -2 * np.pi]), np.array([us, 2 * periods[-1], 2 * np.pi]), \
            np.array([us, periods[0], 1.0])
    raise ValueError(f"unknown effect {name!r}; the catalogue is {EFFECT_NAMES}")


def _quantization_scan(data: GreyData, base: GreyFit, span: float, n_best: int = 3,
                       y_true: np.ndarray | None = None) -> list[float]:
    """Quantization steps ``q`` that make ``Q_q(y_true)`` of the base model match ``y``, best first.

    The error of a quantized measurement is a sawtooth of period ``q`` in the
    true output: the periodogram ``|sum_t e(t) exp(-2 pi i y_sim(t) / q)|`` of
    the base model's residual against its output peaks at ``q`` (steps between
    ``1e-3`` and ``0.1`` of the output span). Each peak is then refined on a
    fine grid (+-5 %, 401 points) of the rounding error itself, which is
    sharp because the levels are whole multiples of ``q``.
    """
    rng = np.random.default_rng(0)
    idx = np.flatnonzero(data.mask.ravel())
    idx = rng.choice(idx, size=min(idx.size, 2000), replace=False)
    ys = (base.y_sim if y_true is None else y_true).ravel()[idx]
    y = data.y.ravel()[idx]
    e = y - ys
    freqs = np.arange(10.0 / span, 1000.0 / span, 0.4 / span)
    power = np.empty(freqs.size)
    for start in range(0, freqs.size, 500):
        f = freqs[start : start + 500, None]
        power[start : start + 500] = np.abs(np.exp(-2j * np.pi * f * ys[None, :]) @ e)
    peaks = [i for i in np.argsort(power)[::-1][:200]]
    coarse: list[float] = []
    for i in peaks:
        q = 1.0 / freqs[i]
        if all(abs(q / c - 1.0) > 0.05 for c in coarse):
            coarse.append(q)
        if len(coarse) == n_best:
            break
    found = []
    for q0 in coarse:
        steps = q0 * np.linspace(0.95, 1.05, 401)
        cost = np.mean((y[None, :] - steps[:, None] * np.round(ys[None, :] / steps[:, None])) ** 2, axis=1)
        i = int(np.argmin(cost))
        found.append((float(cost[i]), float(steps[i])))
    return [q for _, q in sorted(found)]


def _rest_command(fit: GreyFit) -> np.ndarray:
    """Plant input that holds each record at rest (before the actuator blocks), shape (n_records,)."""
    d = fit.plant.discretize(1.0)
    return d.equilibrium(fit.y0)[1] - fit.bias


def _gain_trend(data: GreyData, base: GreyFit) -> float:
    """Relative change per experiment of a per-record gain fitted to the base model's response."""
    if data.n_records < 2:
        return 0.0
    dev_sim = base.y_sim - base.y0[:, None]
    dev = data.y - base.y0[:, None]
    num = np.sum(np.where(data.mask, dev * dev_sim, 0.0), axis=1)
    den = np.sum(np.where(data.mask, dev_sim**2, 0.0), axis=1)
    gains = num / np.maximum(den, 1e-300)
    if np.ptp(data.index) == 0:
        return 0.0
    slope = np.polyfit(data.index, gains, 1)[0]
    return float(slope / max(np.mean(gains), 1e-12))


# -- fitting --------------------------------------------------------------------------------------
@_single_thread
def linear_fit(data: GreyData, spec: ModelSpec | None = None, refine: bool = True) -> GreyFit:
    """Base linear model: SRIVC with a delay of at most one sample, then refined by simulation error.

    Parameters
    ----------
    data : GreyData
    spec : ModelSpec, optional
        Orders and output kind (its effects are ignored); default 2 poles, no zero.
    refine : bool, default True
        Polish the SRIVC estimate by Levenberg-Marquardt on the simulation error.
    """
    spec = ModelSpec() if spec is None else ModelSpec(spec.n_poles, spec.n_zeros, spec.n_integrators, spec.output)
    records = [{"t": data.t[k][data.mask[k]], "r": data.r[k][data.mask[k]], "u": data.u[k][data.mask[k]],
                "y": data.y[k][data.mask[k]]} for k in range(data.n_records)]
    twin = TwinEstimator(n_poles=spec.n_poles, n_zeros=spec.n_zeros, n_integrators=spec.n_integrators,
                         max_delay=data.dt, refine_delay=False, output=spec.output).fit(records)
    theta = np.concatenate([twin.num_, twin.den_[1 : spec.n_poles - spec.n_integrators + 1], [twin.delay_]])
    y0, u0 = twin.rest_levels_[:, 0], twin.rest_levels_[:, 1]
    v_rest = twin.plant_.discretize(data.dt).equilibrium(y0)[1]
    problem = _problem(data, spec, theta, y0, v_rest - u0, np.arange(data.n_records))
    fit_problems(data, [problem], max_iter=30 if refine else 0)  # the delay is refined here, in [0, dt]
    return GreyFit.from_problem(data, problem)


def _problem(data: GreyData, spec: ModelSpec, theta_global: np.ndarray, y0: np.ndarray, bias: np.ndarray,
             rows: np.ndarray, lower=None, upper=None, scale=None, free_global: bool = True, tag=None) -> Problem:
    """A :class:`Problem` with default bounds for the linear part and the nuisance parameters."""
    g = theta_global.size
    nl = spec.n_linear
    lin = np.abs(theta_global[:nl])
    dt = data.dt
    lo = np.concatenate([np.full(nl, -np.inf), [0.0]])
    hi = np.concatenate([np.full(nl, np.inf), [dt]])
    sc = np.concatenate([np.maximum(lin, 1e-6 * max(lin.max(), 1e-12)), [dt]])
    extra = g - nl - 1
    lo = np.concatenate([lo, lower if lower is not None else np.full(extra, -np.inf)])
    hi = np.concatenate([hi, upper if upper is not None else np.full(extra, np.inf)])
    sc = np.concatenate([sc, scale if scale is not None else np.ones(extra)])
    k = rows.size
    ys = max(float(np.ptp(data.y[rows][data.mask[rows]])), 1e-9)
    us = max(float(np.max(np.abs(data.u[rows]))), 1e-9)
    lower = np.concatenate([lo, np.full(2 * k, -np.inf)])
    upper = np.concatenate([hi, np.full(2 * k, np.inf)])
    scale = np.concatenate([sc, np.full(k, ys), np.full(k, us)])
    free = np.concatenate([spec.smooth_mask() & free_global, np.ones(2 * k, dtype=bool)])
    if "time_delay" in spec.effect_names:
        free[nl] = False  # the extra delay takes the delay's place
    theta = np.clip(np.concatenate([theta_global, y0, bias]), lower, upper)
    return Problem(spec=spec, rows=np.asarray(rows, dtype=int), theta=theta, lower=lower, upper=upper, scale=scale,
                   free=free, tag=tag)


def _forward_bias(data: GreyData, fit: GreyFit, spec: ModelSpec, theta: np.ndarray) -> np.ndarray:
    """Bias that keeps each record's rest input after adding effect blocks (their map at the rest command)."""
    u_rest = _rest_command(fit)
    v = u_rest.copy()
    speed = fit.y0 if spec.output != "position" else np.zeros_like(fit.y0)
    try:
        blocks = spec.blocks(theta)
    except ValueError:
        return fit.bias.copy()
    v_old = u_rest.copy()
    for block in fit.blocks:
        if block.side == "actuator":
            block.reset(v_old.size, None, data.dt)
            v_old = block.actuate(v_old, speed)
    for block in blocks:
        if block.side == "actuator":
            block.reset(v.size, None, data.dt)
            v = block.actuate(v, speed)
    return fit.bias + (v_old - v)


#: Actuator effects whose starting value is found on the SRIVC profile: for a given effect parameter the
#: plant input ``v = A(u, speed)`` is computed from the records (speed from the measured output) and the
#: linear part identified from ``(v, y)`` by SRIVC; the parameter with the lowest simulation error wins.
PROFILE_EFFECTS = ("saturation", "dead_zone", "coulomb_friction", "backlash", "stiction")


def _records_through(data: GreyData, blocks: Sequence, output: str) -> list[dict]:
    """Records whose ``u`` is replaced by the plant input of the actuator ``blocks`` (speed from the measured y).

    A ``drift`` of the plant's gain scales each record's input by its factor
    (the same as scaling the numerator), so it is profiled the same way.
    """
    u = data.u.copy()
    for block in blocks:
        if block.name == "drift" and block.parameter == "gain":
            u = u * np.array([block.factor(k)[0] for k in data.index])[:, None]
    speed = data.y if output != "position" else np.gradient(data.y, data.dt, axis=1)
    actuators = [b for b in blocks if b.side == "actuator"]
    if actuators:
        for block in actuators:
            block.reset(data.n_records, None, data.dt)
        for k in range(data.u.shape[1]):
            v = u[:, k]
            for block in actuators:
                v = block.actuate(v, speed[:, k])
            u[:, k] = v
    return [{"t": data.t[k][data.mask[k]], "r": data.r[k][data.mask[k]], "u": u[k][data.mask[k]],
             "y": data.y[k][data.mask[k]]} for k in range(data.n_records)]


def _profile(data: GreyData, spec: ModelSpec, theta: np.ndarray, estimator: TwinEstimator,
             max_delay: float | None = None) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """SRIVC fit of the linear part on the plant input implied by ``spec``'s actuator blocks at ``theta``.

    Returns ``(rmse, theta_global, y0, bias)`` with the linear part (and, with
    ``max_delay``, the delay) replaced by the SRIVC estimate.
    """
    try:
        blocks = spec.blocks(theta)
    except ValueError:
        return np.inf, theta, np.zeros(data.n_records), np.zeros(data.n_records)
    nl = spec.n_linear
    if max_delay is None:
        total = theta[nl] + sum(b.delay for b in blocks if b.name == "time_delay")
        estimator.set_params(delay=float(total), max_delay=None)
    else:
        estimator.set_params(delay=None, max_delay=float(max_delay))
    try:
        twin = estimator.fit(_records_through(data, blocks, spec.output))
    except (ValueError, RuntimeError, np.linalg.LinAlgError):
        return np.inf, theta, np.zeros(data.n_records), np.zeros(data.n_records)
    out = theta.copy()
    out[: nl] = np.concatenate([twin.num_, twin.den_[1 : spec.n_poles - spec.n_integrators + 1]])
    y0, u0 = twin.rest_levels_[:, 0], twin.rest_levels_[:, 1]
    v_rest = twin.plant_.discretize(data.dt).equilibrium(y0)[1]
    if max_delay is not None:
        base_delay = min(float(twin.delay_), data.dt) if "time_delay" in spec.effect_names else float(twin.delay_)
        out[nl] = base_delay
        if "time_delay" in spec.effect_names:
            out[nl + 1 + _effect_offset(spec, "time_delay")] = float(twin.delay_) - base_delay
    return float(twin.rmse_abs_), out, y0, v_rest - u0


def _effect_offset(spec: ModelSpec, name: str) -> int:
    pos = 0
    for effect, _ in spec.effects:
        if effect == name:
            return pos
        pos += len(FITTED_PARAMETERS[effect])
    raise KeyError(name)


def _profile_problems(data, current, spec, name, starts, lo, hi, sc, lower, upper, scale, tag) -> list[Problem]:
    """Starting point on the SRIVC profile of the new effect's parameter(s), then one bounded problem."""
    from scipy.optimize import minimize_scalar

    estimator = TwinEstimator(n_poles=spec.n_poles, n_zeros=spec.n_zeros, n_integrators=spec.n_integrators,
                              output=spec.output, max_iter=10, tol=1e-5)
    rows = np.arange(data.n_records)
    g0 = current.theta.size
    if name == "time_delay":
        theta = np.concatenate([current.theta, [0.0]])
        res = _profile(data, spec, theta, estimator, max_delay=float(hi[0]))
    elif not starts:
        return []
    else:
        results = []
        for start in starts:
            theta = np.concatenate([current.theta, np.clip(start, lo, hi)])
            results.append((theta, _profile(data, spec, theta, estimator)))
        best = int(np.argmin([r[1][0] for r in results]))
        res = results[best][1]
        if lo.size == 1 and len(starts) > 1 and np.isfinite(res[0]):
            values = [float(r[0][g0]) for r in results]
            a = values[max(best - 1, 0)]
            b = values[min(best + 1, len(values) - 1)]
            if b > a:
                cache = {}

                def cost(x: float) -> float:
                    th = results[best][0].copy()
                    th[g0] = x
                    cache[x] = _profile(data, spec, th, estimator)
                    return cache[x][0]

                minimize_scalar(cost, bounds=(a, b), method="bounded", options={"maxiter": 6,
                                                                                 "xatol": 1e-3 * (b - a)})
                x = min(cache, key=lambda key: cache[key][0])
                if cache[x][0] < res[0]:
                    res = cache[x]
    _, theta, y0, bias = res
    if not np.isfinite(res[0]):
        return []
    return [_problem(data, spec, theta, y0, bias, rows, lower, upper, scale, tag=tag)]


def candidate_problems(data: GreyData, current: GreyFit, name: str, options: Mapping | None = None,
                       n_keep: int = 2, tag=None) -> list[Problem]:
    """Problems for ``current`` plus effect ``name``: its data-based starts, screened, the best ``n_keep`` kept.

    Actuator effects of :data:`PROFILE_EFFECTS` and ``time_delay`` start from
    the SRIVC profile (one problem); the others from the starts of
    :func:`effect_starts` screened by their simulation error.
    """
    spec = current.spec.with_effect(name, options)
    starts, lo, hi, sc = effect_starts(name, data, current)
    rows = np.arange(data.n_records)
    n_old = current.theta.size - current.spec.n_linear - 1
    lower, upper, scale = _current_effect_bounds(
        data, current, np.concatenate([np.full(n_old, -np.inf), lo]), np.concatenate([np.full(n_old, np.inf), hi]),
        np.concatenate([np.ones(n_old), sc]))
    if name in PROFILE_EFFECTS or name == "time_delay" or (name == "drift" and dict(options or {}).get(
            "parameter", "gain") == "gain" and data.n_records > 1):
        problems = _profile_problems(data, current, spec, name, starts, lo, hi, sc, lower, upper, scale, tag)
        if problems:
            return problems
    thetas = []
    for start in starts:
        theta = np.concatenate([current.theta, np.clip(start, lo, hi)])
        if name == "time_delay":
            theta[spec.n_linear] = current.theta[current.spec.n_linear]
        thetas.append(theta)
    biases = [_forward_bias(data, current, spec, th) for th in thetas]
    sims = simulate_sets(data, [(spec, np.concatenate([th, current.y0, b]), rows) for th, b in zip(thetas, biases)])
    costs = []
    for y in sims:
        err = np.where(data.mask, y - data.y, 0.0)
        costs.append(float(np.sum(err**2)) if np.all(np.isfinite(err)) else np.inf)
    order = np.argsort(costs)[:n_keep]
    problems = []
    for i in order:
        problems.append(_problem(data, spec, thetas[i], current.y0.copy(), biases[i], rows, lower, upper, scale,
                                 tag=tag))
    return problems


def _current_effect_bounds(data, current: GreyFit, lower, upper, scale):
    """Bounds of the effects already in ``current`` (their data-based ranges)."""
    pos = 0
    for name, _ in current.spec.effects:
        _, lo, hi, sc = effect_starts(name, data, current, with_starts=False)
        n = lo.size
        lower[pos : pos + n], upper[pos : pos + n], scale[pos : pos + n] = lo, hi, sc
        pos += n
    return lower, upper, scale


def refine_grid_parameters(data: GreyData, fit: GreyFit) -> GreyFit:
    """Refine the quantization step of a fit on a fine grid around its value (other parameters fixed)."""
    if "quantization" not in fit.spec.effect_names:
        return fit
    rows = np.arange(data.n_records)
    theta = np.concatenate([fit.theta, fit.y0, fit.bias])
    y_true = simulate_sets(data, [(fit.spec, theta, rows)], true_output=True)[0]
    j = fit.spec.n_linear + 1 + _effect_offset(fit.spec, "quantization")
    span = float(np.ptp(data.y[data.mask]))
    steps = _quantization_scan(data, fit, span, n_best=1, y_true=y_true)
    best = fit
    for q in steps + [fit.theta[j]]:
        th = fit.theta.copy()
        th[j] = q
        problem = _problem(data, fit.spec, th, fit.y0, fit.bias, rows, free_global=False)
        fit_problems(data, [problem], max_iter=0)
        cand = GreyFit.from_problem(data, problem)
        if cand.rmse < best.rmse:
            best = cand
    return best


@_single_thread
def fit_model(data: GreyData, effects: Sequence | Mapping | None = None, spec: ModelSpec | None = None,
              base: GreyFit | None = None, max_iter: int = 25) -> GreyFit:
    """Grey-box fit of the linear model plus ``effects`` (names, or ``{name: {parameter: value}}`` guesses).

    Effects are added one at a time to the fitted model (each from its
    data-based starts, or from the given values), then all parameters are
    refitted together.
    """
    fit = base if base is not None else linear_fit(data, spec)
    for name, given in _effect_items(effects):
        options = {k: v for k, v in given.items() if k not in dict(FITTED_PARAMETERS[name])}
        problems = candidate_problems(data, fit, name, options)
        if any(k in dict(FITTED_PARAMETERS[name]) for k in given):
            p = problems[0]
            pos = fit.theta.size
            for j, (pname, _) in enumerate(FITTED_PARAMETERS[name]):
                if pname in given:
                    p.theta[pos + j] = float(np.clip(given[pname], p.lower[pos + j], p.upper[pos + j]))
        fit_problems(data, problems, max_iter=max_iter)
        best = min(problems, key=lambda p: p.cost)
        fit = refine_grid_parameters(data, GreyFit.from_problem(data, best))
    return fit


def _effect_items(effects) -> list[tuple[str, dict]]:
    if effects is None:
        return []
    if isinstance(effects, str):
        effects = [e for e in effects.split(",") if e.strip()]
    items = effects.items() if isinstance(effects, Mapping) else [
        (e, {}) if isinstance(e, str) else (e[0], dict(e[1] or {})) for e in effects]
    out = []
    for name, given in items:
        name = name.strip()
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; the catalogue is {EFFECT_NAMES}")
        out.append((name, dict(given or {})))
    return out


# -- compare --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class CompareResult:
    """Measured against simulated output.

    Attributes
    ----------
    experiments : ndarray of int, shape (n_records,)
    fit_percent, rmse : ndarray of shape (n_records,)
        ``100 (1 - ||y - y_sim|| / ||y - mean(y)||)`` (MATLAB ``compare``) and RMSE in units of ``y``.
    fit_percent_all, rmse_all : float
        Over all samples of all records (the mean removed per record).
    model : str
    """

    experiments: np.ndarray
    fit_percent: np.ndarray
    rmse: np.ndarray
    fit_percent_all: float
    rmse_all: float
    model: str

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return {"model": self.model, "fit_percent": self.fit_percent_all, "rmse": self.rmse_all,
                "experiments": [{"experiment": int(e), "fit_percent": float(f), "rmse": float(r)}
                                for e, f, r in zip(self.experiments, self.fit_percent, self.rmse)]}


def compare(data: GreyData, fit: GreyFit, experiments: Sequence[int] | None = None) -> CompareResult:
    """Fit % and RMSE of ``fit`` on ``data`` per experiment and overall."""
    err = np.where(data.mask, data.y - fit.y_sim, 0.0)
    mean = np.sum(np.where(data.mask, data.y, 0.0), axis=1) / data.mask.sum(axis=1)
    dev = np.where(data.mask, data.y - mean[:, None], 0.0)
    norm_e = np.sqrt(np.sum(err**2, axis=1))
    norm_d = np.sqrt(np.sum(dev**2, axis=1))
    fitp = 100.0 * (1.0 - norm_e / np.where(norm_d > 0, norm_d, np.nan))
    rmse = norm_e / np.sqrt(data.mask.sum(axis=1))
    all_fit = 100.0 * (1.0 - np.sqrt(np.sum(err**2)) / max(np.sqrt(np.sum(dev**2)), 1e-300))
    ids = np.asarray(experiments if experiments is not None else data.index, dtype=int)
    return CompareResult(ids, fitp, rmse, float(all_fit), float(np.sqrt(np.sum(err**2) / data.n_samples)),
                         fit.spec.label)


# -- residual analysis ----------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ResidualAnalysis:
    """Where and how a model fails.

    Attributes
    ----------
    lags : ndarray of int, shape (n_lags,)
        ``0..L`` for the autocorrelation.
    acf : ndarray of shape (n_lags,)
        Normalised residual autocorrelation, pooled over records.
    ccf_lags : ndarray of int, shape (2 L + 1,)
    ccf : ndarray of shape (2 L + 1,)
        Normalised residual-input cross-correlation ``corr(e(t), u(t - lag))``.
    band : float
        99 % band ``2.58 / sqrt(N)`` of both under whiteness and independence.
    white, independent : bool
        Whether the acf (lags >= 1) and ccf stay inside the band (a 1 % excess allowed).
    bins : dict
        ``{"time" | "experiment" | "input" | "output" | "velocity_sign": {"centers", "rms", "mean", "count"}}``.
    worst : list of dict
        Worst segments: experiment, ``t_start``, ``t_end`` (s), rms and mean residual.
    """

    lags: np.ndarray
    acf: np.ndarray
    ccf_lags: np.ndarray
    ccf: np.ndarray
    band: float
    white: bool
    independent: bool
    bins: dict
    worst: list

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return {"band": self.band, "white": self.white, "independent": self.independent,
                "acf": self.acf.tolist(), "ccf_lags": self.ccf_lags.tolist(), "ccf": self.ccf.tolist(),
                "bins": {k: {kk: np.asarray(vv).tolist() for kk, vv in v.items()} for k, v in self.bins.items()},
                "worst": self.worst}


def residuals(data: GreyData, fit: GreyFit, max_lag: int | None = None, n_bins: int = 10,
              n_worst: int = 5) -> ResidualAnalysis:
    """Residual whiteness, residual-input correlation and the residual's distribution over the operating range."""
    e = np.where(data.mask, data.y - fit.y_sim, 0.0)
    n_min = int(data.mask.sum(axis=1).min())
    lag_max = int(max_lag if max_lag is not None else min(50, max(n_min // 4, 1)))
    means = np.sum(e, axis=1) / data.mask.sum(axis=1)
    ec = np.where(data.mask, e - means[:, None], 0.0)
    u_mean = np.sum(np.where(data.mask, data.u, 0.0), axis=1) / data.mask.sum(axis=1)
    uc = np.where(data.mask, data.u - u_mean[:, None], 0.0)
    n_total = data.n_samples
    ee, uu = float(np.sum(ec**2)), float(np.sum(uc**2))
    acf = np.array([np.sum(ec[:, lag:] * ec[:, : ec.shape[1] - lag]) for lag in range(lag_max + 1)])
    acf = acf / max(ee, 1e-300)
    lags = np.arange(-lag_max, lag_max + 1)
    ccf = np.array([np.sum(ec[:, lag:] * uc[:, : uc.shape[1] - lag]) if lag >= 0 else
                    np.sum(ec[:, : ec.shape[1] + lag] * uc[:, -lag:]) for lag in lags])
    ccf = ccf / max(np.sqrt(ee * uu), 1e-300)
    band = Z99 / np.sqrt(n_total)
    white = bool(np.mean(np.abs(acf[1:]) > band) <= 0.01)
    independent = bool(np.mean(np.abs(ccf) > band) <= 0.01)
    m = data.mask
    speed = data.y if fit.spec.output != "position" else np.gradient(data.y, data.dt, axis=1)
    velocity = np.gradient(speed, data.dt, axis=1) if fit.spec.output != "position" else speed
    if fit.spec.output != "position":  # a speed loop: the sign of the speed itself
        velocity = speed
    t_rel = data.t - data.t[:, :1]
    bins = {
        "time": _binned(t_rel[m], e[m], n_bins),
        "experiment": _grouped(np.broadcast_to(data.index[:, None], e.shape)[m], e[m]),
        "input": _binned(data.u[m], e[m], n_bins, quantiles=True),
        "output": _binned(data.y[m], e[m], n_bins, quantiles=True),
        "velocity_sign": _grouped(np.sign(np.round(velocity[m], 12)), e[m]),
    }
    return ResidualAnalysis(np.arange(lag_max + 1), acf, lags, ccf, float(band), white, independent, bins,
                            _worst_segments(data, e, n_worst))


def _binned(x: np.ndarray, e: np.ndarray, n_bins: int, quantiles: bool = False) -> dict:
    edges = np.unique(np.percentile(x, np.linspace(0, 100, n_bins + 1))) if quantiles else \
        np.linspace(x.min(), x.max(), n_bins + 1)
    if edges.size < 2:
        edges = np.array([x.min(), x.max() + 1e-12])
    which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
    centers = 0.5 * (edges[:-1] + edges[1:])
    count = np.bincount(which, minlength=centers.size)
    total = np.bincount(which, weights=e, minlength=centers.size)
    sq = np.bincount(which, weights=e**2, minlength=centers.size)
    with np.errstate(invalid="ignore", divide="ignore"):
        return {"centers": centers, "rms": np.sqrt(sq / count), "mean": total / count, "count": count}


def _grouped(x: np.ndarray, e: np.ndarray) -> dict:
    keys, which = np.unique(x, return_inverse=True)
    count = np.bincount(which)
    return {"centers": keys.astype(float), "rms": np.sqrt(np.bincount(which, weights=e**2) / count),
            "mean": np.bincount(which, weights=e) / count, "count": count}


def _worst_segments(data: GreyData, e: np.ndarray, n_worst: int) -> list[dict]:
    n_min = int(data.mask.sum(axis=1).min())
    width = max(5, n_min // 20)
    kernel = np.ones(width) / width
    found = []
    for k in range(data.n_records):
        n = int(data.mask[k].sum())
        power = np.convolve(e[k, :n] ** 2, kernel, mode="valid")
        taken = np.zeros(power.size, dtype=bool)
        for _ in range(n_worst):
            cand = np.where(taken, -np.inf, power)
            i = int(np.argmax(cand))
            if not np.isfinite(cand[i]):
                break
            taken[max(0, i - width + 1) : i + width] = True
            found.append((float(power[i]), k, i))
    found.sort(reverse=True)
    out = []
    for power, k, i in found[:n_worst]:
        seg = e[k, i : i + width]
        out.append({"experiment": int(data.index[k]), "t_start": float(data.t[k, i]),
                    "t_end": float(data.t[k, i + width - 1]), "rms": float(np.sqrt(power)),
                    "mean": float(np.mean(seg))})
    return out


# -- diagnosis ------------------------------------------------------------------------------------
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


def separating_experiment(a: str, b: str) -> str:
    """Which experiment would tell effects ``a`` and ``b`` apart."""
    key = frozenset({a, b})
    if key in SEPARATING_EXPERIMENTS:
        return SEPARATING_EXPERIMENTS[key]
    for name, text in _ONE_SIDED.items():
        if name in key:
            return text.format(other=(key - {name}).pop())
    return (f"an experiment over a wider range of inputs, speeds and directions (other gains, step sizes and "
            f"signs) separates {a} from {b}")


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """Ranking of the catalogued effects as additions to a model; see :func:`diagnose`.

    ``fits`` maps each effect to the fitted model with it added; ``current`` is the model diagnosed.
    """

    current: GreyFit
    fits: dict
    candidates: list
    best: str | None
    noise_rmse: float | None
    fit_percent: float
    heldout_rmse: float
    validation: str
    indistinguishable: list
    suggested_experiment: str | None

    def to_dict(self) -> dict:
        """The ``diagnose --json`` object."""
        return {"model": self.current.spec.label, "rmse": float(self.current.rmse),
                "fit_percent": float(self.fit_percent), "noise_rmse": self.noise_rmse, "best": self.best,
                "candidates": self.candidates, "heldout_rmse": float(self.heldout_rmse),
                "validation": self.validation, "indistinguishable": self.indistinguishable,
                "suggested_experiment": self.suggested_experiment,
                "current_params": _jsonable(self.current.effect_params)}


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _variants(name: str, spec: ModelSpec) -> list[dict]:
    if name == "drift":
        dens = [f"den{i}" for i in range(1, spec.n_poles - spec.n_integrators + 1)]
        return [{"parameter": p} for p in ["gain", *dens]]
    return [{}]


def _folds(data: GreyData, n_folds: int) -> list[np.ndarray]:
    order = np.argsort(data.index, kind="stable")
    k = min(n_folds, data.n_records)
    return [order[i::k] for i in range(k)]


def _refit_problem(data: GreyData, fit: GreyFit, rows: np.ndarray, free_global: bool, theta=None, y0=None,
                   bias=None, tag=None) -> Problem:
    rows = np.asarray(rows, dtype=int)
    n_eff = fit.theta.size - fit.spec.n_linear - 1
    lower, upper, scale = _current_effect_bounds(data, fit, np.full(n_eff, -np.inf), np.full(n_eff, np.inf),
                                                 np.ones(n_eff))
    return _problem(data, fit.spec, fit.theta if theta is None else theta,
                    fit.y0[rows] if y0 is None else y0, fit.bias[rows] if bias is None else bias, rows,
                    lower, upper, scale, free_global=free_global, tag=tag)


def heldout_rss(data: GreyData, fits: Sequence[GreyFit], n_folds: int = 4, max_iter: int = 6) -> np.ndarray:
    """Held-out residual sum of squares of each model, cross-validated over experiments.

    Each fold's experiments are left out, every model is refitted on the others
    (from its full-data fit), and its global parameters are then applied to the
    left-out experiments with only their rest levels and biases fitted.

    Returns
    -------
    ndarray of shape (n_models,)
    """
    folds = _folds(data, n_folds)
    train = []
    for m, fit in enumerate(fits):
        for f, test in enumerate(folds):
            rows = np.setdiff1d(np.arange(data.n_records), test)
            train.append(_refit_problem(data, fit, rows, True, tag=(m, f)))
    fit_problems(data, train, max_iter=max_iter)
    tests = []
    for p in train:
        m, f = p.tag
        test = folds[f]
        fit = fits[m]
        tests.append(_refit_problem(data, fit, test, False, theta=p.theta[: p.n_global], tag=(m, f)))
    fit_problems(data, tests, max_iter=4)
    rss = np.zeros(len(fits))
    for p in tests:
        rss[p.tag[0]] += p.cost
    return rss


def _excitation(data: GreyData, output: str) -> dict[str, str]:
    """Effects the data cannot show, with the reason."""
    speed = data.y if output != "position" else np.gradient(data.y, data.dt, axis=1)
    notes = {}
    reversal = np.any((np.max(np.where(data.mask, speed, -np.inf), axis=1) > 0)
                      & (np.min(np.where(data.mask, speed, np.inf), axis=1) < 0))
    if not reversal:
        for name in ("coulomb_friction", "stiction", "backlash"):
            notes[name] = "no speed reversal in the data: acts as a constant load, absorbed by the rest levels"
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


def _evidence(name: str, data: GreyData, current: GreyFit, fit: GreyFit) -> str:
    """The residual signature of effect ``name`` in the current model's residual."""
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
        ratio = (np.sqrt(np.mean(e[over] ** 2)) / max(np.sqrt(np.mean(e[~over] ** 2)), 1e-300)) if over.any() and \
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


@_single_thread
def diagnose(data: GreyData, effects=None, candidates: Sequence[str] | None = None, spec: ModelSpec | None = None,
             current: GreyFit | None = None, n_folds: int = 4, bic_margin: float = 10.0, min_gain: float = 0.02,
             max_iter: int = 20, _restarts: int = 0) -> Diagnosis:
    """Try every catalogued effect as an addition to the model and rank them on held-out experiments.

    Parameters
    ----------
    data : GreyData
    effects : names or ``{name: {parameter: value}}``, optional
        Effects of the current model (default: the linear model alone).
    candidates : sequence of str, optional
        Effects to try (default: the whole catalogue minus the current effects).
    spec : ModelSpec, optional
        Orders and output kind of the linear part.
    current : GreyFit, optional
        An already fitted current model (skips its fit).
    n_folds : int, default 4
        Folds of the cross-validation over experiments (at most one per experiment).
    bic_margin : float, default 10.0
        ``best`` needs ``delta_bic < -bic_margin`` ("very strong" evidence on the
        Kass-Raftery scale); two improving effects whose ``delta_bic`` differ by
        less than it (and whose held-out RMSE differ by less than 1 %) are
        reported as indistinguishable.
    min_gain : float, default 0.02
        ``best`` also needs its held-out RMSE ``min_gain`` below the current model's,
        and the effect itself must matter: switching it off (magnitude at zero)
        must change the output by at least a fifth of the RMS it explains
        (``effect_rms``), so that no effect is credited with a refit of the
        other parameters.
    max_iter : int, default 20
        Levenberg-Marquardt iterations of the full-data fits.

    Returns
    -------
    Diagnosis

    Notes
    -----
    Ranking: ``BIC = n log(RSS_cv / n) + k log n`` with ``RSS_cv`` the held-out
    residual sum of squares over all ``n`` samples (cross-validation over
    experiments, :func:`heldout_rss`) and ``k`` the global parameters;
    ``delta_bic`` is a candidate's BIC minus the current model's, so ``k``
    counts the extra parameters. The current model is refitted with the same
    iteration budget as the candidates, and if a candidate's fit with its new
    effect switched off beats it (a better minimum of the current parameters),
    the diagnosis restarts from that fit, so that no effect is credited with a
    better fit of parameters the model already has. With one experiment there is nothing to hold
    out: the training RSS is used and ``validation`` says so.
    """
    base = None
    if current is None:
        base = linear_fit(data, spec)
        current = fit_model(data, effects, base=base, max_iter=max_iter)
    names = [n for n in (candidates or EFFECT_NAMES) if n not in current.spec.effect_names]
    # the current model gets the same iteration budget as the candidates, so that no candidate wins by
    # merely polishing parameters the current model already has
    problems = [_refit_problem(data, current, np.arange(data.n_records), True, tag="__current__")]
    for name in names:
        for options in _variants(name, current.spec):
            problems += candidate_problems(data, current, name, options, tag=name)
    fit_problems(data, problems, max_iter=max_iter)
    polished = GreyFit.from_problem(data, problems[0])
    if polished.rmse < current.rmse:
        current = refine_grid_parameters(data, polished)
    fits: dict[str, GreyFit] = {}
    for name in names:
        mine = [p for p in problems if p.tag == name and np.isfinite(p.cost)]
        if mine:
            fits[name] = refine_grid_parameters(data, GreyFit.from_problem(data, min(mine, key=lambda p: p.cost)))
    restart = _without_new_effect(data, current, fits)
    if restart is not None and _restarts < 1:  # a candidate found better values of the current parameters
        return diagnose(data, candidates=candidates, current=restart, n_folds=n_folds, bic_margin=bic_margin,
                        min_gain=min_gain, max_iter=max_iter, _restarts=_restarts + 1)
    order = list(fits)
    models = [current] + [fits[name] for name in order]
    n = data.n_samples
    if data.n_records >= 2:
        rss = heldout_rss(data, models, n_folds=n_folds)
        validation = f"held-out: {min(n_folds, data.n_records)}-fold cross-validation over experiments"
    else:
        rss = np.array([m.rmse**2 * n for m in models])
        validation = "training error (one experiment: nothing to hold out)"
    bic = n * np.log(np.maximum(rss, 1e-300) / n) + np.array([m.n_params for m in models]) * np.log(n)
    notes = _excitation(data, current.spec.output)
    cands = []
    for i, name in enumerate(order, start=1):
        fit = fits[name]
        entry = {"effect": name, "rmse": float(np.sqrt(rss[i] / n)), "delta_bic": float(bic[i] - bic[0]),
                 "params": _jsonable(fit.effect_params.get(name, {})) if name in fit.effect_params else {},
                 "evidence": _evidence(name, data, current, fit), "train_rmse": float(fit.rmse),
                 "extra_params": int(fit.n_params - current.n_params),
                 "effect_rms": _effect_size(data, fit)}
        if name in notes:
            entry["note"] = notes[name]
        cands.append(entry)
    cands.sort(key=lambda c: c["delta_bic"])
    cur_rmse = float(np.sqrt(rss[0] / n))
    # an improvement counts if it passes BIC, lowers the held-out error by min_gain, and comes from the
    # effect itself: switching the effect off must move the output by a fifth of what the effect explains
    good = [c for c in cands if c["delta_bic"] < -bic_margin and c["rmse"] < (1.0 - min_gain) * cur_rmse
            and c["effect_rms"] >= 0.2 * np.sqrt(max(current.rmse**2 - c["train_rmse"] ** 2, 0.0))]
    best = good[0]["effect"] if good else None
    pairs = []
    for i, a in enumerate(good):
        for b in good[i + 1 :]:
            if abs(a["delta_bic"] - b["delta_bic"]) < max(bic_margin, 0.002 * abs(a["delta_bic"])) and \
                    abs(a["rmse"] - b["rmse"]) < 0.01 * a["rmse"]:
                pairs.append([a["effect"], b["effect"]])
    suggestion = separating_experiment(*pairs[0]) if pairs else None
    return Diagnosis(current, fits, cands, best, noise_floor(data), compare(data, current).fit_percent_all, cur_rmse,
                     validation, pairs, suggestion)


@_single_thread
def _effect_size(data: GreyData, fit: GreyFit) -> float:
    """RMS change of the output when the last effect of ``fit`` is switched off (its magnitude at zero).

    The plant output before the sensor blocks, or the measurement for a sensor effect.
    """
    name = fit.spec.effect_names[-1]
    theta0 = fit.theta.copy()
    pos = fit.spec.n_linear + 1 + _effect_offset(fit.spec, name) if fit.spec.effect_names.count(name) == 1 else \
        fit.theta.size - len(FITTED_PARAMETERS[name])
    cls = EFFECTS[name]
    for j, (pname, _) in enumerate(FITTED_PARAMETERS[name]):
        if pname == cls.magnitude_param:
            theta0[pos + j] = next(p.zero for p in cls.parameters if p.name == pname)
    rows = np.arange(data.n_records)
    sims = simulate_sets(data, [(fit.spec, np.concatenate([th, fit.y0, fit.bias]), rows) for th in (fit.theta, theta0)],
                         true_output=cls.side != "sensor")  # a sensor effect only shows in the measurement
    diff = np.where(data.mask, sims[0] - sims[1], 0.0)
    return float(np.sqrt(np.sum(diff**2) / data.n_samples)) if np.all(np.isfinite(diff)) else 0.0


def _without_new_effect(data: GreyData, current: GreyFit, fits: dict) -> GreyFit | None:
    """The best candidate fit with its new effect switched off, if that beats the current model.

    A candidate starts from its own profile fit of the linear part, which can
    land in a better minimum than the current model's (quantized outputs make
    the error surface rough); whatever of that gain survives switching the
    effect off belongs to the current model.
    """
    best = None
    for fit in fits.values():
        if fit.rmse >= current.rmse * (1.0 - 1e-3):
            continue
        n_old = current.theta.size
        theta = fit.theta[:n_old].copy()
        problem = _problem(data, current.spec, theta, fit.y0, fit.bias, np.arange(data.n_records), free_global=False)
        problem.free[:] = False
        fit_problems(data, [problem], max_iter=0)
        reduced = GreyFit.from_problem(data, problem)
        if reduced.rmse < current.rmse * (1.0 - 1e-3) and (best is None or reduced.rmse < best.rmse):
            best = reduced
    return best


def error_ladder(data: GreyData, effects=None, spec: ModelSpec | None = None, max_steps: int = 3,
                 **kwargs) -> tuple[list[dict], list[Diagnosis]]:
    """RMSE of the linear model, then with the best effect added, then the next, until nothing helps.

    Returns
    -------
    rungs : list of dict
        ``{"model", "added", "rmse", "fit_percent", "heldout_rmse", "params"}`` per rung.
    diagnoses : list of Diagnosis
        The diagnosis made at each rung.
    """
    current = fit_model(data, effects, base=linear_fit(data, spec))
    rungs, diagnoses = [], []
    added = None
    for _ in range(max_steps + 1):
        d = diagnose(data, current=current, **kwargs)
        diagnoses.append(d)
        rungs.append({"model": current.spec.label, "added": added, "rmse": float(current.rmse),
                      "fit_percent": float(d.fit_percent), "heldout_rmse": float(d.heldout_rmse),
                      "params": _jsonable(current.effect_params)})
        if d.best is None or len(rungs) > max_steps:
            break
        added, current = d.best, d.fits[d.best]
    return rungs, diagnoses


# -- the TwinEstimator with effects ---------------------------------------------------------------
def _estimator_data(estimator, records) -> GreyData:
    from agents.twin.records import as_records, decimate

    raw = as_records(records, min_steps=3)
    kept = [decimate(rec, estimator.n_samples) for rec in raw]
    items = records if isinstance(records, (list, tuple)) else None
    index = None
    if items and all(isinstance(it, Mapping) and it.get("experiment_index") is not None for it in items):
        index = [int(it["experiment_index"]) for it in items]
    return GreyData.from_records([{"t": r.t, "r": r.r, "u": r.u, "y": r.y} for r in kept], experiment_index=index)


@_single_thread
def fit_twin_effects(estimator, records):
    """``TwinEstimator.fit`` with ``effects``: grey-box fit of the linear part and the effect parameters.

    ``estimator.effects`` is a list of catalogue names or ``{name: {parameter:
    value}}``; given values start the fit (all values of an effect given: no
    search of its start), missing ones are found from the data. Sets the
    estimator's fitted attributes like the linear fit, plus ``effects_`` (the
    fitted blocks, which :class:`agents.twin.TwinEnv` puts into the twin's
    loop), ``effect_params_`` and ``greybox_`` (the :class:`GreyFit`).
    ``rmse_`` is normalised by each record's step height ``|r2 - y0|``.
    """
    orders = estimator._check_params()
    data = _estimator_data(estimator, records)
    spec = ModelSpec(orders.n, orders.m, orders.k, estimator.output)
    items = _effect_items(estimator.effects)
    base = linear_fit(data, spec)
    complete = all(all(p in given for p, _ in FITTED_PARAMETERS[name]) for name, given in items)
    if complete and items:
        for name, given in items:
            options = {k: v for k, v in given.items() if k not in dict(FITTED_PARAMETERS[name])}
            spec = spec.with_effect(name, options)
        values = [float(given[p]) for name, given in items for p, _ in FITTED_PARAMETERS[name]]
        theta = np.concatenate([base.theta, values])
        profiler = TwinEstimator(n_poles=spec.n_poles, n_zeros=spec.n_zeros, n_integrators=spec.n_integrators,
                                 output=spec.output, max_iter=20, tol=1e-6)
        rmse, theta_p, y0, bias = _profile(data, spec, theta, profiler)  # linear part consistent with the effects
        if np.isfinite(rmse):
            theta = theta_p
        else:
            y0, bias = base.y0, _forward_bias(data, base, spec, theta)
        n_eff = theta.size - spec.n_linear - 1
        fake = GreyFit(spec, theta, spec.plant(theta), spec.blocks(theta), y0, bias, base.y_sim, base.rmse)
        lower, upper, scale = _current_effect_bounds(data, fake, np.zeros(n_eff), np.zeros(n_eff), np.zeros(n_eff))
        problem = _problem(data, spec, theta, y0, bias, np.arange(data.n_records), lower, upper, scale)
        fit_problems(data, [problem], max_iter=min(int(estimator.max_iter), 20))
        fit = refine_grid_parameters(data, GreyFit.from_problem(data, problem))
    else:
        fit = fit_model(data, estimator.effects, base=base)
    _store(estimator, data, fit)
    return estimator


def _store(estimator, data: GreyData, fit: GreyFit) -> None:
    spec = fit.spec
    nl = spec.n_linear
    nb = spec.n_zeros + 1
    estimator.greybox_ = fit
    estimator.num_ = np.asarray(fit.theta[:nb], dtype=float)
    estimator.den_ = np.concatenate([[1.0], fit.theta[nb:nl], np.zeros(spec.n_integrators)])
    estimator.params_ = np.asarray(fit.theta[:nl], dtype=float)
    estimator.param_names_ = tuple(spec.global_names()[:nl])
    estimator.delay_ = float(fit.theta[nl])
    estimator.plant_ = fit.plant
    blocks = fit.blocks
    if any(b.side == "actuator" for b in blocks):  # the plant-input bias matters after a nonlinearity
        blocks = blocks + (build_effect("offset", {"value": float(np.median(fit.bias))}),)
        # the twin's loop must be able to hold the rest levels of the data: a limit below the largest
        # fitted rest command (a poorly determined rest on few or short records) is raised to it
        need = 1.02 * float(np.max(np.abs(_rest_command(fit))))
        blocks = tuple(build_effect("saturation", {"limit": need}) if b.name == "saturation" and b.limit < need
                       else b for b in blocks)
    estimator.effects_ = blocks
    estimator.effect_params_ = fit.effect_params
    err = np.where(data.mask, data.y - fit.y_sim, 0.0)
    height = np.abs(data.r[np.arange(data.n_records), data.mask.sum(axis=1) - 1] - fit.y0)
    height = np.where(height > 0.0, height, np.nan)
    estimator.rmse_abs_ = float(fit.rmse)
    estimator.rmse_ = float(np.sqrt(np.sum((err / height[:, None]) ** 2) / data.n_samples))
    estimator.rest_levels_ = np.column_stack([fit.y0, _rest_command(fit)])
    estimator.n_iter_ = 0
    estimator.converged_ = True
    estimator.delay_grid_ = np.array([estimator.delay_])
    estimator.delay_rmse_ = np.array([estimator.rmse_])
    estimator.n_records_ = data.n_records
    estimator.n_samples_ = int(data.u.shape[1])
    estimator.dt_ = float(data.dt)


def _refit_rest(estimator, records) -> tuple[GreyData, GreyFit]:
    """The fitted model on new records: only their rest levels and biases are fitted."""
    data = _estimator_data(estimator, records)
    fit = estimator.greybox_
    rows = np.arange(data.n_records)
    y0 = data.y[:, 0].copy()
    v_rest = fit.plant.discretize(data.dt).equilibrium(y0)[1]
    bias = v_rest - data.u[:, 0]
    problem = _problem(data, fit.spec, fit.theta, y0, bias, rows, free_global=False)
    fit_problems(data, [problem], max_iter=10)
    return data, GreyFit.from_problem(data, problem)


@_single_thread
def predict_twin_effects(estimator, records) -> list[np.ndarray]:
    """``TwinEstimator.predict`` with effects: simulated outputs, each of shape (n_steps,)."""
    data, fit = _refit_rest(estimator, records)
    return [fit.y_sim[k][data.mask[k]] for k in range(data.n_records)]


@_single_thread
def rmse_twin_effects(estimator, records, normalize: bool = True) -> float:
    """``TwinEstimator.rmse`` with effects (normalised by the step height by default)."""
    data, fit = _refit_rest(estimator, records)
    if not normalize:
        return float(fit.rmse)
    err = np.where(data.mask, data.y - fit.y_sim, 0.0)
    height = np.abs(data.r[np.arange(data.n_records), data.mask.sum(axis=1) - 1] - fit.y0)
    return float(np.sqrt(np.sum((err / np.where(height > 0, height, np.nan)[:, None]) ** 2) / data.n_samples))
