"""Diagnose the missing effect: the workbench's pipeline, top-down.

records (:class:`~agents.twin.records.Batch`, with how each one starts) -> linear fit
(:func:`~agents.twin.linear_fit.linear_fit`, plus the given effects:
:func:`~agents.twin.fits.fit_model`) -> candidates (:func:`~agents.twin.candidates.candidate_plan`)
-> fits (:func:`~agents.twin.fits.fit_candidates`) -> ranking (:func:`~agents.twin.ranking.rank`)
-> report (:class:`Diagnosis`; the ladder of :mod:`agents.twin.ladder`, the words of
:mod:`agents.twin.ladder_text`, the page of :mod:`agents.twin.report`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from agents.jsonable import jsonable
from agents.run_display import progress_bar
from agents.thread_limits import single_thread
from agents.twin.candidates import CandidatePlan, OrderCandidate, candidate_plan, read_modes
from agents.twin.compare import compare
from agents.twin.diagnosis_options import CandidateSearch, DiagnosisRules
from agents.twin.fits import CandidateRound, first_round, fit_candidates, fit_structure
from agents.twin.ladder_text import rung_text
from agents.twin.map_candidates import with_map_candidates
from agents.twin.model import GreyFit, ModelSpec, effect_label
from agents.twin.modes import plant_modes
from agents.twin.noise_floor import NoiseFloor, noise_floor_estimate
from agents.twin.ranking import SHARE_POINTS, Ranking, rank, validated_folds
from agents.twin.records import Batch
from agents.twin.static_map import MAP_NAMES
from agents.twin.workers import check_n_jobs, worker_processes

__all__ = ["Diagnosis", "as_step", "diagnose", "general_needed"]

_RULES, _SEARCH = DiagnosisRules(), CandidateSearch()  # the defaults of diagnose (frozen)


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """Ranking of the catalogued effects as additions to a model; see :func:`diagnose`.

    Attributes
    ----------
    current : GreyFit
        The model diagnosed.
    fits : dict
        ``{effect: GreyFit}``: the current model with each fitted candidate added.
    ranking : Ranking
        The ranked candidates, the best, the held-out error and what cannot be told apart.
    noise : NoiseFloor
        The measurement's noise floor (:func:`agents.twin.noise_floor.noise_floor_estimate`).
    fit_percent : float
        Fit % of the current model on all data (MATLAB's ``compare``).
    unobservable : list of dict
        The effects the data cannot show: ``{"effect", "reason", "experiment"}`` (why, and the
        experiment that would show them).
    modes : tuple of Mode or None
        The plant's modes in the residual of ``current`` (:func:`agents.twin.modes.plant_modes`), scanned once
        where a candidate's evidence names them, else ``None``.
    not_tried : str or None
        Which general structures (static maps, grown orders) were not fitted because none of them could be
        named ahead of the selected effect (:func:`general_needed`), and why; ``None`` when all were.
    """

    current: GreyFit
    fits: dict
    ranking: Ranking
    noise: NoiseFloor
    fit_percent: float
    unobservable: list = field(default_factory=list)
    data_: Batch | None = field(default=None, repr=False)
    modes: tuple | None = field(default=None, repr=False)
    not_tried: str | None = None

    @property
    def candidates(self) -> list[dict]:
        """The ranked candidates, best first (:attr:`Ranking.candidates`)."""
        return self.ranking.candidates

    @property
    def best(self) -> str | None:
        """The candidate the decision rules select, ``None`` when none helps."""
        return self.ranking.best

    @property
    def best_label(self) -> str | None:
        """The best candidate as ``--effects`` names it, with its variant (``"coulomb_friction:smooth"``)."""
        fit = self.fits.get(self.best) if self.best is not None else None
        if fit is None or not fit.spec.effects or fit.spec.effects[-1][0] != self.best:
            return self.best
        return effect_label(*fit.spec.effects[-1])

    @property
    def heldout_rmse(self) -> float:
        """The current model's held-out RMSE, units of ``y``."""
        return self.ranking.heldout_rmse

    @property
    def validation(self) -> str:
        """How the held-out error was taken."""
        return self.ranking.validation

    @property
    def indistinguishable(self) -> list:
        """Pairs of candidates the data cannot tell apart."""
        return self.ranking.indistinguishable

    @property
    def suggested_experiment(self) -> str | None:
        """The experiment that would separate the first indistinguishable pair (or show an unobservable effect)."""
        return self.ranking.suggested_experiment

    @property
    def noise_rmse(self) -> float | None:
        """The noise floor in units of ``y`` (``None`` when not estimable)."""
        return self.noise.rmse

    @property
    def noise_method(self) -> str:
        """How the noise floor was estimated (a key of :data:`agents.twin.noise_floor.NOISE_FLOOR_LABELS`)."""
        return self.noise.method

    @property
    def noise_label(self) -> str:
        """What the noise floor is, in words."""
        return self.noise.label

    def step(self, name: str, units: Mapping[str, str] | None = None) -> dict:
        """The ladder rung of adding candidate ``name`` to the current model (:func:`agents.twin.ladder.error_ladder`).

        RMSE and fit % are those of the fits to all data (``rmse``, ``fit_percent``), before and after.
        """
        fit = self.fits[name]
        rung = {"model": fit.spec.label, "added": name, "rmse": float(fit.rmse),
                "fit_percent": float(compare(self.data_, fit).fit_percent_all),
                "params": jsonable(fit.effect_params, finite=True)}
        before = {"model": self.current.spec.label, "rmse": float(self.current.rmse),
                  "fit_percent": float(self.fit_percent)}
        intervals = next(c["intervals"] for c in self.candidates if c["effect"] == name)
        return as_step(rung, before, name, intervals, units, fit.spec.output)

    def to_dict(self) -> dict:
        """The ``diagnose --json`` object."""
        return {"model": self.current.spec.label, "rmse": float(self.current.rmse),
                "fit_percent": float(self.fit_percent), "noise_rmse": self.noise_rmse,
                "noise_floor": self.noise.to_dict(), "initial": _initial_summary(self.data_),
                "best": self.best, "candidates": self.candidates, "heldout_rmse": float(self.heldout_rmse),
                "validation": self.validation, "indistinguishable": self.indistinguishable,
                "suggested_experiment": self.suggested_experiment, "unobservable": self.unobservable,
                "current_params": jsonable(self.current.effect_params, finite=True), "not_tried": self.not_tried}


@single_thread()
def diagnose(data: Batch, effects=None, *, candidates: Sequence[str] | None = None, spec: ModelSpec | None = None,
             current: GreyFit | None = None, n_folds: int | None = None, rules: DiagnosisRules = _RULES,
             search: CandidateSearch = _SEARCH, progress: bool | None = False, n_jobs: int | None = None,
             _nested: bool = False) -> Diagnosis:
    """Try every catalogued effect as an addition to the model and rank them on held-out experiments.

    Parameters
    ----------
    data : Batch
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
    rules : DiagnosisRules, default DiagnosisRules()
        When an effect is named ``best``: the BIC margin, the held-out gain and the gain over
        the noise floor it needs (:class:`agents.twin.diagnosis_options.DiagnosisRules`).
    search : CandidateSearch, default CandidateSearch()
        Which candidates are tried (the unexcited ones skipped, the linear part's orders grown)
        and the trial points of their fits (:class:`agents.twin.diagnosis_options.CandidateSearch`).
    progress : bool or None, default False
        A progress bar on stderr over the steps (each candidate's starts, the fits, the
        cross-validation); ``None``: only when stderr is a terminal.
    n_jobs : int or None, default None
        Worker processes for the fits that do not depend on one another (the candidates' starts, their
        fits, the cross-validation's refits; :mod:`agents.twin.workers`): ``-1`` all cores; ``None`` the
        active ``joblib.parallel_config`` (one process unless set), as in scikit-learn. The result does
        not depend on it.

    Returns
    -------
    Diagnosis

    Notes
    -----
    Ranking: ``BIC = n log(RSS_cv / n) + k log n`` with ``RSS_cv`` the held-out
    residual sum of squares over all ``n`` samples (cross-validation over
    experiments, :func:`agents.twin.ranking.heldout_rss`) and ``k`` the global parameters;
    ``delta_bic`` is a candidate's BIC minus the current model's, so ``k`` counts the
    extra parameters. The decision rules are those of :func:`agents.twin.ranking.rank`.
    The current model is refitted with the same iteration budget as the candidates, and
    if a candidate's fit with its new effect switched off beats it (a better minimum of
    the current parameters), the candidates are fitted again from that model
    (:func:`agents.twin.fits.fit_candidates`). With one experiment there is nothing to hold
    out: the training RSS is used and ``validation`` says so. An effect that only one
    experiment shows cannot be credited by cross-validation over experiments: the fold
    that leaves that experiment out refits the effect's parameters on data that do not
    show them. Record the effect in at least two experiments.
    """
    n_folds = validated_folds(n_folds, data.n_records)
    check_n_jobs(n_jobs)
    for name, value, kind in (("rules", rules, DiagnosisRules), ("search", search, CandidateSearch)):
        if not isinstance(value, kind):
            raise TypeError(f"{name}: expected a {kind.__name__}, got {value!r}")
    with worker_processes(n_jobs, shared=(data,)):
        # records -> linear fit (and the effects the model already has)
        if current is None:
            current = fit_structure(data, effects, spec, max_iter=search.max_iter)
        # -> candidates
        plan = candidate_plan(data, current, candidates, search.skip_unexcited, search.orders)
        if search.orders and candidates is None:  # the general structures: grown orders and static maps
            plan = with_map_candidates(plan, data, current)
        bar = progress_bar(len(plan.candidates) + 2, f"diagnose {current.spec.label}", progress, unit="step",
                           leave=not _nested)
        try:
            noise = noise_floor_estimate(data)
            general = [c for c in plan.candidates if _is_general(c)] if search.general_as_fallback else []
            # -> fits -> ranking: the catalogue's effects first, the general structures where they can be named
            tried = [c for c in plan.candidates if c not in general]
            first = first_round(data, current, tried, plan.modes, search.max_iter, search.screen_iter, bar,
                                noise.rmse)
            known: dict = {}
            fitted, ranking, modes = _fitted_and_ranked(data, current, replace(plan, candidates=tried), first, noise,
                                                        n_folds, rules, search, bar, known)
            needed = general_needed(ranking, general)
            if needed:
                if bar.total is not None:  # two more steps: the second round's fits and ranking
                    bar.total += 2
                    bar.refresh()
                more = first_round(data, current, needed, plan.modes, search.max_iter, search.screen_iter, bar,
                                   noise.rmse, polished=first)
                tried = [c for c in plan.candidates if c not in general or c in needed]
                first = first.joined(more, [c.name for c in tried])
                fitted, ranking, modes = _fitted_and_ranked(data, current, replace(plan, candidates=tried), first,
                                                            noise, n_folds, rules, search, bar, known)
            else:
                bar.update(len(general))
        finally:
            bar.close()
    not_tried = _not_tried_note(ranking, [c.name for c in general if c not in needed])
    # -> report
    return Diagnosis(fitted.current, fitted.fits, ranking, noise, compare(data, fitted.current).fit_percent_all,
                     plan.unobservable, data, modes, not_tried)


def _is_general(candidate) -> bool:
    """Whether ``candidate`` is a general structure (a grown order or a static map), not a catalogue effect."""
    return isinstance(candidate, OrderCandidate) or candidate.name in MAP_NAMES


def _fitted_and_ranked(data: Batch, current: GreyFit, plan: CandidatePlan, first: CandidateRound, noise: NoiseFloor,
                       n_folds: int, rules: DiagnosisRules, search: CandidateSearch, bar, known: dict):
    """``(fits, ranking, modes)`` of ``plan``'s candidates, whose first round of fits from ``current`` is ``first``
    (the restart of :func:`agents.twin.fits.fit_candidates` where one is due); ``known``: what an earlier call
    found for the same models (the plant's modes of the model diagnosed, and :func:`agents.twin.ranking.rank`'s
    ``known``), filled in place."""
    fitted = fit_candidates(data, current, plan, search.max_iter, search.screen_iter, progress=bar, noise=noise.rmse,
                            first=first)
    bar.update(1)
    # the plant's modes of the model diagnosed (scanned once; the plan's, if it is unchanged)
    modes = plan.modes if fitted.current is current else None
    scanned, their_modes = known.get("modes", (None, None))
    if modes is None and read_modes(fitted.fits):
        modes = their_modes if scanned is fitted.current else tuple(plant_modes(data, fitted.current))
    known["modes"] = (fitted.current, modes)
    ranking = rank(data, fitted.current, fitted.fits, plan, noise, n_folds, rules.bic_margin, rules.min_gain,
                   rules.noise_gain, progress=bar, modes=modes, known=known.setdefault("ranking", {}))
    bar.update(1)
    return fitted, ranking, modes


def general_needed(ranking: Ranking, general: Sequence) -> list:
    """The general structures of ``general`` that could be named ahead of ``ranking``'s best effect.

    Under :func:`agents.twin.ranking.rank`'s order a grown order comes after every effect that passes the
    rules, and a static map goes ahead of an effect only where it explains
    :data:`~agents.twin.ranking.SHARE_POINTS` percentage points more of the current model's residual power
    (:func:`agents.twin.ranking._map_ahead`). So with an effect selected no order is needed, and no map once
    that effect explains more than ``100 - SHARE_POINTS`` %: none of them could be named.
    """
    if ranking.best is None:
        return list(general)
    share = next(c["share"] for c in ranking.candidates if c["effect"] == ranking.best)
    return [c for c in general if c.name in MAP_NAMES and share <= 100.0 - SHARE_POINTS]


def _not_tried_note(ranking: Ranking, names: Sequence[str]) -> str | None:
    """The sentence that says which general structures were not fitted, and why (``None``: all were)."""
    if not names:
        return None
    best = next(c for c in ranking.candidates if c["effect"] == ranking.best)
    maps = [n for n in names if n in MAP_NAMES]
    why = f"{ranking.best} is selected and explains {best['share']:.1f} % of the residual power; a grown order " \
          "is never named ahead of a catalogue effect"
    if maps:
        why += f", a static map only where it explains {SHARE_POINTS:g} percentage points more"
    return f"not fitted: {', '.join(names)} ({why}; CandidateSearch(general_as_fallback=False) fits them)"


def as_step(rung: dict, before: dict, added: str, intervals: dict, units, output: str) -> dict:
    """``rung`` with what adding ``added`` changed: ``before``, the RMSE's fall in % and as a factor,
    the added parameters with their intervals, and the step in words."""
    rung = {**rung, "added": added, "before": before,
            "rmse_fall_percent": 100.0 * (1.0 - rung["rmse"] / before["rmse"]),
            "rmse_factor": before["rmse"] / rung["rmse"] if rung["rmse"] > 0 else float("inf"),
            "added_params": intervals}
    rung["text"] = rung_text(rung, units, output)
    return rung


def _initial_summary(data: Batch | None) -> dict:
    """How the records start, for the JSON: the count of each case and the pinned rest levels."""
    if data is None:
        return {}
    start = data.initial
    modes, counts = np.unique(start.mode, return_counts=True)
    return {"counts": {str(m): int(c) for m, c in zip(modes, counts)},
            "rest": [{"experiment": int(e), "y0": float(y), "u0": float(u)}
                     for e, y, u, pinned in zip(data.numbers, start.y0, start.u0, start.pinned) if pinned]}
