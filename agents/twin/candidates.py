"""The candidates of a diagnosis: structures tried as an addition to the current model, and their starting problems.

The pipeline's third stage (records, linear fit, **candidates**, fits, ranking, report).
A :class:`Candidate` is one catalogue effect added to the current model, in one or more
variants (``drift`` of the gain or of a denominator coefficient; ``coulomb_friction``
symmetric or, where the speed takes both signs, direction-dependent). Its
:meth:`~Candidate.problems` are bounded least-squares problems
(:class:`agents.twin.least_squares.Problem`) started from data-based guesses
(:mod:`agents.twin.guesses`), on the SRIVC profile where it helps
(:func:`agents.twin.linear_fit.profile`). :func:`candidate_plan` says which candidates a
diagnosis fits, and which effects the data cannot show (:func:`agents.twin.evidence.excitation_notes`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from agents.twin.coast_down import coast_down_mask, speed_tolerance
from agents.twin.evidence import both_directions, excitation_notes, unobservable_effects
from agents.twin.guesses import effect_starts, residual_frequencies, rest_command
from agents.twin.least_squares import Problem, make_problem
from agents.twin.linear_fit import PROFILE_EFFECTS, profile
from agents.twin.model import GreyFit, ModelSpec, fitted_parameters
from agents.twin.modes import Mode, plant_modes
from agents.twin.records import Batch
from agents.twin.simulation import simulate_sets
from gbo_envs.physics.effects import EFFECT_NAMES

__all__ = ["MAX_POLES", "MODE_CANDIDATES", "ORDER_CANDIDATES", "Candidate", "CandidatePlan", "OrderCandidate",
           "candidate_plan", "candidate_problems", "effect_bounds", "forward_bias", "read_modes", "refit_problem"]

#: The linear part's structure tried as candidates beside the catalogue's effects: name -> (extra poles,
#: extra zeros). A lightly damped pole pair is a resonance (a flexible coupling, a belt, a mount); a real
#: pole an unmodelled lag (a current loop, a sensor filter); a zero a lead or an anti-resonance's edge.
ORDER_CANDIDATES: dict[str, tuple[int, int]] = {"pole_pair": (2, 0), "pole": (1, 0), "zero": (0, 1)}
#: Most poles an order candidate grows the linear part to.
MAX_POLES = 6
#: The candidates whose variants, starts or evidence read the plant's modes that the residual shows
#: (:func:`agents.twin.modes.plant_modes`).
MODE_CANDIDATES = ("compliance", "pole_pair")
#: SRIVC iterations (and relative tolerance) of a point on a new effect's profile, from the state-variable
#: filter. Six made the starts a fifth cheaper but lost the Coulomb friction of ``benchmarks/real_like_sets.py``'s
#: asymmetric-friction set (cogging was named: RMSE 3.22 -> 2.28, where ten give -> 0.595; docs/design.md).
PROFILE_ITER = 10
PROFILE_TOL = 1e-5
#: Effects whose starting grid is a scan (:func:`agents.twin.guesses.effect_starts`): each point's SRIVC profile
#: starts from its neighbour's fit and takes :data:`SCAN_PROFILE_ITER` iterations (the first point and Brent's
#: refinement between the best point's neighbours take the full :data:`PROFILE_ITER` from the state-variable filter).
SCANNED_EFFECTS = ("saturation",)
SCAN_PROFILE_ITER = 3


def read_modes(names: Iterable[str]) -> bool:
    """Whether one of the candidates ``names`` reads the plant's modes (:data:`MODE_CANDIDATES`)."""
    return any(name in MODE_CANDIDATES for name in names)


@dataclass(frozen=True)
class Candidate:
    """One catalogue effect tried as an addition to a model.

    Attributes
    ----------
    name : str
        Catalogue effect (:data:`gbo_envs.physics.EFFECT_NAMES`).
    variants : tuple of dict
        Options of each variant of the added effect (block options such as drift's
        ``parameter``, and the pseudo-option ``variant`` that chooses the fitted
        parameters, :data:`agents.twin.model.VARIANT_PARAMETERS`).
    """

    name: str
    variants: tuple = ({},)

    def problems(self, data: Batch, current: GreyFit, modes: Sequence[Mode] | None = None) -> list[Problem]:
        """The starting problems of every variant added to ``current``, tagged with :attr:`name`; ``modes``: the
        plant's modes in the residual of ``current`` (:func:`agents.twin.modes.plant_modes`; ``None``: scanned here
        where the candidate needs them)."""
        out = []
        for options in self.variants:
            out += candidate_problems(data, current, self.name, options, tag=self.name, modes=modes)
        return out


@dataclass(frozen=True)
class OrderCandidate:
    """The linear part's structure grown by ``poles`` poles and ``zeros`` zeros, its effects kept.

    Attributes
    ----------
    name : str
        A key of :data:`ORDER_CANDIDATES`.
    poles, zeros : int
        Added to the current model's orders.
    """

    name: str
    poles: int
    zeros: int

    def spec(self, spec: ModelSpec) -> ModelSpec:
        """``spec`` with the grown orders."""
        return ModelSpec(spec.n_poles + self.poles, spec.n_zeros + self.zeros, spec.n_integrators, spec.output,
                         spec.effects)

    def problems(self, data: Batch, current: GreyFit, n_keep: int = 2, *,
                 modes: Sequence[Mode] | None = None) -> list[Problem]:
        """Starts of the grown structure: SRIVC at the new orders under the current effects
        (:func:`agents.twin.linear_fit.profile`), and the current linear part times a factor of the
        new poles or zeros (:meth:`factor_starts`, from the plant's ``modes``), the best ``n_keep`` of them by
        simulation error."""
        spec = self.spec(current.spec)
        old = current.spec
        n_eff = current.theta.size - old.n_linear - 1
        effects = current.theta[old.n_linear + 1 :]
        delay = current.theta[old.n_linear]
        lower, upper, scale = effect_bounds(data, current, np.full(n_eff, -np.inf), np.full(n_eff, np.inf),
                                            np.ones(n_eff))
        rows = np.arange(data.n_records)
        problems = []
        cost, theta, y0, bias = profile(data, spec, np.concatenate([np.zeros(spec.n_linear), [delay], effects]),
                                        max_iter=10, tol=1e-5)
        if np.isfinite(cost):
            problems.append(make_problem(data, spec, theta, y0, bias, rows, lower, upper, scale, tag=self.name))
        thetas = [np.concatenate([linear, [delay], effects]) for linear in self.factor_starts(data, current, modes)]
        sims = simulate_sets(data, [(spec, np.concatenate([th, current.nuisance()]), rows) for th in thetas])
        with np.errstate(over="ignore"):  # a diverged start's output overflows its square: its cost is inf
            costs = [float(np.sum(np.where(data.mask, y - data.y, 0.0) ** 2)) for y in sims]
        for i in np.argsort(np.where(np.isfinite(costs), costs, np.inf))[:n_keep]:
            if np.isfinite(costs[i]):
                problems.append(make_problem(data, spec, thetas[i], current.y0.copy(), current.bias.copy(), rows,
                                             lower, upper, scale, tag=self.name, start=current.start))
        return problems

    def factor_starts(self, data: Batch, current: GreyFit, modes: Sequence[Mode] | None = None) -> list[np.ndarray]:
        """Linear parameters ``[b_0..b_m, a_1..a_(n-k)]`` of the current plant times ``F(s)`` with ``F(0) = 1``.

        A pole pair ``w^2 / (s^2 + 2 zeta w s + w^2)`` at the plant's modes that the residual shows
        (:func:`agents.twin.modes.plant_modes`, at their damping and 0.05), and at the frequencies where the
        residual rings (:func:`agents.twin.guesses.residual_frequencies`) and on a geometric grid, ``zeta``
        0.05 and 0.3; a pole ``p / (s + p)`` or a zero ``s / z + 1`` on the grid. The grid spans four times the
        records' fundamental to a quarter of the Nyquist frequency (rad/s). ``modes``: the plant's modes in the
        residual of ``current`` (``None``: scanned here).
        """
        span = float(data.mask.sum(axis=1).min() * data.dt)
        grid = list(np.geomspace(8.0 * np.pi / span, 0.25 * np.pi / data.dt, 8))
        factors = []
        if self.poles == 2:
            if modes is None:
                modes = plant_modes(data, current)
            pairs = [(m.frequency, zeta) for m in modes for zeta in sorted({m.damping, 0.05})]
            pairs += [(w, zeta) for w in residual_frequencies(data, current) + grid for zeta in (0.05, 0.3)]
            for w, zeta in pairs:
                factors.append((np.array([w**2]), np.array([1.0, 2.0 * zeta * w, w**2])))
        elif self.poles == 1:
            factors = [(np.array([p]), np.array([1.0, p])) for p in grid]
        else:
            factors = [(np.array([1.0 / z, 1.0]), np.array([1.0])) for z in grid]
        spec = current.spec
        k = spec.n_integrators
        num = np.asarray(current.plant.num, dtype=float)
        den = np.asarray(current.plant.den, dtype=float)
        free_den = den[: den.size - k] if k else den  # the integrators stay separate (fixed at s = 0)
        out = []
        for f_num, f_den in factors:
            new_num, new_den = np.polymul(num, f_num), np.polymul(free_den, f_den)
            new_num, new_den = new_num / new_den[0], new_den / new_den[0]
            width = spec.n_zeros + self.zeros + 1
            b = np.concatenate([np.zeros(max(width - new_num.size, 0)), new_num])[-width:]
            out.append(np.concatenate([b, new_den[1:]]))
        return out


@dataclass(frozen=True)
class CandidatePlan:
    """What a diagnosis tries: the candidates it fits, and the effects the data cannot show.

    Attributes
    ----------
    candidates : list of Candidate
        Fitted, in catalogue order.
    skipped : list of str
        Effects not fitted because the data cannot show them.
    notes : dict
        ``{effect: reason}`` for every effect the data cannot show (:func:`excitation_notes`).
    unobservable : list of dict
        ``{"effect", "reason", "experiment"}`` of the tried effects the data cannot show.
    modes : tuple of Mode or None
        The plant's modes in the residual of the current model (:func:`agents.twin.modes.plant_modes`), scanned
        once where a candidate reads them (:data:`MODE_CANDIDATES`), else ``None``.
    """

    candidates: list
    skipped: list
    notes: dict
    unobservable: list
    modes: tuple | None = None

    @property
    def names(self) -> list[str]:
        """Names of the fitted candidates."""
        return [c.name for c in self.candidates]


def candidate_plan(data: Batch, current: GreyFit, names: Sequence[str] | None = None,
                   skip_unexcited: bool = True, orders: bool = True) -> CandidatePlan:
    """The candidates of a diagnosis of ``current`` on ``data``.

    Parameters
    ----------
    data : Batch
    current : GreyFit
        The model diagnosed; its effects are not tried again.
    names : sequence of str, optional
        Effects to try (default: the whole catalogue).
    skip_unexcited : bool, default True
        Leave out the effects the data cannot show (they are listed in ``skipped``).
    orders : bool, default True
        Also try the linear part's structure grown (:data:`ORDER_CANDIDATES`), up to :data:`MAX_POLES` poles.
    """
    names = [n for n in (names or EFFECT_NAMES) if n not in current.spec.effect_names]
    notes = excitation_notes(data, current.spec.output)
    unobservable = unobservable_effects({n: notes[n] for n in names if n in notes})
    skipped = [n for n in names if n in notes] if skip_unexcited else []
    spec = current.spec
    grown = [OrderCandidate(name, poles, zeros) for name, (poles, zeros) in ORDER_CANDIDATES.items()
             if spec.n_poles + poles <= MAX_POLES and spec.n_zeros + zeros < spec.n_poles + poles] if orders else []
    tried = [n for n in names if n not in skipped]
    modes = tuple(plant_modes(data, current)) if read_modes([*tried, *(c.name for c in grown)]) else None
    candidates = [Candidate(n, _variants(n, data, current, modes)) for n in tried]
    return CandidatePlan(candidates + grown, skipped, notes, unobservable, modes)


def _variants(name: str, data: Batch, current: GreyFit, modes: Sequence[Mode] | None) -> tuple[dict, ...]:
    """Variants of effect ``name`` worth fitting on ``data``.

    ``drift`` of the gain and of each denominator coefficient; ``coulomb_friction`` also with a
    level per direction (``asymmetry``) when the speed takes both signs in records whose
    loads the data pin (a reversal within a record, or records that show their rest), since
    only then do both levels act, and with a ramp below a fitted speed (``smoothing``) where the data
    coast down at zero drive (:mod:`agents.twin.coast_down`), whose tail shows how friction fades out
    towards standstill; ``compliance`` measured on the load's side and, where the residual shows a
    mode of the plant (:func:`agents.twin.modes.plant_modes`), on the motor's (where the coupling's
    anti-resonance shows: an encoder on the motor of a flexible beam); ``modes`` are those of the residual of
    ``current``.
    """
    spec = current.spec
    if name == "drift":
        dens = [f"den{i}" for i in range(1, spec.n_poles - spec.n_integrators + 1)]
        return tuple({"parameter": p} for p in ["gain", *dens])
    if name == "coulomb_friction":
        variants = [{}]
        if both_directions(data, spec.output):
            variants.append({"variant": "asymmetric"})
        if spec.output != "position" and coast_down_mask(data, spec.output,
                                                         speed_tolerance(data.y, data.mask)).any():
            variants.append({"variant": "smooth"})
        return tuple(variants)
    if name == "compliance" and modes:
        return ({}, {"measured": "motor"})
    return ({},)


def forward_bias(data: Batch, fit: GreyFit, spec: ModelSpec, theta: np.ndarray) -> np.ndarray:
    """Plant-input bias that keeps each record's rest input after adding effect blocks.

    The blocks of ``spec`` at ``theta`` map the rest command (:func:`rest_command` of ``fit``)
    differently from ``fit``'s blocks; the difference is added to ``fit.bias``. A record
    whose rest the data pin keeps its bias (zero: its rest is measured).

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
    return np.where(data.initial.pinned, fit.bias, fit.bias + (v_old - v))


def _profile_problems(data, current, spec, name, starts, lo, hi, lower, upper, scale, tag) -> list[Problem]:
    """Starting point on the SRIVC profile of the new effect's parameter(s), then one bounded problem."""
    from scipy.optimize import minimize_scalar

    settings = {"max_iter": PROFILE_ITER, "tol": PROFILE_TOL}
    rows = np.arange(data.n_records)
    g0 = current.theta.size
    if name == "time_delay":  # 16 delays up to the longest, then the bounded search between the best's neighbours
        theta = np.concatenate([current.theta, [0.0]])
        res = profile(data, spec, theta, max_delay=float(hi[0]), delay_step=max(data.dt, float(hi[0]) / 16),
                      **settings)
    elif not starts:
        return []
    else:
        results = []
        for start in starts:
            theta = np.concatenate([current.theta, np.clip(start, lo, hi)])
            previous = results[-1][1] if results and name in SCANNED_EFFECTS else None
            if previous is not None and np.isfinite(previous[0]):  # a scan: from its neighbour's fit, briefly
                results.append((theta, profile(data, spec, theta, max_iter=SCAN_PROFILE_ITER, tol=settings["tol"],
                                               warm=previous[1][: spec.n_linear])))
            else:
                results.append((theta, profile(data, spec, theta, **settings)))
        best = int(np.argmin([r[1][0] for r in results]))
        res = results[best][1]
        if lo.size == 1 and len(starts) > 1 and np.isfinite(res[0]):
            values = [float(r[0][g0]) for r in results]
            a, b = sorted((values[max(best - 1, 0)], values[min(best + 1, len(values) - 1)]))  # a scan runs downwards
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


def candidate_problems(data: Batch, current: GreyFit, name: str, options: Mapping | None = None,
                       n_keep: int = 2, tag=None, modes: Sequence[Mode] | None = None) -> list[Problem]:
    """Problems for ``current`` plus effect ``name``: its data-based starts, screened, the best ``n_keep`` kept.

    Actuator effects of :data:`agents.twin.linear_fit.PROFILE_EFFECTS` and ``time_delay`` start
    from the SRIVC profile (one problem); the others from the starts of
    :func:`agents.twin.guesses.effect_starts` screened by their simulation error. ``modes``: the plant's
    modes in the residual of ``current`` (:func:`agents.twin.modes.plant_modes`; ``None``: scanned here where
    ``name`` needs them).
    """
    if modes is None and read_modes([name]):
        modes = plant_modes(data, current)
    spec = current.spec.with_effect(name, options)
    starts, lo, hi, sc = effect_starts(name, data, current, options=options, modes=modes)
    rows = np.arange(data.n_records)
    n_old = current.theta.size - current.spec.n_linear - 1
    lower, upper, scale = effect_bounds(
        data, current, np.concatenate([np.full(n_old, -np.inf), lo]), np.concatenate([np.full(n_old, np.inf), hi]),
        np.concatenate([np.ones(n_old), sc]))
    if name in PROFILE_EFFECTS or name == "time_delay" or (name == "drift" and dict(options or {}).get(
            "parameter", "gain") == "gain" and data.n_records > 1):
        problems = _profile_problems(data, current, spec, name, starts, lo, hi, lower, upper, scale, tag)
        if problems:
            return problems
    thetas = []
    for start in starts:
        theta = np.concatenate([current.theta, np.clip(start, lo, hi)])
        if name == "time_delay":
            theta[spec.n_linear] = current.theta[current.spec.n_linear]
        thetas.append(theta)
    biases = [forward_bias(data, current, spec, th) for th in thetas]
    moving = current.start.ravel()
    sims = simulate_sets(data, [(spec, np.concatenate([th, current.y0, b, moving]), rows)
                                for th, b in zip(thetas, biases)])
    costs = []
    for y in sims:
        with np.errstate(over="ignore", invalid="ignore"):  # a diverged start: its cost is inf either way
            err = np.where(data.mask, y - data.y, 0.0)
            cost = float(np.sum(err**2))
        costs.append(cost if np.isfinite(cost) else np.inf)
    order = np.argsort(costs)[:n_keep]
    problems = []
    for i in order:
        problems.append(make_problem(data, spec, thetas[i], current.y0.copy(), biases[i], rows, lower, upper, scale,
                                     tag=tag, start=current.start))
    if name == "compliance":  # and at the plant's mode, the linear part profiled under the coupling's factor
        problems += _mode_problems(data, current, spec, options, lower, upper, scale, tag, modes)
    return problems


#: Inertia ratios (load over motor, -) of the profiled starts of a coupling seen from the motor
#: (:func:`_mode_problems`): half a decade apart.
MODE_INERTIA_RATIOS = (0.3, 1.0, 3.0)


def _mode_problems(data: Batch, current: GreyFit, spec: ModelSpec, options, lower, upper, scale, tag,
                   modes: Sequence[Mode]) -> list[Problem]:
    """A compliance started at the strongest of the plant's ``modes`` that the residual shows
    (:func:`agents.twin.modes.plant_modes`),
    with the linear part profiled under the coupling's factor (:func:`agents.twin.linear_fit.profile`), the best
    start over the inertia ratios :data:`MODE_INERTIA_RATIOS` where the coupling is seen from the motor.

    The current linear part has bent itself around the mode it lacks (a short record's 2-pole fit drops the
    motor's second pole): started from it, the fit of six 1 s steps of a flexible beam stopped at twice the
    noise floor (damping 0.014 where the beam has 0.03).
    """
    if not modes:
        return []
    m = modes[0]
    motor = dict(options or {}).get("measured") == "motor"
    ratios = MODE_INERTIA_RATIOS if motor else (None,)
    best = None
    for r in ratios:
        effect = [m.frequency, m.damping] + ([r] if motor else [])
        theta = np.concatenate([current.theta, np.clip(effect, lower[-len(effect):], upper[-len(effect):])])
        res = profile(data, spec, theta, max_iter=PROFILE_ITER, tol=PROFILE_TOL)
        if np.isfinite(res[0]) and (best is None or res[0] < best[0]):
            best = res
    if best is None:
        return []
    _, theta, y0, bias = best
    return [make_problem(data, spec, theta, y0, bias, np.arange(data.n_records), lower, upper, scale, tag=tag)]


def effect_bounds(data: Batch, current: GreyFit, lower: np.ndarray, upper: np.ndarray,
                  scale: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounds and scales of the effects already in ``current`` (their data-based ranges, :func:`effect_starts`).

    ``lower``, ``upper`` and ``scale`` (one entry per effect parameter, the effects of
    ``current`` first) are filled in place for those effects and returned.
    """
    pos = 0
    for name, options in current.spec.effects:
        _, lo, hi, sc = effect_starts(name, data, current, with_starts=False, options=options)
        n = len(fitted_parameters(name, options))
        lower[pos : pos + n], upper[pos : pos + n], scale[pos : pos + n] = lo, hi, sc
        pos += n
    return lower, upper, scale


def refit_problem(data: Batch, fit: GreyFit, rows=None, free_global: bool = True, theta=None, y0=None, bias=None,
                  tag=None) -> Problem:
    """``fit``'s structure on the records ``rows`` (default all), started from ``fit`` (or the given global
    parameters ``theta``, rest levels ``y0`` and biases ``bias``), within its effects' data-based bounds."""
    rows = np.arange(data.n_records) if rows is None else np.asarray(rows, dtype=int)
    n_eff = fit.theta.size - fit.spec.n_linear - 1
    lower, upper, scale = effect_bounds(data, fit, np.full(n_eff, -np.inf), np.full(n_eff, np.inf), np.ones(n_eff))
    return make_problem(data, fit.spec, fit.theta if theta is None else theta,
                        fit.y0[rows] if y0 is None else y0, fit.bias[rows] if bias is None else bias, rows,
                        lower, upper, scale, free_global=free_global, tag=tag, start=fit.start[rows])
