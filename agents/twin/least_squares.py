"""Bounded least squares of the simulation error: the fits of every stage of the pipeline.

A :class:`Problem` is one structure fitted to some records (:func:`make_problem` builds
it with the default bounds). :func:`fit_problems` solves many problems together by the
trust-region reflective method of ``scipy.optimize.least_squares`` (within bounds;
:func:`agents.twin.trust_region.trf`): the parameters minimise the simulation error

.. math:: V(\\theta) = \\sum_k \\sum_t (y_k(t) - \\hat y_k(t; \\theta))^2

The Jacobian is a forward difference, in which the per-record nuisance parameters are
perturbed all at once (each only moves its own record). It is simulated and compressed a
few records at a time to one small triangular block per record
(:class:`agents.twin.jacobian.RecordQR`) with the same normal equations, so that memory
and time grow linearly with the number of records and the full Jacobian never exists. Up
to :data:`DENSE_JACOBIAN_MAX_BYTES` (as a dense matrix) the iteration takes
``least_squares``' exact trust-region steps (``tr_solver="exact"``, from the SVD of the
compressed system: the same steps in exact arithmetic); a larger one takes its LSMR steps
(``tr_solver="lsmr"``).

Parameters of effects whose simulation error is not differentiable (the quantization
step) are not moved by the iteration; they are chosen from a grid
(:func:`agents.twin.guesses.effect_starts`) and refined on a finer grid at the end
(:func:`agents.twin.fits.refine_grid_parameters`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize._lsq.common import make_strictly_feasible  # least_squares' own (private module)

from agents.twin.fidelity import rmse
from agents.twin.jacobian import RecordQR, dense_jacobian
from agents.twin.model import GreyFit, ModelSpec, fitted_parameters, output_error, residual_in_increments, to_increments
from agents.twin.records import Batch
from agents.twin.simulation import simulate_sets
from agents.twin.trust_region import trf
from agents.twin.workers import map_independent, workers_available

__all__ = ["DENSE_JACOBIAN_MAX_BYTES", "JACOBIAN_PASS_SAMPLES", "Problem",
           "fit_problems", "jacobian", "make_problem", "residual"]

#: Largest Jacobian (bytes as a dense float64 matrix) whose fit takes ``least_squares``' exact trust-region
#: steps (the SVD of its compression record by record, :class:`agents.twin.jacobian.RecordQR`); a larger one
#: takes the LSMR steps, and keeps fewer signals in memory.
DENSE_JACOBIAN_MAX_BYTES = 32 * 2**20
#: Most samples (records times steps, all trial points together) simulated in one pass of a compressed
#: Jacobian (about 8 MB per signal).
JACOBIAN_PASS_SAMPLES = 2**20


@dataclass(eq=False)
class Problem:
    """One bounded least-squares problem: a model structure fitted to some records.

    ``theta`` holds the global parameters followed by ``y0`` and ``bias`` of
    each record of ``rows``, then, where a record starts moving, ``n_start`` initial-state
    parameters per record (record by record). ``free`` marks what the iteration may move;
    ``solver_state`` is the trust-region iteration's state after the last fit
    (:func:`agents.twin.trust_region.trf`), from which a fit with ``resume=True`` goes on.
    """

    spec: ModelSpec
    rows: np.ndarray
    theta: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    scale: np.ndarray
    free: np.ndarray
    tag: object = None
    cost: float = np.inf
    n_iter: int = 0
    solver_state: dict | None = field(default=None, repr=False)
    residual: np.ndarray | None = field(default=None, repr=False)
    y_sim: np.ndarray | None = field(default=None, repr=False)

    @property
    def n_global(self) -> int:
        """Global (model) parameters."""
        return self.spec.n_global

    @property
    def n_start(self) -> int:
        """Initial-state parameters per record (0 when no record of the problem starts moving)."""
        return (self.theta.size - self.spec.n_global) // self.rows.size - 2

    def record_of(self, cols: np.ndarray) -> np.ndarray:
        """The record (position in ``rows``) that each per-record parameter index of ``cols`` belongs to."""
        g, k, m = self.n_global, self.rows.size, self.n_start
        cols = np.asarray(cols) - g
        return np.where(cols < 2 * k, cols % k, (cols - 2 * k) // max(m, 1))

    def fit(self, data: Batch) -> GreyFit:
        """The solved problem as a :class:`~agents.twin.model.GreyFit` (its records must be ``data``'s)."""
        g, k, m = self.n_global, self.rows.size, self.n_start
        theta = self.theta
        rows = self.rows
        y, mask = (data.y, data.mask) if data.is_all(rows) else (data.y[rows], data.mask[rows])  # no copies
        return GreyFit(self.spec, theta[:g].copy(), self.spec.plant(theta[:g]), self.spec.blocks(theta[:g]),
                       theta[g : g + k].copy(), theta[g + k : g + 2 * k].copy(), self.y_sim,
                       rmse(output_error(y, self.y_sim, mask, self.spec, data.closed_loop[self.rows]), mask=mask),
                       theta[g + 2 * k :].reshape(k, m).copy())

    def nuisance_of(self, theta: np.ndarray, records) -> np.ndarray:
        """The per-record parameters of ``theta`` for the records ``records`` (a slice or index of ``rows``)."""
        g, k, m = self.n_global, self.rows.size, self.n_start
        start = theta[g + 2 * k :].reshape(k, m)[records].ravel()
        return np.concatenate([theta[g : g + k][records], theta[g + k : g + 2 * k][records], start])


def residual(data: Batch, rows: np.ndarray, y_sim: np.ndarray, out: np.ndarray | None = None,
             increments: bool = False) -> np.ndarray:
    r"""Simulation error ``y_sim - y`` of the records ``rows``, the residual :func:`fit_problems` minimises.

    Padding samples give 0; a non-finite or huge simulated value (a diverged model) gives a large
    finite penalty, ``1e6 (1 + max |y|)``, so that the cost stays comparable and its sum of squares
    cannot overflow inside the solver.

    With ``increments`` (a position output, :func:`residual_in_increments`) the error is taken on the
    increments of the output after the first sample,

    .. math:: \epsilon_k(0) = e_k(0), \qquad \epsilon_k(t) = e_k(t) - e_k(t-1),

    an invertible map of ``e``: the same minimum for a model that replays the record, but an
    error that does not persist. A replayed slider that sticks a moment earlier than the
    plant's stays off by the difference for the rest of the record; on the increments the
    difference counts once, so the error is smooth in the friction and the drive limit.

    Parameters
    ----------
    data : Batch
    rows : ndarray of int
        The records simulated, in the order of the rows of ``y_sim``.
    y_sim : ndarray of shape (len(rows), n_steps)
        Simulated measurement, units of ``y``.
    out : ndarray of shape (len(rows), n_steps), optional
        Array to write the residual into (e.g. a Jacobian column); default a new one.

    Returns
    -------
    ndarray of shape (len(rows), n_steps)
        In the units of ``y``.
    """
    y = data.rows_of(data.y, rows)
    mask = data.rows_of(data.mask, rows) if data.padded(rows) else None
    penalty = 1e6 * (1.0 + data.y_extent(rows))
    with np.errstate(invalid="ignore", over="ignore"):
        err = np.subtract(y_sim, y, out=out)
    if mask is not None:
        err[~mask] = 0.0
    # the common case, every value finite and within the penalty, in two passes without temporaries
    # (a NaN fails both comparisons); the residual runs once per Jacobian column of every fit
    if not (err.max() <= penalty and -err.min() <= penalty):
        diverged = ~np.isfinite(err)
        np.clip(err, -penalty, penalty, out=err)
        err[diverged] = penalty
    return to_increments(err, mask, data.closed_loop[rows]) if increments else err


def fit_problems(data: Batch, problems: list[Problem], max_iter: int = 25, tol: float = 1e-7, *,
                 budgets: Sequence[int] | None = None, resume: bool = False) -> list[Problem]:
    """Solve bounded least-squares problems of the simulation error with ``scipy.optimize.least_squares``.

    All problems are first simulated at their starts in one vectorised pass; each
    problem with free parameters is then solved alone, one after another (or in the worker
    processes of :func:`agents.twin.workers.worker_processes`: the same values), by the trust-region reflective
    method (``method="trf"``) within its bounds, with the variables scaled by
    ``scale``, stopping when an accepted step lowers the cost by less than the
    fraction ``tol`` (``ftol``) or after ``max_iter`` trial points (``max_nfev =
    max_iter + 1``). The Jacobian is a forward difference computed in vectorised
    simulations (:func:`simulate_sets`), with the per-record rest levels (and
    biases) perturbed all at once, since each only moves its own record; for a
    model with a quantized output it is taken on the plant output before the
    sensor, which is smooth in the parameters. It is compressed record by record
    (:class:`~agents.twin.jacobian.RecordQR`), so memory and time grow linearly with the
    records; up to :data:`DENSE_JACOBIAN_MAX_BYTES` the trust-region steps are exact
    (``tr_solver="exact"``), above they are in the 2-D subspace of ``tr_solver="lsmr"``
    (:func:`agents.twin.trust_region.trf`).
    ``benchmarks/bench_greybox_solver.py`` compares it with the hand-written Levenberg-Marquardt iteration it replaced.

    Parameters
    ----------
    data : Batch
    problems : list of Problem
    max_iter : int, default 25
        Trial points per problem after the start; 0 only simulates the starts.
    tol : float, default 1e-7
        Relative cost decrease that ends the iteration.
    budgets : sequence of int, optional
        Trial points of each problem, instead of ``max_iter`` for all.
    resume : bool, default False
        Go on from where the last fit of each problem stopped (its :attr:`Problem.solver_state`), with
        ``max_iter`` counted from that fit's start: the steps one fit with the larger budget takes. A
        problem without a state starts from its parameters.

    Returns
    -------
    list of Problem
        The same objects, with ``theta``, ``cost`` (sum of squared residuals, units of ``y`` squared),
        ``residual``, ``y_sim`` and ``n_iter`` (simulations of trial points) set.
    """
    budgets = [int(max_iter)] * len(problems) if budgets is None else [int(b) for b in budgets]
    if len(budgets) != len(problems):
        raise ValueError(f"budgets: need one per problem ({len(problems)}), got {len(budgets)}")
    todo = [(p, b) for p, b in zip(problems, budgets) if b > 0 and np.any(p.free & (p.lower < p.upper))]
    fresh = {id(p) for p in problems if not (resume and p.solver_state is not None)}  # a resumed one has its output
    # the starts in one vectorised pass here, or each in the worker process that solves it (the same values: the
    # rows of a pass do not interact), which keeps this process's memory and time free of them
    elsewhere = {id(p) for p, _ in todo} & fresh if workers_available() else set()
    _at_start(data, [p for p in problems if id(p) in fresh - elsewhere])
    # one problem at a time, each alone (in worker processes where the caller opened them,
    # agents.twin.workers): its own exact steps, and one problem's signals in memory per process
    # (a problem simulated at its start in its worker goes without its old output: 0.5 MB of 12 x 2,501 samples)
    pieces = []
    for p, b in todo:
        away = id(p) in elsewhere
        pieces.append((data, replace(p, residual=None, y_sim=None) if away else p, b, float(tol), resume, away))
    for p, solved in zip([p for p, _ in todo], map_independent(_solved, pieces)):
        if solved is not p:  # solved in a worker process: its copy
            p.theta, p.cost, p.n_iter, p.residual, p.y_sim, p.solver_state = (
                solved.theta, solved.cost, solved.n_iter, solved.residual, solved.y_sim, solved.solver_state)
    return problems


def _at_start(data: Batch, problems: list[Problem]) -> None:
    """Simulate ``problems`` at their parameters in one vectorised pass: their ``y_sim``, ``residual`` and ``cost``."""
    for p, y in zip(problems, simulate_sets(data, [(p.spec, p.theta, p.rows) for p in problems])):
        p.y_sim, p.residual = y, residual(data, p.rows, y, increments=residual_in_increments(p.spec))
        p.cost = float(np.sum(p.residual**2))


def _solved(data: Batch, p: Problem, max_iter: int, tol: float, resume: bool, start: bool) -> Problem:
    """``p`` solved in place (:func:`_solve`; first simulated at its start, :func:`_at_start`, when ``start``),
    returned (from a worker process: a copy)."""
    if start:
        _at_start(data, [p])
    _solve(data, p, max_iter, tol, resume)
    return p


def _difference_layout(p: Problem):
    """``(free, rough, columns)`` of a forward-difference Jacobian of ``p``.

    ``free`` are the moving parameters; ``rough`` says a grid parameter (a quantized output) makes the
    Jacobian be taken on the plant output before the sensor; ``columns`` groups the
    free parameters one per simulation: each global parameter alone, then all rest
    levels together and all biases together (each moves only its own record).
    """
    free = np.flatnonzero(p.free & (p.lower < p.upper))
    g, k, m = p.n_global, p.rows.size, p.n_start
    rough = any(not smooth for name, options in p.spec.effects for _, smooth in fitted_parameters(name, options))
    columns = [[j] for j in free[free < g]]
    columns += [group for first in (g, g + k) if (group := [j for j in free if first <= j < first + k])]
    # the initial-state parameters, one group per slot: slot s of every moving record at once
    columns += [group for s in range(m) if (group := [j for j in free if j >= g + 2 * k and (j - g - 2 * k) % m == s])]
    return free, rough, columns


def _difference_sets(p: Problem, theta: np.ndarray, columns: list[list[int]]) -> tuple[list, list[float]]:
    """Forward-difference trial sets of ``p`` at ``theta``: one per group of ``columns``, and their steps.

    The step of a group is ``1e-6`` times its largest magnitude (at least its scale),
    taken backwards where a lone parameter would cross its upper bound.
    """
    sets, steps = [], []
    for cols in columns:
        h = 1e-6 * max(float(np.max(np.abs(theta[cols]))), p.scale[cols[0]])
        if len(cols) == 1 and theta[cols[0]] + h > p.upper[cols[0]]:
            h = -h
        trial = theta.copy()
        trial[cols] += h
        sets.append((p.spec, trial, p.rows))
        steps.append(h)
    return sets, steps


def jacobian(data: Batch, p: Problem, theta: np.ndarray) -> np.ndarray:
    """Forward-difference Jacobian of the residual of ``p`` with respect to its free parameters, at ``theta``.

    One simulation per free global parameter and one for each group of per-record
    nuisances (rest levels, biases: each only moves its own record), all in one
    vectorised pass; for a model with a grid parameter (a quantized output) it is taken
    on the plant output before the sensor, which is smooth in the parameters.

    Parameters
    ----------
    data : Batch
    p : Problem
        Its ``free`` mask, ``scale``, ``upper`` and ``rows`` are used.
    theta : ndarray
        All parameters of ``p`` (globals, rest levels, biases).

    Returns
    -------
    ndarray of shape (len(p.rows) * n_steps, n_free)
        Units of ``y`` per unit of each free parameter.
    """
    free, rough, columns = _difference_layout(p)
    sets, steps = _difference_sets(p, theta, columns)
    ys = simulate_sets(data, [*sets, (p.spec, theta, p.rows)], true_output=rough)  # last the output at theta itself
    inc = residual_in_increments(p.spec)
    base = residual(data, p.rows, ys[-1], increments=inc)
    diffs = [(residual(data, p.rows, y, increments=inc) - base) / h for y, h in zip(ys, steps)]
    n_shared = int(np.sum(free < p.n_global))
    shared = np.array(diffs[:n_shared]).reshape(n_shared, *base.shape)
    return _dense_jacobian(p, free, columns, shared, diffs[n_shared:])


def _dense_jacobian(p: Problem, free: np.ndarray, columns: list[list[int]], shared: np.ndarray,
                    per_record: list[np.ndarray]) -> np.ndarray:
    """The dense Jacobian of ``p`` from its difference quotients: ``shared`` (one per free global
    parameter, the first groups of ``columns``) and ``per_record`` (one per later group of ``columns``)."""
    g = p.n_global
    positions = [np.flatnonzero(free < g)]
    for cols in columns[shared.shape[0]:]:
        positions.append(np.column_stack([np.searchsorted(free, cols), p.record_of(cols)]))
    return dense_jacobian(shared, per_record, positions)


def _solve(data: Batch, p: Problem, max_iter: int, tol: float, resume: bool = False) -> None:
    """One :class:`Problem` by the trust-region reflective method from its start; see :func:`fit_problems`.

    With ``resume`` and a :attr:`Problem.solver_state`, the iteration goes on from where the last
    fit of ``p`` stopped, up to ``max_iter`` trial points counted from that fit's start.

    The iteration is ``least_squares``' (trf; :func:`agents.twin.trust_region.trf`) with a
    forward-difference Jacobian (:func:`jacobian`), simulated and factorised a few records at a time
    (:data:`JACOBIAN_PASS_SAMPLES` samples per pass) into :class:`~agents.twin.jacobian.RecordQR`. A
    Jacobian of at most :data:`DENSE_JACOBIAN_MAX_BYTES` as a dense matrix gets the exact trust-region
    steps of ``tr_solver="exact"`` (the same steps as ``least_squares`` on the dense Jacobian, whose SVD
    took most of the time of a small fit), and the simulated outputs of the current and the trial point
    are kept; a larger one gets the 2-D subspace steps of ``tr_solver="lsmr"``, and memory linear in the
    records: beyond the simulated output and residual at the current and the trial point, bounded (the
    final output is
    simulated again, once).
    """
    free, rough, columns = _difference_layout(p)
    g, k, n = p.n_global, p.rows.size, data.u.shape[1]
    inc = residual_in_increments(p.spec)
    exact = 8 * k * n * free.size <= DENSE_JACOBIAN_MAX_BYTES  # bytes of the Jacobian as a dense matrix
    start = p.theta.copy()
    n_shared = int(np.sum(free < g))
    positions = _record_positions(p, free, columns, n_shared)
    # records per pass: at most JACOBIAN_PASS_SAMPLES samples (as many passes per Jacobian as it takes)
    per_pass = max(1, JACOBIAN_PASS_SAMPLES // (n * (len(columns) + 1)))
    # the current point (accepted: the lowest cost so far) and the last trial point, with their residuals
    # (and, with exact steps, their simulated outputs)
    at = {"key": None, "residual": p.residual, "y": p.y_sim}
    trial: dict = {"key": None}

    def full(x: np.ndarray) -> np.ndarray:
        theta = start.copy()
        theta[free] = x
        return theta

    def part(theta: np.ndarray, records: slice) -> np.ndarray:
        return np.concatenate([theta[:g], p.nuisance_of(theta, records)])

    def cost(x: np.ndarray) -> float:
        trial.update(key=None, residual=None, y=None)  # a rejected trial point's residual: freed first
        y = simulate_sets(data, [(p.spec, full(x), p.rows)])[0]
        res = residual(data, p.rows, y, increments=inc)
        trial.update(key=x.tobytes(), residual=res, y=y if exact else None)
        return 0.5 * float(np.einsum("kt,kt->", res, res))

    def system(x: np.ndarray):
        if x.tobytes() == trial["key"]:  # accepted: the trial point becomes the current one
            at.update(trial)
        trial.update(key=None, residual=None, y=None)
        theta = full(x)
        sets, steps = _difference_sets(p, theta, columns)
        compressed = RecordQR(k, positions.shape[1])
        for first in range(0, k, per_pass):
            records = slice(first, first + per_pass)
            rows = p.rows[records]
            passes = [(p.spec, part(one[1], records), rows) for one in sets]
            if rough:  # the smooth output at x itself, first
                passes.insert(0, (p.spec, part(theta, records), rows))
            ys = simulate_sets(data, passes, true_output=rough)
            base = residual(data, rows, ys.pop(0), increments=inc) if rough else at["residual"][records]
            blocks = np.empty((len(ys), rows.size, n))
            for block, y, h in zip(blocks, ys, steps):
                residual(data, rows, y, out=block, increments=inc)
                block -= base
                block /= h
            compressed.add(records, blocks, at["residual"][records])
        return compressed.system(positions, free.size)

    scale = np.where(p.scale[free] > 0, p.scale[free], 1.0)
    lower, upper = p.lower[free], p.upper[free]
    state = p.solver_state if resume and exact else None  # where the last fit's iteration stopped, if it goes on
    # a resumed iteration goes on from its own point (strictly feasible already: moving it by make_strictly_feasible's
    # step would change the steps)
    x0 = start[free].copy() if state is not None else make_strictly_feasible(np.clip(start[free], lower, upper),
                                                                             lower, upper)
    y_start = p.y_sim
    if not exact:
        p.y_sim = at["y"] = None  # freed meanwhile: simulated again at the end
    if not np.array_equal(x0, start[free]):  # the start moved inside the bounds: its residual is not p's
        at["residual"] = at["y"] = None
        if not exact:
            p.residual = None  # freed meanwhile (computed again if nothing beats it)
        cost(x0)
        at.update(trial)
    at["key"] = x0.tobytes()
    cost0 = 0.5 * float(np.einsum("kt,kt->", at["residual"], at["residual"]))
    x, _, nfev, end_state = trf(cost, system, x0, cost0, lower, upper, scale, ftol=tol, max_nfev=max_iter + 1,
                                tr_solver="exact" if exact else "lsmr", n_rows=k * n, resume=state)
    p.n_iter += nfev - (1 if state is None else state["nfev"])
    if x.tobytes() != at["key"]:  # the last accepted step ended the iteration before its Jacobian
        at.update(trial)
    new_cost = float(np.einsum("kt,kt->", at["residual"], at["residual"]))
    if new_cost < p.cost:
        p.theta = full(x)
        p.residual, p.cost, y_start = at["residual"], new_cost, at["y"]
    at.clear()
    trial.clear()
    # the iteration goes on from here only where p holds its point (and its steps are exact: trf's resume)
    p.solver_state = end_state if exact and np.array_equal(p.theta[free], x) else None
    if exact:
        p.y_sim = y_start  # the output whose residual p has
        return
    p.y_sim = simulate_sets(data, [(p.spec, p.theta, p.rows)])[0]  # the output whose residual p has (deterministic)
    if p.residual is None:
        p.residual = residual(data, p.rows, p.y_sim, increments=inc)


def _record_positions(p: Problem, free: np.ndarray, columns: list[list[int]], n_shared: int) -> np.ndarray:
    """Position among the free parameters of each column of each record's block, -1 where fixed.

    Returns
    -------
    ndarray of int, shape (len(p.rows), len(columns))
        The free global parameters first (the same for every record), then the record's own
        parameter of each per-record group of ``columns`` (rest level, bias, initial-state slot).
    """
    k = p.rows.size
    out = np.full((k, len(columns)), -1)
    out[:, :n_shared] = np.arange(n_shared)
    for j, cols in enumerate(columns[n_shared:], start=n_shared):
        cols = np.asarray(cols)
        out[p.record_of(cols), j] = np.searchsorted(free, cols)
    return out


def make_problem(data: Batch, spec: ModelSpec, theta_global: np.ndarray, y0: np.ndarray, bias: np.ndarray,
                 rows: np.ndarray, lower=None, upper=None, scale=None, free_global: bool = True,
                 tag=None, start=None) -> Problem:
    """A :class:`Problem` of ``spec`` on the records ``rows``, with default bounds for the linear part and nuisances.

    Parameters
    ----------
    data : Batch
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
    start : ndarray of shape (len(rows), spec.n_start), optional
        Starting initial-state parameters of the records that start moving (units of ``y`` per s;
        default zero, the rest state); only those records have them, and only when one of ``rows`` does.
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
    rows = np.asarray(rows, dtype=int)
    k = rows.size
    ys = max(float(np.ptp(data.y[rows][data.mask[rows]])), 1e-9)
    us = max(float(np.max(np.abs(data.u[rows]))), 1e-9)
    # a record that shows its rest is pinned there: measured rest level, no plant-input bias (docs/design.md,
    # "Records as real rigs produce them"); the others estimate both, and one that starts moving its state
    pinned = data.initial.pinned[rows]
    moving = data.initial.mode[rows] == "moving"
    m = spec.n_start if moving.any() else 0
    if start is None or m == 0 or np.shape(start) != (k, m):
        start = np.zeros((k, m))
    span = float(data.mask[rows].sum(axis=1).max() * dt)
    lower = np.concatenate([lo, np.full((2 + m) * k, -np.inf)])
    upper = np.concatenate([hi, np.full((2 + m) * k, np.inf)])
    scale = np.concatenate([sc, np.full(k, ys), np.full(k, us), np.full(k * m, ys / span)])
    free = np.concatenate([spec.smooth_mask() & free_global, ~pinned, ~pinned, np.repeat(moving, m)])
    y0 = np.where(pinned, data.initial.y0[rows], y0)
    bias = np.where(pinned, 0.0, bias)
    start = np.where(moving[:, None], start, 0.0)
    if "time_delay" in spec.effect_names:
        free[nl] = False  # the extra delay takes the delay's place
    theta = np.clip(np.concatenate([theta_global, y0, bias, start.ravel()]), lower, upper)
    return Problem(spec=spec, rows=np.asarray(rows, dtype=int), theta=theta, lower=lower, upper=upper, scale=scale,
                   free=free, tag=tag)
