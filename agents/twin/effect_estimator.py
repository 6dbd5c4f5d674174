"""The :class:`~agents.twin.TwinEstimator` with ``effects``: fit, predict and score through the grey-box fit."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from agents.thread_limits import single_thread
from agents.twin.estimator import TwinEstimator
from agents.twin.fitting import (
    _current_effect_bounds,
    _effect_items,
    _forward_bias,
    _problem,
    _profile,
    fit_model,
    linear_fit,
    refine_grid_parameters,
)
from agents.twin.greybox import FITTED_PARAMETERS, GreyData, GreyFit, ModelSpec, fit_problems
from agents.twin.guesses import _rest_command
from gbo_envs.physics.effects import build_effect

__all__ = ["fit_twin_effects", "predict_twin_effects", "rmse_twin_effects"]


def _estimator_data(estimator, records) -> GreyData:
    from agents.twin.records import as_records, decimate

    raw = as_records(records, min_steps=3)
    kept = [decimate(rec, estimator.n_samples) for rec in raw]
    items = records if isinstance(records, (list, tuple)) else None
    index = None
    if items and all(isinstance(it, Mapping) and it.get("experiment_index") is not None for it in items):
        index = [int(it["experiment_index"]) for it in items]
    return GreyData.from_records([{"t": r.t, "r": r.r, "u": r.u, "y": r.y} for r in kept], experiment_index=index)


@single_thread()
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


@single_thread()
def predict_twin_effects(estimator, records) -> list[np.ndarray]:
    """``TwinEstimator.predict`` with effects: simulated outputs, each of shape (n_steps,)."""
    data, fit = _refit_rest(estimator, records)
    return [fit.y_sim[k][data.mask[k]] for k in range(data.n_records)]


@single_thread()
def rmse_twin_effects(estimator, records, normalize: bool = True) -> float:
    """``TwinEstimator.rmse`` with effects (normalised by the step height by default)."""
    data, fit = _refit_rest(estimator, records)
    if not normalize:
        return float(fit.rmse)
    err = np.where(data.mask, data.y - fit.y_sim, 0.0)
    height = np.abs(data.r[np.arange(data.n_records), data.mask.sum(axis=1) - 1] - fit.y0)
    return float(np.sqrt(np.sum((err / np.where(height > 0, height, np.nan)[:, None]) ** 2) / data.n_samples))
