"""Fits of model structures: a given structure (:func:`fit_model`) and the candidates of a diagnosis.

The pipeline's fourth stage (records, linear fit, candidates, **fits**, ranking, report).
Every fit is a bounded least-squares problem of the simulation error
(:mod:`agents.twin.least_squares`), each solved alone; the problems of the candidates, which do not
depend on one another, go to the worker processes of :mod:`agents.twin.workers` where a caller opened them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from agents.thread_limits import single_thread
from agents.twin.candidates import (
    CandidatePlan,
    candidate_problems,
    effect_bounds,
    forward_bias,
    read_modes,
    refit_problem,
)
from agents.twin.guesses import quantization_scan
from agents.twin.least_squares import Problem, fit_problems, make_problem
from agents.twin.linear_fit import linear_fit, profile
from agents.twin.model import GreyFit, ModelSpec, effect_items, effect_offset, fitted_parameters
from agents.twin.modes import plant_modes
from agents.twin.noise_floor import quantization_step
from agents.twin.record_checks import check_fit_size
from agents.twin.records import Batch
from agents.twin.simulation import simulate_sets
from agents.twin.static_map import MAP_NAMES, map_options
from agents.twin.workers import map_independent

__all__ = ["GIVEN_VALUES_MAX_ITER", "CandidateFits", "CandidateRound", "fit_candidates", "fit_model", "fit_structure",
           "first_round", "refine_grid_parameters"]

#: Trial points at most of the least-squares refit from complete given effect values (:func:`fit_structure`).
GIVEN_VALUES_MAX_ITER = 20


@single_thread()
def fit_structure(data: Batch, effects=None, spec: ModelSpec | None = None, max_iter: int = 25) -> GreyFit:
    """The model of a given structure fitted to ``data``: the linear part (:func:`linear_fit`) with ``effects`` added.

    Parameters
    ----------
    data : Batch
    effects : names, comma-separated str or ``{name: {parameter: value}}``, optional
        Catalogue effects or static maps (a map without breakpoints takes the data's,
        :func:`agents.twin.static_map.map_options`). When every fitted parameter of every effect is
        given, the linear part is profiled at those values and everything refitted from there (at most
        ``min(max_iter, GIVEN_VALUES_MAX_ITER)`` trial points); otherwise the effects are added one at a
        time from their data-based starts (:func:`fit_model`).
    spec : ModelSpec, optional
        Orders and output kind of the linear part (its effects are ignored); default 2 poles, no zero.
    max_iter : int, default 25
        Trial points of the least-squares fits.
    """
    spec = ModelSpec() if spec is None else ModelSpec(spec.n_poles, spec.n_zeros, spec.n_integrators, spec.output)
    items = [(name, map_options(name, data) | given if name in MAP_NAMES else given)  # a map's breakpoints: the data's
             for name, given in effect_items(effects)]
    effects = dict(items)
    check_fit_size(data, spec, sum(len(fitted_parameters(name, given)) for name, given in items))
    base = linear_fit(data, spec)
    if items and all(all(p in given for p, _ in fitted_parameters(name, given)) for name, given in items):
        return _fit_from_given_values(data, spec, items, base, max_iter)
    return fit_model(data, effects, base=base, max_iter=max_iter)


def _fit_from_given_values(data: Batch, spec: ModelSpec, items, base: GreyFit, max_iter: int) -> GreyFit:
    """All effect values given: the linear part profiled at them, then everything refitted from there."""
    for name, given in items:
        options = {k: v for k, v in given.items() if k not in dict(fitted_parameters(name, given))}
        spec = spec.with_effect(name, options)
    values = [float(given[p]) for name, given in items for p, _ in fitted_parameters(name, given)]
    theta = np.concatenate([base.theta, values])
    cost, theta_p, y0, bias = profile(data, spec, theta)  # linear part consistent with the effects
    if np.isfinite(cost):
        theta = theta_p
    else:
        y0, bias = base.y0, forward_bias(data, base, spec, theta)
    n_eff = theta.size - spec.n_linear - 1
    start = GreyFit(spec, theta, spec.plant(theta), spec.blocks(theta), y0, bias, base.y_sim, base.rmse)
    lower, upper, scale = effect_bounds(data, start, np.zeros(n_eff), np.zeros(n_eff), np.zeros(n_eff))
    problem = make_problem(data, spec, theta, y0, bias, np.arange(data.n_records), lower, upper, scale)
    fit_problems(data, [problem], max_iter=min(int(max_iter), GIVEN_VALUES_MAX_ITER))
    return refine_grid_parameters(data, problem.fit(data))


@single_thread()
def fit_model(data: Batch, effects: Sequence | Mapping | None = None, spec: ModelSpec | None = None,
              base: GreyFit | None = None, max_iter: int = 25) -> GreyFit:
    """Grey-box fit of the linear model plus ``effects`` (names, or ``{name: {parameter: value}}`` guesses).

    Effects are added one at a time to the fitted model (each from its
    data-based starts, or from the given values), then all parameters are
    refitted together.
    """
    fit = base if base is not None else linear_fit(data, spec)
    for name, given in effect_items(effects):
        options = {k: v for k, v in given.items() if k not in dict(fitted_parameters(name, given))}
        fitted = dict(fitted_parameters(name, options))
        problems = candidate_problems(data, fit, name, options)
        if any(k in fitted for k in given):
            p = problems[0]
            pos = fit.theta.size
            for j, (pname, _) in enumerate(fitted_parameters(name, options)):
                if pname in given:
                    p.theta[pos + j] = float(np.clip(given[pname], p.lower[pos + j], p.upper[pos + j]))
        fit_problems(data, problems, max_iter=max_iter)
        best = min(problems, key=lambda p: p.cost)
        fit = refine_grid_parameters(data, best.fit(data))
    return fit


def refine_grid_parameters(data: Batch, fit: GreyFit) -> GreyFit:
    """Refine the quantization step of a fit on a fine grid around its value (other parameters fixed).

    Where the output's changes show its resolution (:func:`agents.twin.noise_floor.quantization_step`), the
    step is that resolution and is kept.
    """
    if "quantization" not in fit.spec.effect_names or quantization_step(data.y, data.mask)[0] is not None:
        return fit
    rows = np.arange(data.n_records)
    theta = np.concatenate([fit.theta, fit.nuisance()])
    y_true = simulate_sets(data, [(fit.spec, theta, rows)], true_output=True)[0]
    j = fit.spec.n_linear + 1 + effect_offset(fit.spec, "quantization")
    span = float(np.ptp(data.y[data.mask]))
    steps = quantization_scan(data, fit, span, n_best=1, y_true=y_true)
    best = fit
    for q in steps + [fit.theta[j]]:
        th = fit.theta.copy()
        th[j] = q
        problem = make_problem(data, fit.spec, th, fit.y0, fit.bias, rows, free_global=False, start=fit.start)
        fit_problems(data, [problem], max_iter=0)
        cand = problem.fit(data)
        if cand.rmse < best.rmse:
            best = cand
    return best


@dataclass(frozen=True)
class CandidateFits:
    """The current model and each candidate's fit to all data.

    Attributes
    ----------
    current : GreyFit
        The model diagnosed, refitted with the candidates' iteration budget (or its better
        minimum that a candidate found, see :func:`fit_candidates`).
    fits : dict
        ``{candidate name: GreyFit}`` of the candidates whose fit is finite, in plan order.
    restarted : bool
        Whether the current model was replaced by a better minimum of its own parameters.
    """

    current: GreyFit
    fits: dict
    restarted: bool = False


@dataclass(frozen=True, eq=False)
class CandidateRound:
    """The first round of candidate fits from one model (:func:`first_round`), before any restart.

    Attributes
    ----------
    current : GreyFit
        The model the round started from, refitted with the candidates' iteration budget.
    cost : float
        That refit's cost (sum of squared residuals, units of ``y`` squared): a candidate whose
        screening fit is not below it stops screening (:func:`_screened_fit`).
    fits : dict
        ``{candidate name: GreyFit}`` of the candidates whose fit is finite, in the order fitted.
    """

    current: GreyFit
    cost: float
    fits: dict

    def joined(self, other: CandidateRound, order: Sequence[str]) -> CandidateRound:
        """This round's fits with ``other``'s (a round of other candidates from the same model, refitted
        as this one's: :func:`first_round` with ``polished=self``), in the order of the names ``order``."""
        fits = {**self.fits, **other.fits}
        return CandidateRound(self.current, self.cost, {name: fits[name] for name in order if name in fits})


def first_round(data: Batch, current: GreyFit, candidates: Sequence, modes: tuple | None, max_iter: int = 20,
                screen_iter: int = 8, progress=None, noise: float | None = None,
                polished: CandidateRound | None = None) -> CandidateRound:
    """Fit ``candidates`` to all data from ``current``, and ``current`` itself with the same budget.

    Each candidate starts from its own problems (:meth:`Candidate.problems`; ``modes``: the plant's modes in the
    residual of ``current``) and is screened (:func:`_screened_fit`); among its variants the one of lowest
    training BIC is kept (:func:`_best_variant`). ``polished``: a round from the same ``current`` with the same
    budget, whose refit of ``current`` this round takes instead of fitting it again (the same values: each
    problem is solved alone).
    """
    problems = [] if polished is not None else [refit_problem(data, current, tag="__current__")]
    made = _starting_problems(data, current, list(candidates), progress, modes)
    for candidate in candidates:
        problems += made[candidate.name]
    return _fitted_round(data, current, candidates, problems, max_iter, screen_iter, noise, polished, progress)


def _fitted_round(data: Batch, current: GreyFit, candidates: Sequence, problems: list[Problem], max_iter: int,
                  screen_iter: int, noise: float | None, polished: CandidateRound | None = None,
                  progress=None) -> CandidateRound:
    """The round of ``candidates`` whose starting ``problems`` are made (the refit of ``current`` first, unless
    ``polished`` gives it): screened, fitted and each candidate's best variant kept."""
    if progress is not None:
        progress.set_postfix_str(f"fitting {len(candidates)} candidates")
    if polished is None:
        _screened_fit(data, problems, max_iter, screen_iter)
        cost, refit = problems[0].cost, problems[0].fit(data)
        if refit.rmse < current.rmse:
            current = refine_grid_parameters(data, refit)
        problems = problems[1:]
    else:
        cost, current = polished.cost, polished.current
        _screened_fit(data, problems, max_iter, screen_iter, reference=cost)
    fits = {}
    for candidate in candidates:
        mine = [p for p in problems if p.tag == candidate.name and np.isfinite(p.cost)]
        if mine:
            fits[candidate.name] = refine_grid_parameters(data, _best_variant(data, mine, noise))
    return CandidateRound(current, float(cost), fits)


def fit_candidates(data: Batch, current: GreyFit, plan: CandidatePlan, max_iter: int = 20,
                   screen_iter: int = 8, progress=None, noise: float | None = None,
                   first: CandidateRound | None = None) -> CandidateFits:
    """Fit the current model and every candidate of ``plan`` to all data.

    The current model gets the same iteration budget as the candidates that can win, so
    that no candidate wins by merely polishing parameters the current model already has.
    Each candidate is screened with ``screen_iter`` trial points and refitted with all
    ``max_iter`` when it beats the current model (:func:`_screened_fit`); among a
    candidate's variants the one of lowest training BIC is kept (:func:`_best_variant`).
    A candidate starts from its own profile fit of the linear part, which can land in a
    better minimum than the current model's; if that minimum survives switching the new
    effect off (:func:`_without_new_effect`), the current model is replaced by it and every
    candidate is fitted once more, from its first fit; a candidate without one from its starts at that model
    (the plant's modes in that model's residual, :func:`agents.twin.modes.plant_modes`, scanned once for them).

    Parameters
    ----------
    data : Batch
    current : GreyFit
    plan : CandidatePlan
    max_iter, screen_iter : int
        Trial points of the full and of the screening fits.
    noise : float, optional
        The measurement's noise floor (units of ``y``): a variant's gain must be resolvable.
    progress : tqdm bar, optional
        Advanced once per candidate's starts and once per round of fits.
    first : CandidateRound, optional
        The first round of ``plan``'s candidates from ``current`` (:func:`first_round`), fitted already.
    """
    if first is None:
        first = first_round(data, current, plan.candidates, plan.modes, max_iter, screen_iter, progress, noise)
    better = _without_new_effect(data, first.current, first.fits)
    if better is None:
        return CandidateFits(first.current, first.fits, False)
    # the second round from the better minimum: each candidate from its first fit, one without from its starts
    fresh = [c for c in plan.candidates if c.name not in first.fits]
    modes = tuple(plant_modes(data, better)) if read_modes(c.name for c in fresh) else None
    made = _starting_problems(data, better, fresh, None, modes)
    problems = [refit_problem(data, better, tag="__current__")]
    for candidate in plan.candidates:
        if candidate.name in first.fits:
            problems.append(refit_problem(data, first.fits[candidate.name], tag=candidate.name))
        else:
            problems += made[candidate.name]
    second = _fitted_round(data, better, plan.candidates, problems, max_iter, screen_iter, noise,
                           progress=progress)
    return CandidateFits(second.current, second.fits, True)


def _starting_problems(data: Batch, current: GreyFit, candidates: list, progress=None,
                       modes: tuple | None = None) -> dict[str, list]:
    """``{name: problems}``: each candidate's starting problems (SRIVC profiles, screening simulations), which
    do not depend on one another's (in the worker processes of :func:`agents.twin.workers.worker_processes`);
    ``modes``: the plant's modes in the residual of ``current`` (``None``: scanned by the candidates that need them)."""
    made = {}
    pieces = [(c, data, current, modes) for c in candidates]
    for candidate, problems in zip(candidates, map_independent(_problems_of, pieces)):
        made[candidate.name] = problems
        if progress is not None:
            progress.set_postfix_str(f"starts of {candidate.name}")
            progress.update(1)
    return made


def _problems_of(candidate, data: Batch, current: GreyFit, modes: tuple | None) -> list[Problem]:
    return candidate.problems(data, current, modes=modes)


def _best_variant(data: Batch, problems: list[Problem], floor: float | None = None, margin: float = 10.0,
                  noise_gain: float = 0.05) -> GreyFit:
    """The fit of lowest training BIC, ``n log(RSS / n) + k log n``, among a candidate's problems.

    Variants of one effect differ in their fitted parameters (a Coulomb friction with one level or
    two): a variant with more parameters is kept only when its BIC is lower by ``margin`` ("very
    strong" evidence, as a candidate needs against the current model) and its RMSE lower by
    ``noise_gain`` times the noise ``floor`` (a gain the measurement resolves: with tens of thousands
    of correlated samples, BIC alone credits an asymmetry of a few percent that fits the noise).
    Starts of one variant have the same ``k``, so among them the lowest cost wins.
    """
    n = data.n_samples

    def bic(p: Problem) -> float:
        return n * np.log(max(p.cost, 1e-300) / n) + p.n_global * np.log(n)

    fewest = min(p.n_global for p in problems)
    simplest = min((p for p in problems if p.n_global == fewest), key=bic)
    best = min(problems, key=bic)
    gain = np.sqrt(simplest.cost / n) - np.sqrt(best.cost / n)
    resolved = floor is None or gain >= noise_gain * floor
    return (best if bic(best) < bic(simplest) - margin and resolved else simplest).fit(data)


def _screened_fit(data: Batch, problems: list[Problem], max_iter: int, screen_iter: int,
                  reference: float | None = None) -> None:
    """Fit the current model (``problems[0]``, ``max_iter`` trial points) and the candidates (``screen_iter``).

    The candidates whose cost is then below the current model's go on to all ``max_iter``
    trial points (the same fit as without the screen: the iteration resumes where the screen
    stopped, :func:`agents.twin.trust_region.trf`; one that cannot resume is fitted again from
    its start), in place in ``problems``. ``reference``: the current model's cost, fitted already;
    then every problem is a candidate's.
    """
    first = 0 if reference is not None else 1  # the first candidate's problem
    if max_iter <= screen_iter:
        fit_problems(data, problems, max_iter=max_iter)
        return
    starts = [replace(p) for p in problems]
    fit_problems(data, problems, budgets=[max_iter] * first + [screen_iter] * (len(problems) - first))
    reference = problems[0].cost if reference is None else reference
    ahead = [i for i in range(first, len(problems)) if problems[i].cost < reference]
    for i in ahead:
        if problems[i].solver_state is None:
            problems[i] = starts[i]
    if ahead:
        fit_problems(data, [problems[i] for i in ahead], max_iter=max_iter, resume=True)


def _without_new_effect(data: Batch, current: GreyFit, fits: dict) -> GreyFit | None:
    """The best candidate fit with its new effect switched off, if that beats the current model.

    A candidate starts from its own profile fit of the linear part, which can
    land in a better minimum than the current model's (quantized outputs make
    the error surface rough); whatever of that gain survives switching the
    effect off belongs to the current model.
    """
    best = None
    for fit in fits.values():
        if fit.rmse >= current.rmse * (1.0 - 1e-3) or fit.spec.n_linear != current.spec.n_linear:
            continue  # no gain, or a grown structure (no new effect to switch off)
        n_old = current.theta.size
        theta = fit.theta[:n_old].copy()
        problem = make_problem(data, current.spec, theta, fit.y0, fit.bias, np.arange(data.n_records),
                               free_global=False, start=fit.start)
        problem.free[:] = False
        fit_problems(data, [problem], max_iter=0)
        reduced = problem.fit(data)
        if reduced.rmse < current.rmse * (1.0 - 1e-3) and (best is None or reduced.rmse < best.rmse):
            best = reduced
    return best
