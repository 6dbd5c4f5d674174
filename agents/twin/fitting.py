"""Grey-box fits of a model structure: the base linear model, then effects added one at a time.

:func:`linear_fit` starts from SRIVC; :func:`candidate_problems` builds the
problems of one added effect from its data-based starts
(:mod:`agents.twin.guesses`), on the SRIVC profile where it helps;
:func:`fit_model` chains them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from agents.thread_limits import single_thread
from agents.twin.greybox import FITTED_PARAMETERS, GreyData, GreyFit, ModelSpec, Problem, fit_problems, simulate_sets
from agents.twin.guesses import effect_starts, quantization_scan, rest_command
from agents.twin.identify import LinearIdentification, identify_linear
from gbo_envs.physics.effects import EFFECT_NAMES, EFFECTS

__all__ = ["PROFILE_EFFECTS", "candidate_problems", "effect_bounds", "effect_items", "effect_offset", "fit_model",
           "forward_bias", "linear_fit", "make_problem", "profile", "refine_grid_parameters"]

@single_thread()
def linear_fit(data: GreyData, spec: ModelSpec | None = None, refine: bool = True) -> GreyFit:
    """Base linear model: SRIVC with a delay of at most one sample, then refined by simulation error.

    Parameters
    ----------
    data : GreyData
    spec : ModelSpec, optional
        Orders and output kind (its effects are ignored); default 2 poles, no zero.
    refine : bool, default True
        Polish the SRIVC estimate by least squares on the simulation error (:func:`fit_problems`).
    """
    spec = ModelSpec() if spec is None else ModelSpec(spec.n_poles, spec.n_zeros, spec.n_integrators, spec.output)
    lengths = data.mask.sum(axis=1)  # real samples lead each row, padding follows (GreyData.from_records)
    records = [{"t": data.t[k, :m], "r": data.r[k, :m], "u": data.u[k, :m], "y": data.y[k, :m]}
               for k, m in enumerate(lengths)]  # views of the rows: no copy of the data
    fit = identify_linear(records, n_poles=spec.n_poles, n_zeros=spec.n_zeros, n_integrators=spec.n_integrators,
                          max_delay=data.dt, refine_delay=False)
    theta = np.concatenate([fit.params, [fit.delay]])
    y0, u0 = fit.rest_levels[:, 0], fit.rest_levels[:, 1]
    v_rest = fit.plant(spec.output).discretize(data.dt).equilibrium(y0)[1]
    problem = make_problem(data, spec, theta, y0, v_rest - u0, np.arange(data.n_records))
    fit_problems(data, [problem], max_iter=30 if refine else 0)  # the delay is refined here, in [0, dt]
    return GreyFit.from_problem(data, problem)


def make_problem(data: GreyData, spec: ModelSpec, theta_global: np.ndarray, y0: np.ndarray, bias: np.ndarray,
                 rows: np.ndarray, lower=None, upper=None, scale=None, free_global: bool = True,
                 tag=None) -> Problem:
    """A :class:`Problem` of ``spec`` on the records ``rows``, with default bounds for the linear part and nuisances.

    Parameters
    ----------
    data : GreyData
    spec : ModelSpec
    theta_global : ndarray of shape (n_global,)
        Starting global parameters (``spec.global_names()``).
    y0, bias : ndarray of shape (len(rows),)
        Starting rest level (units of ``y``) and plant-input bias (units of ``u``) of each record.
    rows : ndarray of int
        Records of ``data`` the problem fits.
    lower, upper, scale : ndarray of shape (n_global - spec.n_linear - 1,), optional
        Bounds and scales of the effect parameters (default unbounded, scale 1); the linear
        part is unbounded, the delay in ``[0, data.dt]``.
    free_global : bool, default True
        Whether the iteration moves the global parameters (else only the rest levels and biases).
    tag : object, optional
        Caller's label, kept on the problem.
    """
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


def forward_bias(data: GreyData, fit: GreyFit, spec: ModelSpec, theta: np.ndarray) -> np.ndarray:
    """Plant-input bias that keeps each record's rest input after adding effect blocks.

    The blocks of ``spec`` at ``theta`` map the rest command (:func:`rest_command` of ``fit``)
    differently from ``fit``'s blocks; the difference is added to ``fit.bias``.

    Returns
    -------
    ndarray of shape (n_records,)
        In the units of ``u``.
    """
    u_rest = rest_command(fit)
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


def profile(data: GreyData, spec: ModelSpec, theta: np.ndarray, max_delay: float | None = None,
            max_iter: int = 20, tol: float = 1e-6) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """SRIVC fit of the linear part on the plant input implied by ``spec``'s actuator blocks at ``theta``.

    Parameters
    ----------
    data : GreyData
    spec : ModelSpec
    theta : ndarray of shape (n_global,)
        Global parameters; the effect parameters are kept.
    max_delay : float, optional
        Search the delay up to this many s (default: the delay of ``theta`` plus any ``time_delay``, fixed).
    max_iter, tol
        SRIVC iterations and tolerance (:func:`agents.twin.identify.identify_linear`).

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
    try:
        fit: LinearIdentification = identify_linear(
            _records_through(data, blocks, spec.output), n_poles=spec.n_poles, n_zeros=spec.n_zeros,
            n_integrators=spec.n_integrators, delay=delay, max_delay=max_delay, max_iter=max_iter, tol=tol)
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


def effect_offset(spec: ModelSpec, name: str) -> int:
    """Position of effect ``name``'s first fitted parameter among ``spec``'s effect parameters (0-based).

    Raises
    ------
    KeyError
        ``name`` is not an effect of ``spec``.
    """
    pos = 0
    for effect, _ in spec.effects:
        if effect == name:
            return pos
        pos += len(FITTED_PARAMETERS[effect])
    raise KeyError(name)


def _profile_problems(data, current, spec, name, starts, lo, hi, sc, lower, upper, scale, tag) -> list[Problem]:
    """Starting point on the SRIVC profile of the new effect's parameter(s), then one bounded problem."""
    from scipy.optimize import minimize_scalar

    settings = {"max_iter": 10, "tol": 1e-5}
    rows = np.arange(data.n_records)
    g0 = current.theta.size
    if name == "time_delay":
        theta = np.concatenate([current.theta, [0.0]])
        res = profile(data, spec, theta, max_delay=float(hi[0]), **settings)
    elif not starts:
        return []
    else:
        results = []
        for start in starts:
            theta = np.concatenate([current.theta, np.clip(start, lo, hi)])
            results.append((theta, profile(data, spec, theta, **settings)))
        best = int(np.argmin([r[1][0] for r in results]))
        res = results[best][1]
        if lo.size == 1 and len(starts) > 1 and np.isfinite(res[0]):
            values = [float(r[0][g0]) for r in results]
            a = values[max(best - 1, 0)]
            b = values[min(best + 1, len(values) - 1)]
            if b > a:
                cache = {}
                # an effect value the profile cannot fit (inf) goes to Brent as a finite value worse than every
                # fitted one: its parabolic steps subtract the values, and inf - inf warned "invalid value"
                worst = 2.0 * max(r[1][0] for r in results if np.isfinite(r[1][0])) or 1.0

                def cost(x: float) -> float:
                    th = results[best][0].copy()
                    th[g0] = x
                    cache[x] = profile(data, spec, th, **settings)
                    return cache[x][0] if np.isfinite(cache[x][0]) else worst

                minimize_scalar(cost, bounds=(a, b), method="bounded", options={"maxiter": 6,
                                                                                 "xatol": 1e-3 * (b - a)})
                x = min(cache, key=lambda key: cache[key][0])
                if cache[x][0] < res[0]:
                    res = cache[x]
    _, theta, y0, bias = res
    if not np.isfinite(res[0]):
        return []
    return [make_problem(data, spec, theta, y0, bias, rows, lower, upper, scale, tag=tag)]


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
    lower, upper, scale = effect_bounds(
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
    biases = [forward_bias(data, current, spec, th) for th in thetas]
    sims = simulate_sets(data, [(spec, np.concatenate([th, current.y0, b]), rows) for th, b in zip(thetas, biases)])
    costs = []
    for y in sims:
        err = np.where(data.mask, y - data.y, 0.0)
        costs.append(float(np.sum(err**2)) if np.all(np.isfinite(err)) else np.inf)
    order = np.argsort(costs)[:n_keep]
    problems = []
    for i in order:
        problems.append(make_problem(data, spec, thetas[i], current.y0.copy(), biases[i], rows, lower, upper, scale,
                                     tag=tag))
    return problems


def effect_bounds(data: GreyData, current: GreyFit, lower: np.ndarray, upper: np.ndarray,
                  scale: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounds and scales of the effects already in ``current`` (their data-based ranges, :func:`effect_starts`).

    ``lower``, ``upper`` and ``scale`` (one entry per effect parameter, the effects of
    ``current`` first) are filled in place for those effects and returned.
    """
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
    j = fit.spec.n_linear + 1 + effect_offset(fit.spec, "quantization")
    span = float(np.ptp(data.y[data.mask]))
    steps = quantization_scan(data, fit, span, n_best=1, y_true=y_true)
    best = fit
    for q in steps + [fit.theta[j]]:
        th = fit.theta.copy()
        th[j] = q
        problem = make_problem(data, fit.spec, th, fit.y0, fit.bias, rows, free_global=False)
        fit_problems(data, [problem], max_iter=0)
        cand = GreyFit.from_problem(data, problem)
        if cand.rmse < best.rmse:
            best = cand
    return best


@single_thread()
def fit_model(data: GreyData, effects: Sequence | Mapping | None = None, spec: ModelSpec | None = None,
              base: GreyFit | None = None, max_iter: int = 25) -> GreyFit:
    """Grey-box fit of the linear model plus ``effects`` (names, or ``{name: {parameter: value}}`` guesses).

    Effects are added one at a time to the fitted model (each from its
    data-based starts, or from the given values), then all parameters are
    refitted together.
    """
    fit = base if base is not None else linear_fit(data, spec)
    for name, given in effect_items(effects):
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


def effect_items(effects) -> list[tuple[str, dict]]:
    """``[(name, {parameter: value})]`` of effects given as names, a comma-separated string or ``{name: values}``.

    Raises
    ------
    ValueError
        An effect outside the catalogue :data:`gbo_envs.physics.EFFECT_NAMES`.
    """
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
