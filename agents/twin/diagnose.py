"""Diagnose the missing effect: every catalogued effect tried as an addition, ranked on held-out experiments.

* :func:`diagnose`: the ranking (held-out RMSE, delta BIC), evidence and indistinguishable pairs;
* :func:`heldout_rss`: cross-validation over experiments;
* :func:`error_ladder`: add the best effect, diagnose again, until nothing helps.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from agents.jsonable import jsonable
from agents.run_display import progress_bar
from agents.thread_limits import single_thread
from agents.twin.compare import compare
from agents.twin.evidence import (
    REVEALING_EXPERIMENTS,
    effect_evidence,
    excitation_notes,
    separating_experiment,
    unobservable_effects,
)
from agents.twin.fidelity import rmse
from agents.twin.fitting import (
    candidate_problems,
    effect_bounds,
    effect_offset,
    make_problem,
    refine_grid_parameters,
)
from agents.twin.greybox import (
    FITTED_PARAMETERS,
    GreyData,
    GreyFit,
    ModelSpec,
    Problem,
    fit_problems,
    output_error,
    simulate_sets,
)
from agents.twin.greybox_twin import GreyBoxTwin
from agents.twin.ladder_text import rung_text
from agents.twin.noise_floor import NOISE_FLOOR_LABELS, noise_floor_estimate
from agents.twin.uncertainty import parameter_intervals
from gbo_envs.physics.effects import EFFECT_NAMES, EFFECTS, describe_effect

#: Folds of the cross-validation over experiments when none are given (fewer with fewer experiments).
DEFAULT_FOLDS = 4
#: Trial points of the refit of a fold's rest levels and biases with an effect parameter put back at its
#: full-data value (:func:`_keep_undetermined`).
NUISANCE_REFIT_ITER = 6

__all__ = ["Diagnosis", "diagnose", "effect_intervals", "error_ladder", "heldout_rss"]


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """Ranking of the catalogued effects as additions to a model; see :func:`diagnose`.

    ``fits`` maps each effect to the fitted model with it added; ``current`` is the model diagnosed.
    ``unobservable`` lists the effects the data cannot show (``{"effect", "reason", "experiment"}``:
    why, and the experiment that would show them); ``noise_method`` says how ``noise_rmse`` was
    estimated (:func:`agents.twin.noise_floor.noise_floor_method`).
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
    unobservable: list = field(default_factory=list)
    noise_method: str = "none"
    data_: GreyData | None = field(default=None, repr=False)

    def step(self, name: str, units: Mapping[str, str] | None = None) -> dict:
        """The ladder rung of adding candidate ``name`` to the current model (see :func:`error_ladder`).

        RMSE and fit % are those of the fits to all data (``rmse``, ``fit_percent``), before and after.
        """
        fit = self.fits[name]
        rung = {"model": fit.spec.label, "added": name, "rmse": float(fit.rmse),
                "fit_percent": float(compare(self.data_, fit).fit_percent_all),
                "params": jsonable(fit.effect_params, finite=True)}
        before = {"model": self.current.spec.label, "rmse": float(self.current.rmse),
                  "fit_percent": float(self.fit_percent)}
        intervals = next(c["intervals"] for c in self.candidates if c["effect"] == name)
        return _as_step(rung, before, name, intervals, units, fit.spec.output)

    @property
    def noise_label(self) -> str:
        """What the noise floor is, in words (:data:`agents.twin.noise_floor.NOISE_FLOOR_LABELS`)."""
        return NOISE_FLOOR_LABELS[self.noise_method]

    def to_dict(self) -> dict:
        """The ``diagnose --json`` object."""
        return {"model": self.current.spec.label, "rmse": float(self.current.rmse),
                "fit_percent": float(self.fit_percent), "noise_rmse": self.noise_rmse,
                "noise_floor": {"rmse": self.noise_rmse, "method": self.noise_method, "label": self.noise_label},
                "best": self.best, "candidates": self.candidates, "heldout_rmse": float(self.heldout_rmse),
                "validation": self.validation, "indistinguishable": self.indistinguishable,
                "suggested_experiment": self.suggested_experiment, "unobservable": self.unobservable,
                "current_params": jsonable(self.current.effect_params, finite=True)}


def _variants(name: str, spec: ModelSpec) -> list[dict]:
    if name == "drift":
        dens = [f"den{i}" for i in range(1, spec.n_poles - spec.n_integrators + 1)]
        return [{"parameter": p} for p in ["gain", *dens]]
    return [{}]


def _validated_folds(n_folds, n_records: int) -> int:
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


def _folds(data: GreyData, n_folds: int) -> list[np.ndarray]:
    order = np.argsort(data.index, kind="stable")
    k = min(n_folds, data.n_records)
    return [order[i::k] for i in range(k)]


def _refit_problem(data: GreyData, fit: GreyFit, rows: np.ndarray, free_global: bool, theta=None, y0=None,
                   bias=None, tag=None) -> Problem:
    rows = np.asarray(rows, dtype=int)
    n_eff = fit.theta.size - fit.spec.n_linear - 1
    lower, upper, scale = effect_bounds(data, fit, np.full(n_eff, -np.inf), np.full(n_eff, np.inf),
                                                 np.ones(n_eff))
    return make_problem(data, fit.spec, fit.theta if theta is None else theta,
                    fit.y0[rows] if y0 is None else y0, fit.bias[rows] if bias is None else bias, rows,
                    lower, upper, scale, free_global=free_global, tag=tag)


def _grey_box(effects, spec: ModelSpec | None, max_iter: int = 25) -> GreyBoxTwin:
    """The grey-box twin of ``spec``'s linear part (default 2 poles, no zero) plus ``effects``."""
    spec = ModelSpec() if spec is None else spec
    return GreyBoxTwin(effects=() if effects is None else effects, n_poles=spec.n_poles, n_zeros=spec.n_zeros,
                       n_integrators=spec.n_integrators, output=spec.output, max_iter=max_iter)


def heldout_rss(data: GreyData, fits: Sequence[GreyFit], n_folds: int = 4, max_iter: int = 6) -> np.ndarray:
    """Held-out residual sum of squares of each model, cross-validated over experiments.

    Each fold's experiments are left out, every model is refitted on the others
    (from its full-data fit), and its global parameters are then applied to the
    left-out experiments with only their rest levels and biases fitted. An effect
    parameter that the fold's experiments do not determine keeps its full-data value
    (:func:`_keep_undetermined`).

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
    _keep_undetermined(data, train, fits)
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





@single_thread()
def diagnose(data: GreyData, effects=None, candidates: Sequence[str] | None = None, spec: ModelSpec | None = None,
             current: GreyFit | None = None, n_folds: int | None = None, bic_margin: float = 10.0,
             min_gain: float = 0.02, max_iter: int = 20, *, noise_gain: float = 0.05, skip_unexcited: bool = True,
             screen_iter: int = 8, progress: bool | None = False, _restarts: int = 0, _starts: dict | None = None,
             _nested: bool = False) -> Diagnosis:
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
    n_folds : int, optional
        Folds of the cross-validation over experiments, from 2 to the number of
        experiments (default: 4, or one per experiment when there are fewer).
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
        Trial points of the full-data least-squares fits (:func:`agents.twin.greybox.fit_problems`).
    noise_gain : float, default 0.05
        ``best`` also needs its held-out RMSE at least ``noise_gain`` times the
        measurement noise floor (:func:`agents.twin.noise_floor.noise_floor`) below
        the current model's: a gain far below what the measurement resolves is not
        evidence (on noise-free data the linear model's error is far below the
        floor, and an effect would otherwise be credited with fitting that error).
    skip_unexcited : bool, default True
        Do not fit the effects the data cannot show (:func:`agents.twin.evidence.excitation_notes`:
        friction, stiction and backlash without a speed reversal, a dead zone without a
        zero crossing of the input, drift in one experiment, a constant offset always).
        They stay in ``candidates`` with their ``note``, ``"fitted": False``, no entry in
        ``fits``, the current model's errors (the effect is absorbed by the rest levels
        and biases, so its fit is the current model's) and a ``delta_bic`` of its extra
        parameters' penalty alone.
    screen_iter : int, default 8
        Trial points after which a candidate whose cost is not below the current
        model's (fitted with all ``max_iter``) stops: it cannot pass the decision rule
        below without beating the current model. The candidates ahead of it are
        fitted again from their starts with all ``max_iter`` trial points.
    progress : bool or None, default False
        A progress bar on stderr over the steps (each candidate's starts, the fits, the
        cross-validation); ``None``: only when stderr is a terminal.

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
    better fit of parameters the model already has (each candidate then starts
    from its fit of the first round). With one experiment there is nothing to hold
    out: the training RSS is used and ``validation`` says so. An effect that only
    one experiment shows cannot be credited by cross-validation over experiments:
    the fold that leaves that experiment out refits the effect's parameters on data
    that do not show them, and its held-out error is the linear model's or worse.
    Record the effect in at least two experiments (e.g. two slow loops through a
    dead band).

    Decision rule: ``best`` is the candidate with the lowest ``delta_bic`` among
    those with ``delta_bic < -bic_margin``, a held-out RMSE below ``(1 - min_gain)``
    times the current model's and at least ``noise_gain`` times the noise floor
    below it, and an ``effect_rms`` of at least a fifth of the RMS it explains;
    ``None`` when no candidate passes. The noise floor from second differences
    overestimates the noise of smooth noise-free data (the response's own
    curvature), which only makes the noise rule stricter there; a quantized
    output without noise uses ``q / sqrt(12)``.
    """
    n_folds = _validated_folds(n_folds, data.n_records)
    if not np.isfinite(noise_gain) or noise_gain < 0.0:
        raise ValueError(f"noise_gain: must be a finite number >= 0, got {noise_gain}")
    if int(screen_iter) < 1:
        raise ValueError(f"screen_iter: must be an integer >= 1, got {screen_iter}")
    if current is None:
        current = _grey_box(effects, spec, max_iter).fit(data).greybox_
    names = [n for n in (candidates or EFFECT_NAMES) if n not in current.spec.effect_names]
    notes = excitation_notes(data, current.spec.output)
    unobservable = unobservable_effects({n: notes[n] for n in names if n in notes})
    skipped = [n for n in names if n in notes] if skip_unexcited else []
    names = [n for n in names if n not in skipped]
    bar = progress_bar(len(names) + 3, f"diagnose {current.spec.label}" + (" (restart)" if _restarts else ""),
                       progress, unit="step", leave=not _nested)
    try:
        return _diagnose(data, current, names, skipped, notes, unobservable, bar, candidates=candidates,
                         n_folds=n_folds, bic_margin=bic_margin, min_gain=min_gain, max_iter=max_iter,
                         noise_gain=noise_gain, skip_unexcited=skip_unexcited, screen_iter=screen_iter,
                         progress=progress, _restarts=_restarts, _starts=_starts, _nested=_nested)
    finally:
        bar.close()


def _diagnose(data: GreyData, current: GreyFit, names: list, skipped: list, notes: dict, unobservable: list, bar,
              *, candidates, n_folds, bic_margin, min_gain, max_iter, noise_gain, skip_unexcited, screen_iter,
              progress, _restarts, _starts, _nested) -> Diagnosis:
    """The body of :func:`diagnose` once the current model is fitted; ``bar`` counts its steps."""
    # the current model gets the same iteration budget as the candidates that can win, so that no candidate
    # wins by merely polishing parameters the current model already has
    problems = [_refit_problem(data, current, np.arange(data.n_records), True, tag="__current__")]
    for name in names:
        if _starts and name in _starts:  # a restart: the candidate's fit of the first round is its start
            problems.append(_refit_problem(data, _starts[name], np.arange(data.n_records), True, tag=name))
        else:
            bar.set_postfix_str(f"starts of {name}")
            for options in _variants(name, current.spec):
                problems += candidate_problems(data, current, name, options, tag=name)
        bar.update(1)
    bar.set_postfix_str(f"fitting {len(names)} candidates")
    _screened_fit(data, problems, max_iter, screen_iter)
    bar.update(1)
    bar.set_postfix_str("refining the grid parameters")
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
        bar.close()
        # one experiment has no folds to pass on (its validated default stands for none)
        folds = n_folds if data.n_records >= 2 else None
        return diagnose(data, candidates=candidates, current=restart, n_folds=folds, bic_margin=bic_margin,
                        min_gain=min_gain, max_iter=max_iter, noise_gain=noise_gain,
                        skip_unexcited=skip_unexcited, screen_iter=screen_iter, progress=progress,
                        _restarts=_restarts + 1, _starts=fits, _nested=_nested)
    bar.update(1)
    order = list(fits)
    models = [current] + [fits[name] for name in order]
    n = data.n_samples
    bar.set_postfix_str("cross-validation over experiments")
    if data.n_records >= 2:
        rss = heldout_rss(data, models, n_folds=n_folds)
        validation = f"held-out: {min(n_folds, data.n_records)}-fold cross-validation over experiments"
    else:
        rss = np.array([m.rmse**2 * n for m in models])
        validation = "training error (one experiment: nothing to hold out)"
    bar.update(1)
    bic = n * np.log(np.maximum(rss, 1e-300) / n) + np.array([m.n_params for m in models]) * np.log(n)
    cands = []
    for i, name in enumerate(order, start=1):
        fit = fits[name]
        entry = {"effect": name, "rmse": float(np.sqrt(rss[i] / n)), "delta_bic": float(bic[i] - bic[0]),
                 "params": jsonable(fit.effect_params.get(name, {}), finite=True) if name in fit.effect_params else {},
                 "evidence": effect_evidence(name, data, current, fit), "train_rmse": float(fit.rmse),
                 "extra_params": int(fit.n_params - current.n_params),
                 "effect_rms": _effect_size(data, fit), "fitted": True,
                 "intervals": effect_intervals(data, fit, name)}
        if name in notes:
            entry["note"] = notes[name]
        cands.append(entry)
    cur_rmse = float(np.sqrt(rss[0] / n))
    for name in skipped:  # not fitted: absorbed by the rest levels, so its fit is the current model's
        extra = len(FITTED_PARAMETERS[name])
        cands.append({"effect": name, "rmse": cur_rmse, "delta_bic": float(extra * np.log(n)), "params": {},
                      "evidence": f"not fitted: {notes[name]}", "train_rmse": float(current.rmse),
                      "extra_params": extra, "effect_rms": 0.0, "note": notes[name], "fitted": False})
    cands.sort(key=lambda c: c["delta_bic"])
    noise, noise_method = noise_floor_estimate(data)
    # an improvement counts if it passes BIC, lowers the held-out error by min_gain, and comes from the
    # effect itself: switching the effect off must move the output by a fifth of what the effect explains
    # and the gain must be resolvable by the measurement: at least noise_gain times its noise floor
    good = [c for c in cands if c["delta_bic"] < -bic_margin and c["rmse"] < (1.0 - min_gain) * cur_rmse
            and (noise is None or cur_rmse - c["rmse"] >= noise_gain * noise)
            and c["effect_rms"] >= 0.2 * np.sqrt(max(current.rmse**2 - c["train_rmse"] ** 2, 0.0))]
    best = good[0]["effect"] if good else None
    pairs = []
    for i, a in enumerate(good):
        for b in good[i + 1 :]:
            if abs(a["delta_bic"] - b["delta_bic"]) < max(bic_margin, 0.002 * abs(a["delta_bic"])) and \
                    abs(a["rmse"] - b["rmse"]) < 0.01 * a["rmse"]:
                pairs.append([a["effect"], b["effect"]])
    suggestion = separating_experiment(*pairs[0]) if pairs else None
    # effects the data cannot show for the same reason cannot be told apart either (e.g. every friction
    # law without a speed reversal is a constant load); the experiment that shows them comes first
    blind = [u["effect"] for u in unobservable]
    blind_pairs = [[a, b] for i, a in enumerate(blind) for b in blind[i + 1 :] if notes[a] == notes[b]]
    if blind_pairs and suggestion is None:
        suggestion = REVEALING_EXPERIMENTS.get(blind_pairs[0][0], separating_experiment(*blind_pairs[0]))
    return Diagnosis(current, fits, cands, best, noise, compare(data, current).fit_percent_all, cur_rmse,
                     validation, pairs + blind_pairs, suggestion, unobservable, noise_method, data)


def effect_intervals(data: GreyData, fit: GreyFit, name: str, level: float = 0.95) -> dict[str, dict]:
    """Value, standard error, ``level`` confidence interval and unit of each fitted parameter of effect ``name``.

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
    out = {}
    for param, value in fit.effect_params.get(name, {}).items():
        if isinstance(value, str):
            continue
        ci = intervals.get(f"{name}.{param}", {"value": value, "std": None, "low": None, "high": None})
        out[param] = {**jsonable(ci, finite=True), "unit": units.get(param, "")}
    return out


@single_thread()
def _effect_size(data: GreyData, fit: GreyFit) -> float:
    """RMS change of the output when the last effect of ``fit`` is switched off (its magnitude at zero).

    The plant output before the sensor blocks, or the measurement for a sensor effect.
    """
    name = fit.spec.effect_names[-1]
    theta0 = fit.theta.copy()
    pos = fit.spec.n_linear + 1 + effect_offset(fit.spec, name) if fit.spec.effect_names.count(name) == 1 else \
        fit.theta.size - len(FITTED_PARAMETERS[name])
    cls = EFFECTS[name]
    for j, (pname, _) in enumerate(FITTED_PARAMETERS[name]):
        if pname == cls.magnitude_param:
            theta0[pos + j] = next(p.zero for p in cls.parameters if p.name == pname)
    rows = np.arange(data.n_records)
    sims = simulate_sets(data, [(fit.spec, np.concatenate([th, fit.y0, fit.bias]), rows) for th in (fit.theta, theta0)],
                         true_output=cls.side != "sensor")  # a sensor effect only shows in the measurement
    size = rmse(output_error(sims[0], sims[1], data.mask, fit.spec), mask=data.mask)  # in the fit's error
    return size if np.isfinite(size) else 0.0


def _screened_fit(data: GreyData, problems: list[Problem], max_iter: int, screen_iter: int) -> None:
    """Fit the current model (``problems[0]``, ``max_iter`` trial points) and the candidates (``screen_iter``).

    The candidates whose cost is then below the current model's are fitted again
    from their starts with all ``max_iter`` trial points (the same fit as without
    the screen), in place in ``problems``.
    """
    if max_iter <= screen_iter:
        fit_problems(data, problems, max_iter=max_iter)
        return
    starts = [replace(p) for p in problems]
    fit_problems(data, problems, budgets=[max_iter] + [screen_iter] * (len(problems) - 1))
    ahead = [i for i in range(1, len(problems)) if problems[i].cost < problems[0].cost]
    for i in ahead:
        problems[i] = starts[i]
    if ahead:
        fit_problems(data, [problems[i] for i in ahead], max_iter=max_iter)


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
        problem = make_problem(data, current.spec, theta, fit.y0, fit.bias, np.arange(data.n_records),
                               free_global=False)
        problem.free[:] = False
        fit_problems(data, [problem], max_iter=0)
        reduced = GreyFit.from_problem(data, problem)
        if reduced.rmse < current.rmse * (1.0 - 1e-3) and (best is None or reduced.rmse < best.rmse):
            best = reduced
    return best


def _as_step(rung: dict, before: dict, added: str, intervals: dict, units, output: str) -> dict:
    """``rung`` with what adding ``added`` changed: ``before``, the RMSE's fall in % and as a factor,
    the added parameters with their intervals, and the step in words."""
    rung = {**rung, "added": added, "before": before,
            "rmse_fall_percent": 100.0 * (1.0 - rung["rmse"] / before["rmse"]),
            "rmse_factor": before["rmse"] / rung["rmse"] if rung["rmse"] > 0 else float("inf"),
            "added_params": intervals}
    rung["text"] = rung_text(rung, units, output)
    return rung


def _keep_undetermined(data: GreyData, train: list[Problem], fits: Sequence[GreyFit]) -> None:
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


def error_ladder(data: GreyData, effects=None, spec: ModelSpec | None = None, max_steps: int = 3,
                 progress: bool | None = False, units: Mapping[str, str] | None = None,
                 **kwargs) -> tuple[list[dict], list[Diagnosis]]:
    """RMSE of the linear model, then with the best effect added, then the next, until nothing helps.

    Parameters
    ----------
    data : GreyData
    effects : names or ``{name: {parameter: value}}``, optional
        Effects of the first model (default: the linear model alone).
    spec : ModelSpec, optional
    max_steps : int, default 3
        Effects added at most.
    progress : bool or None, default False
        Progress bars on stderr (the rungs, and each diagnosis nested in it); ``None``: only on a terminal.
    units : mapping, optional
        ``{"y": ..., "u": ...}``, the units of the output and input, for the ``text`` of each rung.
    **kwargs
        Passed to :func:`diagnose`.

    Returns
    -------
    rungs : list of dict
        Per rung: ``"model", "added", "rmse", "fit_percent", "heldout_rmse", "params"``; from the
        second rung on also ``"before"`` (the previous rung's ``model, rmse, fit_percent,
        heldout_rmse``), ``"rmse_fall_percent"`` (``100 (1 - rmse / before rmse)``), ``"rmse_factor"``
        (``before rmse / rmse``) and ``"added_params"`` (the added effect's parameters with
        their standard errors, 95 % intervals and units, :func:`effect_intervals`); and ``"text"``,
        the rung in words (:func:`agents.twin.ladder_text.rung_text`). RMSE and fit % are those of
        the fit to all data, in units of ``y`` and %.
    diagnoses : list of Diagnosis
        The diagnosis made at each rung.
    """
    current = _grey_box(effects, spec).fit(data).greybox_
    rungs, diagnoses = [], []
    added = None
    bar = progress_bar(max_steps + 1, "error ladder", progress, unit="rung")
    try:
        for _ in range(max_steps + 1):
            bar.set_postfix_str(current.spec.label)
            d = diagnose(data, current=current, progress=progress, _nested=True, **kwargs)
            diagnoses.append(d)
            rung = {"model": d.current.spec.label, "added": added, "rmse": float(d.current.rmse),
                    "fit_percent": float(d.fit_percent), "heldout_rmse": float(d.heldout_rmse),
                    "params": jsonable(d.current.effect_params, finite=True)}
            if rungs:
                before = {key: rungs[-1][key] for key in ("model", "rmse", "fit_percent", "heldout_rmse")}
                intervals = next(c["intervals"] for c in diagnoses[-2].candidates if c["effect"] == added)
                rung = _as_step(rung, before, added, intervals, units, d.current.spec.output)
            else:
                rung["text"] = rung_text(rung, units, d.current.spec.output)
            rungs.append(rung)
            bar.update(1)
            if d.best is None or len(rungs) > max_steps:
                bar.total = len(rungs)  # nothing more to add: the ladder is complete
                bar.refresh()
                break
            added, current = d.best, d.fits[d.best]
    finally:
        bar.close()
    return rungs, diagnoses
