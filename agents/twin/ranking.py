"""Rank the candidates: held-out error over experiments, a BIC penalty, and the rules a physicist would sign.

The pipeline's fifth stage (records, linear fit, candidates, fits, **ranking**, report).
:func:`heldout_rss` cross-validates every fit over experiments; :func:`rank` turns the
held-out errors into the ranking

.. math:: \\mathrm{BIC} = n \\log(\\mathrm{RSS}_{cv} / n) + k \\log n

(``delta_bic`` against the current model) and picks the best candidate with the rules of
:func:`rank`: beyond the BIC margin, a held-out gain, a gain the measurement resolves and an
effect that itself matters; an effect that explains a large share of the residual power
is not beaten by one that explains little, unless the held-out error says so clearly; and
a grown model order comes after the effects of the catalogue.
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from agents.jsonable import jsonable
from agents.thread_limits import single_thread
from agents.twin.candidates import refit_problem
from agents.twin.evidence import REVEALING_EXPERIMENTS, effect_evidence, order_change, separating_experiment
from agents.twin.fidelity import rmse
from agents.twin.least_squares import Problem, fit_problems
from agents.twin.model import FITTED_PARAMETERS, GreyFit, effect_offset, fitted_parameters, output_error
from agents.twin.modes import RESONANCE_DAMPING, is_resonance
from agents.twin.noise_floor import NoiseFloor
from agents.twin.records import Batch
from agents.twin.simulation import simulate_sets
from agents.twin.static_map import MAP_NAMES, map_evidence, map_size
from agents.twin.uncertainty import parameter_intervals
from agents.twin.workers import map_independent
from gbo_envs.physics.effects import EFFECTS, describe_effect

__all__ = ["CLEAR_HELDOUT_GAIN", "DEFAULT_FOLDS", "NUISANCE_REFIT_ITER", "ORDER_RULE", "REFIT_RATIO", "REFIT_SHARE",
           "Ranking", "effect_intervals", "effect_size", "heldout_rss", "rank", "validated_folds"]

#: Folds of the cross-validation over experiments when none are given (fewer with fewer experiments).
DEFAULT_FOLDS = 4
#: Trial points of the refit of a fold's rest levels and biases with an effect parameter put back at its
#: full-data value (:func:`_keep_undetermined`).
NUISANCE_REFIT_ITER = 6


def validated_folds(n_folds, n_records: int) -> int:
    """``n_folds`` checked against the data (``None``: 4, or one fold per experiment when there are fewer)."""
    if n_folds is None:
        return min(DEFAULT_FOLDS, max(n_records, 2))
    if isinstance(n_folds, bool) or not isinstance(n_folds, numbers.Integral):
        raise TypeError(f"n_folds: expected an integer from 2 to the number of experiments ({n_records}), "
                        f"got {n_folds!r}")
    if not 2 <= n_folds <= max(n_records, 2) or n_records < 2:
        what = ("one experiment has nothing to hold out; leave the folds at their default" if n_records < 2 else
                f"must be from 2 to the number of experiments ({n_records})")
        raise ValueError(f"n_folds (--folds): {what}, got {n_folds}")
    return int(n_folds)


def _folds(data: Batch, n_folds: int) -> list[np.ndarray]:
    order = np.argsort(data.index, kind="stable")
    k = min(n_folds, data.n_records)
    return [order[i::k] for i in range(k)]


#: A candidate whose fit to all data explains more than this share (%) of the current model's residual power ...
REFIT_SHARE = 30.0
#: ... and whose held-out RMSE on a fold is more than this many times the current model's there has a failed
#: fold refit: that fold is predicted from the all-data parameters instead (:func:`heldout_rss`).
REFIT_RATIO = 2.0


def heldout_rss(data: Batch, fits: Sequence[GreyFit], n_folds: int = 4, max_iter: int = 6,
                refits: dict | None = None, known: dict | None = None) -> np.ndarray:
    """Held-out residual sum of squares of each model, cross-validated over experiments.

    Each fold's experiments are left out, every model is refitted on the others
    (from its full-data fit), and its global parameters are then applied to the
    left-out experiments with only their rest levels and biases fitted. An effect
    parameter that the fold's experiments do not determine keeps its full-data value
    (:func:`_keep_undetermined`).

    With ``refits`` (a dict, filled in place) ``fits[0]`` is the reference (the current model), and a
    fold refit cannot fail silently: where a model's fit to all data explains more than
    :data:`REFIT_SHARE` % of the reference's residual power but its held-out RMSE on a fold is more than
    :data:`REFIT_RATIO` times the reference's there (a dead time whose fold refit slid into another
    minimum of its multimodal cost), that fold is predicted from the model's all-data parameters (the
    left-out experiments' rest levels and biases fitted), kept where it predicts better;
    ``refits[m]`` lists ``(fold, failed RMSE, RMSE from the all-data parameters, reference RMSE)``.

    ``known`` (a dict, filled in place) holds the models cross-validated already with the same
    ``n_folds``, ``max_iter`` and reference: ``{id(fit): (fit, fold costs, refits entry)}``. They are not
    refitted (each model's folds are refitted alone, so the values are the same).

    Returns
    -------
    ndarray of shape (n_models,)
    """
    folds = _folds(data, n_folds)
    known = {} if known is None else known
    todo = [m for m, fit in enumerate(fits) if known.get(id(fit), (None,))[0] is not fit]
    costs = np.zeros((len(fits), len(folds)))
    costs[todo] = _fold_costs(data, [fits[m] for m in todo], folds, max_iter)
    for m, fit in enumerate(fits):
        if m not in todo:
            costs[m] = known[id(fit)][1]
    if refits is not None:
        _refit_failed_folds(data, fits, folds, costs, refits, todo)
        refits.update({m: known[id(fits[m])][2] for m in range(len(fits)) if m not in todo and known[id(fits[m])][2]})
    for m in todo:
        known[id(fits[m])] = (fits[m], costs[m].copy(), (refits or {}).get(m))
    return costs.sum(axis=1)


def _fold_costs(data: Batch, fits: Sequence[GreyFit], folds: list[np.ndarray], max_iter: int) -> np.ndarray:
    """Held-out residual sums of squares of ``fits`` on each of ``folds``, shape (n_models, n_folds)."""
    costs = np.zeros((len(fits), len(folds)))
    if not fits:
        return costs
    train = []
    for m, fit in enumerate(fits):
        for f, test in enumerate(folds):
            rows = np.setdiff1d(np.arange(data.n_records), test)
            train.append(refit_problem(data, fit, rows, True, tag=(m, f)))
    fit_problems(data, train, max_iter=max_iter)
    _keep_undetermined(data, train, fits)
    tests = []
    for p in train:
        m, f = p.tag
        test = folds[f]
        fit = fits[m]
        tests.append(refit_problem(data, fit, test, False, theta=p.theta[: p.n_global], tag=(m, f)))
    fit_problems(data, tests, max_iter=4)
    for p in tests:
        costs[p.tag] = p.cost
    return costs


def _refit_failed_folds(data: Batch, fits: Sequence[GreyFit], folds: list[np.ndarray], costs: np.ndarray,
                        refits: dict, models: Sequence[int]) -> None:
    """The guard of :func:`heldout_rss` (``refits``): refit the failed folds of ``models`` (indices of ``fits``)
    from the all-data parameters.

    Changes ``costs`` (models by folds, held-out residual sums of squares) in place and fills ``refits``.
    """
    reference = fits[0].rmse ** 2
    failed = [(m, f) for m in models if m > 0 for f in range(len(folds))
              if 100.0 * (1.0 - fits[m].rmse**2 / max(reference, 1e-300)) > REFIT_SHARE
              and costs[m, f] > REFIT_RATIO**2 * costs[0, f]]
    if not failed:
        return
    trials = [refit_problem(data, fits[m], folds[f], False, tag=(m, f)) for m, f in failed]
    fit_problems(data, trials, max_iter=4)
    for p in trials:
        m, f = p.tag
        n_fold = int(data.mask[folds[f]].sum())
        if p.cost < costs[m, f]:
            refits.setdefault(m, []).append((f, float(np.sqrt(costs[m, f] / n_fold)), float(np.sqrt(p.cost / n_fold)),
                                             float(np.sqrt(costs[0, f] / n_fold))))
            costs[m, f] = p.cost


def _keep_undetermined(data: Batch, train: list[Problem], fits: Sequence[GreyFit]) -> None:
    """Put back the full-data value of every effect parameter that a fold's refit moved without cause.

    A parameter the fold's experiments do not excite (a drive limit that no command of
    theirs reaches) has no gradient there, yet the refit may move it along its flat
    direction (the forward-difference steps); the left-out experiment that does show it
    would then be predicted with an arbitrary value (on DCMotor-v0 with a 138-unit limit
    reached in one of five experiments, the fold without it moved the limit to 134.9, just
    above its largest command: a held-out error 700 times the fit's, and a wrong effect
    credited instead). A parameter is put back when its full-data value, with the fold's
    rest levels and biases fitted again (:data:`NUISANCE_REFIT_ITER` trial points), leaves
    the fold's training cost unchanged (relative ``1e-9``): the fold's data cannot tell the
    two values apart. The rest levels and biases take part because they can absorb an
    effect the fold's experiments do not show in full: a dead zone of width ``w`` that
    the commands only cross shifts each record's input by ``w / 2`` away from the band, which
    the input biases absorb, so the width and the biases are flat only together (on
    DCMotor-v0 with a 20-unit dead zone, a fold moved the width to 10.9 at a training cost
    lower by 5e-10 relative, and its held-out error was 30 times the fit's). Changes ``train``
    in place (``theta`` and ``cost``).
    """
    trials, owners = [], []
    for i, p in enumerate(train):
        full = fits[p.tag[0]].theta
        for j in range(p.spec.n_linear + 1, p.n_global):
            if p.theta[j] != full[j]:
                theta = p.theta.copy()
                theta[j] = full[j]
                free = p.free.copy()
                free[: p.n_global] = False  # the rest levels and biases only
                trials.append(replace(p, theta=theta, free=free))
                owners.append(i)
    if not trials:
        return
    fit_problems(data, trials, max_iter=NUISANCE_REFIT_ITER)
    changed = {}
    for trial, i in zip(trials, owners):
        if trial.cost <= train[i].cost * (1.0 + 1e-9):
            changed.setdefault(i, []).append(trial)
    for i, kept in changed.items():
        p = train[i]
        for trial in kept:  # each put-back parameter, with the rest levels and biases of its own refit
            p.theta[: p.n_global] = np.where(trial.theta[: p.n_global] != p.theta[: p.n_global],
                                             trial.theta[: p.n_global], p.theta[: p.n_global])
        p.theta[p.n_global :] = min(kept, key=lambda t: t.cost).theta[p.n_global :]
    if changed:
        fit_problems(data, [train[i] for i in sorted(changed)], max_iter=0)  # their costs at the kept values


def effect_intervals(data: Batch, fit: GreyFit, name: str, level: float = 0.95) -> dict[str, dict]:
    """Value, standard error, ``level`` confidence interval and unit of each fitted parameter of effect ``name``
    (not of the options it holds, such as a static map's breakpoints).

    From :func:`agents.twin.uncertainty.parameter_intervals`; the unit is the catalogue's
    (:func:`gbo_envs.physics.describe_effect`, e.g. ``"input units"``). A parameter chosen on
    a grid (the quantization step) has ``std`` ``None``.

    Returns
    -------
    dict
        ``{parameter: {"value", "std", "low", "high", "unit"}}`` (JSON-ready: ``None`` for NaN).
    """
    intervals = parameter_intervals(data, fit, level)
    units = {p.name: p.unit for p in describe_effect(name)}
    fitted = {param for param, _ in fitted_parameters(name, dict(fit.spec.effects)[name])}
    out = {}
    for param, value in fit.effect_params.get(name, {}).items():
        if isinstance(value, str) or param not in fitted:  # a variant's name, or an option held (a breakpoint)
            continue
        ci = intervals.get(f"{name}.{param}", {"value": value, "std": None, "low": None, "high": None})
        out[param] = {**jsonable(ci, finite=True), "unit": units.get(param, "")}
    return out


@single_thread()
def effect_size(data: Batch, fit: GreyFit) -> float:
    """RMS change of the output when the last effect of ``fit`` is switched off (its magnitude at zero).

    The plant output before the sensor blocks, or the measurement for a sensor effect.
    """
    name = fit.spec.effect_names[-1]
    theta0 = fit.theta.copy()
    fitted = fitted_parameters(name, fit.spec.effects[-1][1])
    pos = fit.spec.n_linear + 1 + effect_offset(fit.spec, name) if fit.spec.effect_names.count(name) == 1 else \
        fit.theta.size - len(fitted)
    cls = EFFECTS[name]
    for j, (pname, _) in enumerate(fitted):
        if pname == cls.magnitude_param:
            theta0[pos + j] = next(p.zero for p in cls.parameters if p.name == pname)
    rows = np.arange(data.n_records)
    sims = simulate_sets(data, [(fit.spec, np.concatenate([th, fit.nuisance()]), rows) for th in (fit.theta, theta0)],
                         true_output=cls.side != "sensor")  # a sensor effect only shows in the measurement
    size = rmse(output_error(sims[0], sims[1], data.mask, fit.spec, data.closed_loop), mask=data.mask)  # the fit's
    return size if np.isfinite(size) else 0.0


#: A candidate that explains a much larger share of the residual power (see :func:`rank`) is put first
#: unless the other's held-out RMSE is lower by at least this fraction.
CLEAR_HELDOUT_GAIN = 0.05
#: Shares of the residual power (training) that count as "much larger": at least this many percentage
#: points more, and at least :data:`SHARE_RATIO` times the other's.
SHARE_POINTS = 10.0
SHARE_RATIO = 1.5


@dataclass(frozen=True)
class Ranking:
    """The ranked candidates of a diagnosis (:func:`rank`).

    Attributes
    ----------
    candidates : list of dict
        Per candidate, best first: ``effect, rmse`` (held-out), ``delta_bic, params, evidence,
        train_rmse, share`` (% of the current model's residual power the candidate's fit
        explains), ``extra_params, effect_rms, fitted, intervals``, ``verdict`` (``"selected"``,
        ``"passes"`` or the first rule it fails, :data:`ORDER_RULE`) and ``note`` where the data
        cannot show the effect.
    best : str or None
        The candidate the rules select.
    heldout_rmse : float
        The current model's held-out RMSE, units of ``y``.
    validation : str
        How the held-out error was taken.
    indistinguishable : list of [str, str]
        Pairs the data cannot tell apart.
    suggested_experiment : str or None
    """

    candidates: list
    best: str | None
    heldout_rmse: float
    validation: str
    indistinguishable: list
    suggested_experiment: str | None


def rank(data: Batch, current: GreyFit, fits: dict, plan, noise: NoiseFloor, n_folds: int,
         bic_margin: float = 10.0, min_gain: float = 0.02, noise_gain: float = 0.05, progress=None,
         modes: tuple | None = None, known: dict | None = None) -> Ranking:
    """Rank the candidate ``fits`` against ``current`` and select the best; see :func:`agents.twin.diagnose.diagnose`.

    ``modes`` are the plant's modes in the residual of ``current`` (:func:`agents.twin.modes.plant_modes`), which
    the evidence of a compliance or a pole pair names (``None``: scanned for each where needed). ``known``: what an
    earlier ranking against the same ``current`` (and ``modes``) found for the models it shares with this one,
    filled in place: their held-out costs (``known["heldout"]``, :func:`heldout_rss`) and descriptions
    (``known["described"]``).

    Rules, in order: a candidate is *good* when its ``delta_bic < -bic_margin``, its held-out
    RMSE is below ``(1 - min_gain)`` times the current model's and at least ``noise_gain``
    times the noise floor below it, its fit to all data is better than the current model's
    (a candidate that fits worse cannot be the missing physics, whatever a few held-out
    experiments say), and its ``effect_rms`` is at least a fifth of the RMS it explains. The
    good candidates are ordered by ``delta_bic``; then a candidate whose fit explains a much larger
    share of the residual power (:data:`SHARE_POINTS`, :data:`SHARE_RATIO`)
    moves ahead of one that explains little, unless the latter's held-out RMSE is lower by
    :data:`CLEAR_HELDOUT_GAIN`: the held-out error of a few experiments is itself uncertain,
    and a small effect that wins by a hair is not the physics that the residual shows. A
    grown order of the linear part comes after every good effect (:func:`_physics_first`): it
    is the fallback for what the catalogue does not explain, and the ladder grows it once no
    effect helps. With one experiment nothing is held out, and no order candidate is
    good: the training error of one record always favours the more flexible structure (on
    LinearMotor-v0 with Coulomb friction a pole pair 8 % ahead of saturation on guided BO's first
    record, whose twin then explained its next records and was never diagnosed again).
    """
    order = list(fits)
    models = [current] + [fits[name] for name in order]
    n = data.n_samples
    if progress is not None:
        progress.set_postfix_str("cross-validation over experiments")
    refits: dict = {}
    if data.n_records >= 2:
        rss = heldout_rss(data, models, n_folds=n_folds, refits=refits,
                          known=None if known is None else known.setdefault("heldout", {}))
        validation = f"held-out: {min(n_folds, data.n_records)}-fold cross-validation over experiments"
    else:
        rss = np.array([m.rmse**2 * n for m in models])
        validation = "training error (one experiment: nothing to hold out)"
    bic = n * np.log(np.maximum(rss, 1e-300) / n) + np.array([m.n_params for m in models]) * np.log(n)
    cands = []
    described = _descriptions(data, current, fits, modes, {} if known is None else known.setdefault("described", {}))
    for i, (name, (grown, params, intervals, size, evidence)) in enumerate(zip(order, described), start=1):
        fit = fits[name]
        kind = "order" if grown else "map" if name in MAP_NAMES else "effect"
        entry = {"effect": name, "kind": kind, "rmse": float(np.sqrt(rss[i] / n)),
                 "delta_bic": float(bic[i] - bic[0]), "params": jsonable(params, finite=True),
                 "evidence": evidence, "train_rmse": float(fit.rmse),
                 "share": _share(current, fit), "extra_params": int(fit.n_params - current.n_params),
                 "effect_rms": float(size) if np.isfinite(size) else 0.0, "fitted": True, "intervals": intervals}
        notes = [plan.notes[name]] if name in plan.notes else []
        if i in refits:
            notes.append(_refit_note(refits[i], min(n_folds, data.n_records)))
        if notes:
            entry["note"] = "; ".join(notes)
        cands.append(entry)
    cur_rmse = float(np.sqrt(rss[0] / n))
    for name in plan.skipped:  # not fitted: absorbed by the rest levels, so its fit is the current model's
        extra = len(FITTED_PARAMETERS[name])
        cands.append({"effect": name, "kind": "effect", "rmse": cur_rmse, "delta_bic": float(extra * np.log(n)),
                      "params": {},
                      "evidence": f"not fitted: {plan.notes[name]}", "train_rmse": float(current.rmse), "share": 0.0,
                      "extra_params": extra, "effect_rms": 0.0, "note": plan.notes[name], "fitted": False})
    cands.sort(key=lambda c: c["delta_bic"])
    floor = noise.rmse
    for c in cands:
        c["verdict"] = _failed_rule(c, cur_rmse, current.rmse, floor, data.n_records, bic_margin, min_gain,
                                    noise_gain) or "passes"
    good = _physics_first(_by_share([c for c in cands if c["verdict"] == "passes"]))
    cands = good + [c for c in cands if c not in good]
    best = good[0]["effect"] if good else None
    if good:
        good[0]["verdict"] = "selected"
    pairs = []
    for i, a in enumerate(good):
        for b in good[i + 1 :]:
            if abs(a["delta_bic"] - b["delta_bic"]) < max(bic_margin, 0.002 * abs(a["delta_bic"])) and \
                    abs(a["rmse"] - b["rmse"]) < 0.01 * a["rmse"]:
                pairs.append([a["effect"], b["effect"]])
    suggestion = separating_experiment(*pairs[0]) if pairs else None
    # effects the data cannot show for the same reason cannot be told apart either (e.g. every friction
    # law without a speed reversal is a constant load); the experiment that shows them comes first
    blind = [u["effect"] for u in plan.unobservable]
    blind_pairs = [[a, b] for i, a in enumerate(blind) for b in blind[i + 1 :] if plan.notes[a] == plan.notes[b]]
    if blind_pairs and suggestion is None:
        suggestion = REVEALING_EXPERIMENTS.get(blind_pairs[0][0], separating_experiment(*blind_pairs[0]))
    return Ranking(cands, best, cur_rmse, validation, pairs + blind_pairs, suggestion)


#: How :func:`rank` orders its candidates, in the words of the printout (the ``verdict`` and ``delta_bic`` columns).
ORDER_RULE = ("order: the candidates that pass every rule first (verdict 'selected', then 'passes'; effects of the "
              "catalogue before static maps and grown orders, each by delta BIC, except that one explaining a much "
              "larger share of the residual moves ahead, and a map ahead of an effect only where it explains and "
              "predicts clearly more), then the rest by delta BIC (lowest first)")


def _failed_rule(c: dict, cur_heldout: float, cur_train: float, floor: float | None, n_records: int,
                 bic_margin: float, min_gain: float, noise_gain: float) -> str | None:
    """The first rule of :func:`rank` that candidate ``c`` fails, in words (None: it passes them all)."""
    if not c.get("fitted", True):
        return "not fitted"
    if not c["delta_bic"] < -bic_margin:
        return f"delta BIC not below -{bic_margin:g}"
    if not c["rmse"] < (1.0 - min_gain) * cur_heldout:
        return f"held-out gain under {100 * min_gain:g} %"
    if floor is not None and cur_heldout - c["rmse"] < noise_gain * floor:
        return f"held-out gain under {100 * noise_gain:g} % of the noise floor"
    if not c["train_rmse"] < cur_train:
        return "fits all data worse than the current model"
    if not c["effect_rms"] >= 0.2 * np.sqrt(max(cur_train**2 - c["train_rmse"] ** 2, 0.0)):
        return "its effect is too small for the error it removes"
    if n_records < 2 and c["kind"] == "order":
        return "no order grown on one record's training error"
    damping = (c.get("params") or {}).get("damping") if c["effect"] == "pole_pair" else None
    if damping is not None and not is_resonance(damping):  # a grown pair named a mode must be one
        low, high = RESONANCE_DAMPING
        return f"its mode is no resonance (damping {damping:.2g} outside {low:g}..{high:g})"
    return None


def _refit_note(refitted: list, n_folds: int) -> str:
    """The ranking's note on a candidate whose failed fold refits were predicted from its all-data parameters."""
    folds = ", ".join(str(f + 1) for f, *_ in refitted)
    worst = max(refitted, key=lambda r: r[1])
    return (f"held-out fold{'s' if len(refitted) > 1 else ''} {folds} of {n_folds} refitted from the all-data "
            f"parameters: the fold refit failed (held-out RMSE {worst[1]:.3g} against {worst[3]:.3g} for the current "
            f"model; {worst[2]:.3g} from the all-data parameters)")


def _descriptions(data: Batch, current: GreyFit, fits: dict, modes: tuple | None, known: dict) -> list[tuple]:
    """:func:`_described` of each of ``fits`` (in their order), those of ``known`` (``{id(fit): (fit, description)}``,
    filled in place) taken from there."""
    todo = [name for name, fit in fits.items() if known.get(id(fit), (None,))[0] is not fit]
    pieces = [(data, current, fits[name], name, modes) for name in todo]
    for name, text in zip(todo, map_independent(_described, pieces)):
        known[id(fits[name])] = (fits[name], text)
    return [known[id(fit)][1] for fit in fits.values()]


def _described(data: Batch, current: GreyFit, fit: GreyFit, name: str, modes: tuple | None = None) -> tuple:
    """``(grown, params, intervals, effect_rms, evidence)`` of candidate ``name`` fitted as ``fit``: whether it grows
    the linear part, its parameters with their intervals, the RMS its effect itself makes (or, for a grown
    order, the change of the output) and the evidence in words (``modes``: the plant's modes in the residual of
    ``current``). Each candidate's apart from the others' (in the worker processes of
    :func:`agents.twin.workers.worker_processes`)."""
    grown = fit.spec.n_linear != current.spec.n_linear  # an order candidate
    if grown:
        change = order_change(name, current, fit)
        params = {key: value["value"] for key, value in change.items()}
        intervals = {key: {**value, "std": "n/a"} for key, value in change.items()}
        size = rmse(output_error(fit.y_sim, current.y_sim, data.mask, fit.spec, data.closed_loop), mask=data.mask)
    elif name in MAP_NAMES:
        params = {key: value for key, value in fit.effect_params[name].items() if not isinstance(value, str)}
        return False, params, effect_intervals(data, fit, name), map_size(data, fit, name), \
            map_evidence(name, data, current, fit)
    else:
        params = fit.effect_params.get(name, {})
        intervals, size = effect_intervals(data, fit, name), effect_size(data, fit)
    return grown, params, intervals, size, effect_evidence(name, data, current, fit, modes)


def _share(current: GreyFit, fit: GreyFit) -> float:
    """Share of the current model's residual power (its training RMSE squared) that ``fit`` explains, in %."""
    return float(100.0 * max(0.0, 1.0 - fit.rmse**2 / max(current.rmse**2, 1e-300)))


def _by_share(good: list[dict]) -> list[dict]:
    """``good`` (ordered by ``delta_bic``) with each candidate moved ahead of those it clearly out-explains.

    ``b`` goes before ``a`` when ``b`` explains at least :data:`SHARE_POINTS` percentage points and
    :data:`SHARE_RATIO` times more of the residual power, unless ``a``'s held-out RMSE is lower than
    ``b``'s by :data:`CLEAR_HELDOUT_GAIN`. An insertion that keeps ``delta_bic`` order otherwise.
    """
    out: list[dict] = []
    for b in good:
        pos = len(out)
        while pos > 0:
            a = out[pos - 1]
            explains_more = b["share"] >= a["share"] + SHARE_POINTS and b["share"] >= SHARE_RATIO * a["share"]
            clearly_better = a["rmse"] < (1.0 - CLEAR_HELDOUT_GAIN) * b["rmse"]
            if explains_more and not clearly_better:
                pos -= 1
            else:
                break
        out.insert(pos, b)
    return out


def _physics_first(good: list[dict]) -> list[dict]:
    """The good catalogue effects first, then the good static maps, then the good grown orders, each in the order
    of ``good``; a map goes ahead of an effect only where it clearly explains and predicts more (:func:`_map_ahead`).

    A grown order of the linear part is the fallback for what no effect of the catalogue explains: an extra
    pole pair mimics a friction's lag or a limit's slowing and names no physics, and a rung of the ladder
    spent on it can block the effects. On LinearMotor-v0 with Coulomb friction (guided BO's first 4
    records), a pole pair 8 % ahead held out took the first rung; saturation, then backlash followed, to a
    held-out RMSE of 1.6e-5 m, where saturation then Coulomb friction reach 2.9e-6 m. A static map
    (:mod:`agents.twin.static_map`) names no physics either, but it is not a fallback for the catalogue's
    limits and bands, which it can mimic with its breakpoints: where an effect explains about as much,
    the effect is named.
    """
    out = [c for c in good if c["kind"] == "effect"]
    for m in (c for c in good if c["kind"] == "map"):
        held = [j for j, c in enumerate(out) if c["kind"] == "effect" and not _map_ahead(m, c)]
        pos = held[-1] + 1 if held else 0  # after the last effect it does not clearly beat
        while pos < len(out) and out[pos]["kind"] == "map":  # and after the maps placed before it
            pos += 1
        out.insert(pos, m)
    return out + [c for c in good if c["kind"] == "order"]


def _map_ahead(m: dict, e: dict) -> bool:
    """Whether static map ``m`` goes before catalogue effect ``e``: it explains at least :data:`SHARE_POINTS`
    percentage points more of the residual power and its held-out RMSE is lower by :data:`CLEAR_HELDOUT_GAIN`."""
    return m["share"] >= e["share"] + SHARE_POINTS and m["rmse"] < (1.0 - CLEAR_HELDOUT_GAIN) * e["rmse"]
