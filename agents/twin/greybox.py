"""Grey-box twin: the linear plant and physical effect parameters fitted together by simulation error.

The model of a record is the open-loop replay of its commanded input ``u``
(:func:`agents.twin.open_loop.simulate_open_loop`): a continuous-time
transfer function ``B(s)/A(s) e^{-s tau}`` (the SRIVC structure of
:mod:`agents.twin.srivc`) with effect blocks from the catalogue, and per
record the rest level ``y0_k`` of the measured output and a constant
plant-input bias ``b_k`` (load, or the rest mismatch of the model; for a
linear model it is SRIVC's rest input ``u0_k`` in disguise,
``b_k = v_rest(y0_k) - u0_k``). The parameters minimise the simulation error

.. math:: V(\\theta) = \\sum_k \\sum_t (y_k(t) - \\hat y_k(t; \\theta))^2

with the trust-region reflective method of ``scipy.optimize.least_squares`` (within
bounds; :func:`agents.twin.trust_region.trf`), started from the SRIVC fit of the
linear part and data-based guesses of the effect parameters. The starts of many
problems (candidate models, starts, cross-validation folds) are simulated in
vectorised passes of bounded size (:data:`SIMULATION_BATCH_SAMPLES`); the Jacobian is a forward difference, in
which the per-record nuisance parameters are perturbed all at once (each only
moves its own record). It is simulated and compressed a few records at a time to
one small triangular block per record (:class:`agents.twin.jacobian.RecordQR`) with
the same normal equations, so that memory and time grow linearly with the number of
records and the full Jacobian never exists. Up to :data:`DENSE_JACOBIAN_MAX_BYTES`
(as a dense matrix) the iteration takes ``least_squares``' exact trust-region steps
(``tr_solver="exact"``, from the SVD of the compressed system: the same steps in exact
arithmetic); a larger one takes its LSMR steps (``tr_solver="lsmr"``).

Parameters of effects whose simulation error is not differentiable (the
quantization step) are not moved by the iteration; they are chosen from a
grid (see :func:`agents.twin.workbench.effect_starts`) and refined on a finer
grid at the end.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize._lsq.common import make_strictly_feasible  # least_squares' own (private module)

from agents.twin.fidelity import rmse
from agents.twin.jacobian import RecordQR, dense_jacobian
from agents.twin.open_loop import simulate_open_loop
from agents.twin.records import as_records, decimate_records
from agents.twin.trust_region import trf
from gbo_envs.physics.effects import EFFECTS, build_effect
from gbo_envs.physics.lti import ContinuousPlant

__all__ = ["DENSE_JACOBIANS_TOTAL_BYTES", "DENSE_JACOBIAN_MAX_BYTES", "FITTED_PARAMETERS", "JACOBIAN_PASS_SAMPLES",
           "SIMULATION_BATCH_SAMPLES",
           "GreyData", "GreyFit", "ModelSpec", "Problem", "fit_problems", "jacobian", "output_error", "residual",
           "residual_in_increments", "simulate_sets", "to_increments"]

#: Effect parameters the grey-box fit estimates, and whether they are moved by the gradient
#: iteration (``True``) or chosen on a grid (``False``). Other parameters keep their defaults.
FITTED_PARAMETERS: dict[str, tuple[tuple[str, bool], ...]] = {
    "time_delay": (("delay", True),),
    "saturation": (("limit", True),),
    "dead_zone": (("width", True),),
    "coulomb_friction": (("torque", True),),
    "viscous_friction": (("coefficient", True),),
    "stiction": (("breakaway", True), ("threshold", True)),
    "backlash": (("width", True),),
    "quantization": (("step", False),),
    "drift": (("rate", True),),
    "offset": (("value", True),),
    "cogging": (("amplitude", True), ("period", True), ("phase", True)),
}


#: Largest Jacobian (bytes as a dense float64 matrix) whose fit takes ``least_squares``' exact trust-region
#: steps (the SVD of its compression record by record, :class:`agents.twin.jacobian.RecordQR`); a larger one
#: takes the LSMR steps, and keeps fewer signals in memory.
DENSE_JACOBIAN_MAX_BYTES = 32 * 2**20
#: Largest sum of the dense Jacobians of the problems solved together in lock-step (bytes); above it
#: each takes the LSMR steps, however small.
DENSE_JACOBIANS_TOTAL_BYTES = 256 * 2**20
#: Most samples (records times steps, all trial points together) simulated in one pass of a compressed
#: Jacobian (about 8 MB per signal); problems in lock-step share :data:`SIMULATION_BATCH_SAMPLES` per pass.
JACOBIAN_PASS_SAMPLES = 2**20
#: Most samples (records times steps) simulated in one vectorised pass (about 8 MB per signal). With the
#: compiled stepping a pass costs the same per sample at any size, so it is kept small: at 2**22 samples
#: the passes held about 200 MB more at the peak of ``gbo twin diagnose`` (issue 37).
SIMULATION_BATCH_SAMPLES = 2**20


@dataclass(frozen=True, eq=False)
class GreyData:
    """Records stacked for grey-box fitting (shorter records padded, masked out).

    Attributes
    ----------
    t, r, u, y : ndarray of shape (n_records, n_steps)
        Time (s), reference, commanded input and measured output; padded with the last value.
    mask : ndarray of bool, shape (n_records, n_steps)
        True on real samples, which lead each row (the padding follows them).
    dt : float
        Common sample time in s.
    index : ndarray of int, shape (n_records,)
        Experiment index of each record (0 for the first; used by ``drift``).
    first_index : int, default 0
        The 0-based :attr:`~gbo_envs.Experiment.index` of the experiment whose ``index`` is 0.
        ``numbers`` (``index + first_index + 1``) are the experiment numbers a person reads:
        counted from 1, as in the workbench CSV (docs/design.md, "Experiment numbers").
    """

    t: np.ndarray
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    mask: np.ndarray
    dt: float
    index: np.ndarray
    first_index: int = 0

    @classmethod
    def decimated(cls, records, n_samples: int | None) -> GreyData:
        """The records decimated to about ``n_samples`` samples each, with the mean input over each hold
        (:func:`agents.twin.records.decimate_records`; ``None`` keeps every sample), then stacked."""
        return cls.from_records(decimate_records(as_records(records, min_steps=3), n_samples, mean_input=True))

    @classmethod
    def from_records(cls, records, experiment_index: Sequence[int] | None = None) -> GreyData:
        """Validate records (:func:`agents.twin.records.as_records`) and stack them into read-only arrays.

        ``experiment_index`` defaults to the records' :attr:`~gbo_envs.Experiment.index`
        as :func:`~agents.twin.records.as_records` sets it.
        """
        data = as_records(records, min_steps=3)
        dts = np.array([rec.dt for rec in data])
        if np.any(np.abs(dts - dts[0]) > 1e-6 * dts[0]):
            raise ValueError(f"records: every experiment must have the same sample time, got {sorted(set(dts))}")
        if experiment_index is None:
            experiment_index = [rec.index for rec in data]
        index = np.asarray(list(experiment_index), dtype=int)
        if index.size != len(data):
            raise ValueError(f"experiment_index: need {len(data)} values, got {index.size}")
        first = int(index.min())
        index = index - first
        n = max(rec.n_steps for rec in data)
        arrays = {name: np.empty((len(data), n)) for name in ("t", "r", "u", "y")}
        mask = np.zeros((len(data), n), dtype=bool)
        for k, rec in enumerate(data):
            m = rec.n_steps
            mask[k, :m] = True
            for name in ("r", "u", "y"):
                arrays[name][k, :m] = getattr(rec, name)
                arrays[name][k, m:] = getattr(rec, name)[-1]
            arrays["t"][k] = rec.t[0] + np.arange(n) * rec.dt
        for array in (*arrays.values(), mask):  # read-only: records of their rows share them, uncopied
            array.setflags(write=False)
        return cls(**arrays, mask=mask, dt=float(dts[0]), index=index, first_index=first)

    @property
    def n_records(self) -> int:
        """Number of records."""
        return self.u.shape[0]

    @property
    def numbers(self) -> np.ndarray:
        """Experiment number of each record, counted from 1 (the workbench CSV's ``experiment`` id)."""
        return self.index + self.first_index + 1

    @property
    def n_samples(self) -> int:
        """Real samples in all."""
        return int(self.mask.sum())

    def is_all(self, rows: np.ndarray) -> bool:
        """Whether ``rows`` are all the records in order (so that the arrays serve as they are, uncopied)."""
        return rows.size == self.n_records and np.array_equal(rows, np.arange(rows.size))

    def subset(self, rows: Sequence[int]) -> GreyData:
        """The records ``rows`` (experiment indices kept)."""
        rows = np.asarray(rows, dtype=int)
        return GreyData(self.t[rows], self.r[rows], self.u[rows], self.y[rows], self.mask[rows], self.dt,
                        self.index[rows], self.first_index)


@dataclass(frozen=True)
class ModelSpec:
    """Structure of a grey-box model: transfer-function orders and effects (with fixed options).

    ``effects`` is a tuple of ``(name, ((option, value), ...))`` in application order.
    """

    n_poles: int = 2
    n_zeros: int = 0
    n_integrators: int = 0
    output: str = "speed"
    effects: tuple = ()

    def with_effect(self, name: str, options: Mapping | None = None) -> ModelSpec:
        """This structure with one more effect (appended)."""
        return ModelSpec(self.n_poles, self.n_zeros, self.n_integrators, self.output,
                         self.effects + ((name, tuple(sorted((options or {}).items()))),))

    @property
    def effect_names(self) -> tuple[str, ...]:
        """Names of the effects."""
        return tuple(name for name, _ in self.effects)

    @property
    def label(self) -> str:
        """Short description, e.g. ``"linear(2p0z)+saturation"``."""
        base = f"linear({self.n_poles}p{self.n_zeros}z" + (f"{self.n_integrators}i" if self.n_integrators else "")
        return base + ")" + "".join(f"+{name}" for name in self.effect_names)

    @property
    def n_linear(self) -> int:
        """Linear parameters ``b_0..b_m, a_1..a_{n-k}``."""
        return self.n_zeros + 1 + self.n_poles - self.n_integrators

    def global_names(self) -> list[str]:
        """Names of the global parameters (before the per-record rest levels and biases)."""
        names = [f"b{j}" for j in range(self.n_zeros + 1)]
        names += [f"a{i}" for i in range(1, self.n_poles - self.n_integrators + 1)]
        names.append("delay")
        for i, (name, _) in enumerate(self.effects):
            names += [f"{name}.{p}" if self.effect_names.count(name) == 1 else f"{name}[{i}].{p}"
                      for p, _ in FITTED_PARAMETERS[name]]
        return names

    def smooth_mask(self) -> np.ndarray:
        """Which global parameters the gradient iteration moves (grid parameters excluded)."""
        flags = [True] * (self.n_linear + 1)
        for name, _ in self.effects:
            flags += [smooth for _, smooth in FITTED_PARAMETERS[name]]
        return np.array(flags)

    def plant(self, theta: np.ndarray) -> ContinuousPlant:
        """Linear plant of the global parameters ``theta``."""
        nb = self.n_zeros + 1
        num = tuple(theta[:nb])
        den = (1.0, *theta[nb : self.n_linear], *([0.0] * self.n_integrators))
        return ContinuousPlant(num=num, den=den, delay=max(float(theta[self.n_linear]), 0.0), output=self.output)

    def effect_params(self, theta: np.ndarray) -> list[tuple[str, dict]]:
        """``[(name, {parameter: value, option: value})]`` of the global parameters ``theta``."""
        out, pos = [], self.n_linear + 1
        for name, options in self.effects:
            params = dict(options)
            for p, _ in FITTED_PARAMETERS[name]:
                params[p] = float(theta[pos])
                pos += 1
            out.append((name, params))
        return out

    def blocks(self, theta: np.ndarray) -> tuple:
        """Effect blocks of the global parameters ``theta``."""
        return tuple(build_effect(name, _valid(name, params)) for name, params in self.effect_params(theta))


def _valid(name: str, params: dict) -> dict:
    """Clip fitted values into the block's allowed ranges (the iteration may touch a bound)."""
    out = dict(params)
    for spec in EFFECTS[name].parameters:
        if spec.name in out and not isinstance(out[spec.name], str):
            out[spec.name] = float(np.clip(out[spec.name], spec.low, spec.high))
    return out


@dataclass(eq=False)
class Problem:
    """One bounded least-squares problem: a model structure fitted to some records.

    ``theta`` holds the global parameters followed by ``y0`` and ``bias`` of
    each record of ``rows``. ``free`` marks what the iteration may move.
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
    residual: np.ndarray | None = field(default=None, repr=False)
    y_sim: np.ndarray | None = field(default=None, repr=False)

    @property
    def n_global(self) -> int:
        """Global (model) parameters."""
        return self.theta.size - 2 * self.rows.size


def simulate_sets(data: GreyData, sets: Sequence[tuple[ModelSpec, np.ndarray, np.ndarray]],
                  true_output: bool = False) -> list[np.ndarray]:
    """Simulated measurements of many ``(spec, theta, rows)`` sets in one vectorised pass.

    ``true_output=True`` returns the plant output before the sensor blocks
    (smooth in the parameters even when the sensor quantizes).

    Returns
    -------
    list of ndarray of shape (len(rows), n_steps)
        ``nan`` rows where a parameter set is invalid (e.g. an unstable plant).
    """
    return [pair[1 if true_output else 0] for pair in _simulate_both(data, sets)]


def _simulate_both(data: GreyData, sets: Sequence[tuple[ModelSpec, np.ndarray, np.ndarray]]) -> list[tuple]:
    """``(measurement, plant output before the sensors)`` of each set, in vectorised passes.

    Consecutive sets are simulated together up to :data:`SIMULATION_BATCH_SAMPLES` samples
    (a larger set alone), so that the memory of one pass is bounded. The rows of a pass do not
    interact, so the grouping does not change the values.
    """
    n_steps = data.u.shape[1]
    out, batch, size = [], [], 0
    for one in sets:
        if batch and size + one[2].size * n_steps > SIMULATION_BATCH_SAMPLES:
            out += _simulate_batch(data, batch)
            batch, size = [], 0
        if one[2].size * n_steps > SIMULATION_BATCH_SAMPLES:
            out.append(_simulate_in_parts(data, *one))
        else:
            batch.append(one)
            size += one[2].size * n_steps
    return out + _simulate_batch(data, batch) if batch else out


def _simulate_in_parts(data: GreyData, spec: ModelSpec, theta: np.ndarray, rows: np.ndarray) -> tuple:
    """``(measurement, plant output before the sensors)`` of one large set, a few records per pass."""
    k, n_steps = rows.size, data.u.shape[1]
    g = theta.size - 2 * k
    y, y_true = np.empty((k, n_steps)), np.empty((k, n_steps))
    per_pass = max(1, SIMULATION_BATCH_SAMPLES // n_steps)
    for first in range(0, k, per_pass):
        part = slice(first, first + per_pass)
        piece = np.concatenate([theta[:g], theta[g : g + k][part], theta[g + k :][part]])
        y[part], y_true[part] = _simulate_batch(data, [(spec, piece, rows[part])])[0]
    return y, y_true


def _simulate_batch(data: GreyData, sets: Sequence[tuple[ModelSpec, np.ndarray, np.ndarray]]) -> list[tuple]:
    """``(measurement, plant output before the sensors)`` of each set, in one vectorised pass."""
    plants, chains, u, y0, bias, index, owner = [], [], [], [], [], [], []
    for s, (spec, theta, rows) in enumerate(sets):
        k = rows.size
        g = theta.size - 2 * k
        try:
            plant = spec.plant(theta[:g])
            blocks = spec.blocks(theta[:g])
        except ValueError:
            continue
        plants += [plant] * k
        chains += [blocks] * k
        u.append(data.u if data.is_all(rows) else data.u[rows])  # read only: no copy of all the records
        y0.append(theta[g : g + k])
        bias.append(theta[g + k :])
        index.append(data.index[rows])
        owner += [s] * k
    out: list = [None] * len(sets)
    if owner:
        try:
            with np.errstate(all="ignore"):
                res = simulate_open_loop(plants, u[0] if len(u) == 1 else np.concatenate(u), data.dt, chains,
                                         y0=np.concatenate(y0), bias=np.concatenate(bias),
                                         experiment_index=np.concatenate(index))
        except (np.linalg.LinAlgError, ValueError):  # a plant that cannot be sampled (overflowing coefficients)
            if len(sets) > 1:
                return [_simulate_batch(data, [one])[0] for one in sets]
        else:
            owner = np.array(owner)
            if (owner == owner[0]).all():  # one set: its outputs as they are, not copied
                out[owner[0]] = (res.y, res.y_true)
            else:
                for s in set(owner.tolist()):
                    out[s] = (res.y[owner == s], res.y_true[owner == s])
    return [(np.full((rows.size, data.u.shape[1]), np.nan),) * 2 if pair is None else pair
            for pair, (_, _, rows) in zip(out, sets)]


class _Lockstep:
    """Simulation requests of problems solved in parallel threads, run together in one vectorised pass.

    Each thread runs one trust-region fit; its residual and Jacobian evaluations
    call :meth:`simulate`, which waits until every thread still solving has made
    its request, then simulates all requests at once (:func:`_simulate_both`).
    The rows of a batch do not interact, so every problem sees the values it
    would see alone; only the per-call overhead of the time loop is shared.
    """

    def __init__(self, data: GreyData, n_workers: int) -> None:
        self.data = data
        self.active = n_workers
        self.pending: list[tuple[list, dict]] = []
        self.cond = threading.Condition()

    def simulate(self, sets: list, true_output: bool = False) -> list[np.ndarray]:
        slot: dict = {}
        with self.cond:
            self.pending.append((sets, slot))
            if len(self.pending) >= self.active:
                self._run()
            while not slot:
                self.cond.wait()
        if "error" in slot:
            raise slot["error"]
        return [pair[1 if true_output else 0] for pair in slot["out"]]

    def leave(self) -> None:
        """A thread has finished; run the others' requests if they were waiting for it."""
        with self.cond:
            self.active -= 1
            if self.pending and len(self.pending) >= self.active:
                self._run()

    def _run(self) -> None:  # called with the lock held
        pending, self.pending = self.pending, []
        try:
            res = _simulate_both(self.data, [one for sets, _ in pending for one in sets])
            start = 0
            for sets, slot in pending:
                slot["out"] = res[start : start + len(sets)]
                start += len(sets)
        except Exception as exc:  # noqa: BLE001  (handed to every waiting thread)
            for _, slot in pending:
                slot["error"] = exc
        self.cond.notify_all()


def residual(data: GreyData, rows: np.ndarray, y_sim: np.ndarray, out: np.ndarray | None = None,
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
    data : GreyData
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
    y, mask = (data.y, data.mask) if data.is_all(rows) else (data.y[rows], data.mask[rows])  # no copies
    penalty = 1e6 * (1.0 + max(float(y.max()), -float(y.min())))
    with np.errstate(invalid="ignore", over="ignore"):
        err = np.subtract(y_sim, y, out=out)
    err[~mask] = 0.0
    diverged = ~np.isfinite(err)
    np.clip(err, -penalty, penalty, out=err)
    err[diverged] = penalty
    return to_increments(err, mask) if increments else err


def residual_in_increments(spec: ModelSpec) -> bool:
    """Whether the fit of ``spec`` takes the simulation error on the output's increments: a position output."""
    return spec.output == "position"


def to_increments(err: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``err`` (records by samples, 0 on padding) replaced in place by its first sample and its increments."""
    err[:, 1:] -= err[:, :-1].copy()
    err[~mask] = 0.0
    return err


def output_error(y: np.ndarray, y_sim: np.ndarray, mask: np.ndarray, spec: ModelSpec) -> np.ndarray:
    """Measured minus simulated output, 0 on padding; on the increments for a position output
    (:func:`residual_in_increments`): the error every RMSE of a grey-box fit is taken on."""
    err = np.where(mask, y - y_sim, 0.0)
    return to_increments(err, mask) if residual_in_increments(spec) else err


def fit_problems(data: GreyData, problems: list[Problem], max_iter: int = 25, tol: float = 1e-7, *,
                 budgets: Sequence[int] | None = None) -> list[Problem]:
    """Solve bounded least-squares problems of the simulation error with ``scipy.optimize.least_squares``.

    All problems are first simulated at their starts in one vectorised pass; each
    problem with free parameters is then solved by the trust-region reflective
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
    data : GreyData
    problems : list of Problem
    max_iter : int, default 25
        Trial points per problem after the start; 0 only simulates the starts.
    tol : float, default 1e-7
        Relative cost decrease that ends the iteration.
    budgets : sequence of int, optional
        Trial points of each problem, instead of ``max_iter`` for all.

    Returns
    -------
    list of Problem
        The same objects, with ``theta``, ``cost`` (sum of squared residuals, units of ``y`` squared),
        ``residual``, ``y_sim`` and ``n_iter`` (simulations of trial points) set.
    """
    sims = simulate_sets(data, [(p.spec, p.theta, p.rows) for p in problems])
    for p, y in zip(problems, sims):
        p.y_sim, p.residual = y, residual(data, p.rows, y, increments=residual_in_increments(p.spec))
        p.cost = float(np.sum(p.residual**2))
    budgets = [int(max_iter)] * len(problems) if budgets is None else [int(b) for b in budgets]
    if len(budgets) != len(problems):
        raise ValueError(f"budgets: need one per problem ({len(problems)}), got {len(budgets)}")
    todo = [(p, b) for p, b in zip(problems, budgets) if b > 0 and np.any(p.free & (p.lower < p.upper))]
    if len(todo) == 1:
        _solve(data, todo[0][0], todo[0][1], float(tol))
    elif todo:
        lockstep = _Lockstep(data, len(todo))

        def solve(p: Problem, budget: int) -> None:
            try:
                _solve(data, p, budget, float(tol), lockstep.simulate, n_parallel=len(todo))
            finally:
                lockstep.leave()

        with ThreadPoolExecutor(max_workers=len(todo)) as pool:
            for future in [pool.submit(solve, p, b) for p, b in todo]:
                future.result()
    return problems


def _difference_layout(data: GreyData, p: Problem, simulate=None):
    """``(simulate, free, rough, columns)`` of a forward-difference Jacobian of ``p``.

    ``simulate`` defaults to :func:`simulate_sets` on ``data``; ``free`` are the moving
    parameters; ``rough`` says a grid parameter (a quantized output) makes the
    Jacobian be taken on the plant output before the sensor; ``columns`` groups the
    free parameters one per simulation: each global parameter alone, then all rest
    levels together and all biases together (each moves only its own record).
    """
    if simulate is None:
        def simulate(sets, true_output=False):
            return simulate_sets(data, sets, true_output=true_output)
    free = np.flatnonzero(p.free & (p.lower < p.upper))
    g, k = p.n_global, p.rows.size
    rough = any(not smooth for name, _ in p.spec.effects for _, smooth in FITTED_PARAMETERS[name])
    columns = [[j] for j in free[free < g]]
    columns += [group for first in (g, g + k) if (group := [j for j in free if first <= j < first + k])]
    return simulate, free, rough, columns


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


def jacobian(data: GreyData, p: Problem, theta: np.ndarray, simulate=None) -> np.ndarray:
    """Forward-difference Jacobian of the residual of ``p`` with respect to its free parameters, at ``theta``.

    One simulation per free global parameter and one for each group of per-record
    nuisances (rest levels, biases: each only moves its own record), all in one
    vectorised pass; for a model with a grid parameter (a quantized output) it is taken
    on the plant output before the sensor, which is smooth in the parameters.

    Parameters
    ----------
    data : GreyData
    p : Problem
        Its ``free`` mask, ``scale``, ``upper`` and ``rows`` are used.
    theta : ndarray
        All parameters of ``p`` (globals, rest levels, biases).
    simulate : callable, optional
        ``simulate(sets, true_output)`` runs the simulations (default :func:`simulate_sets` on ``data``).

    Returns
    -------
    ndarray of shape (len(p.rows) * n_steps, n_free)
        Units of ``y`` per unit of each free parameter.
    """
    simulate, free, rough, columns = _difference_layout(data, p, simulate)
    sets, steps = _difference_sets(p, theta, columns)
    ys = simulate([*sets, (p.spec, theta, p.rows)], true_output=rough)  # last the output at theta itself
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
    g, k = p.n_global, p.rows.size
    positions = [np.flatnonzero(free < g)]
    for cols in columns[shared.shape[0]:]:
        first = g if cols[0] < g + k else g + k
        positions.append(np.column_stack([np.searchsorted(free, cols), np.asarray(cols) - first]))
    return dense_jacobian(shared, per_record, positions)


def _solve(data: GreyData, p: Problem, max_iter: int, tol: float, simulate=None, n_parallel: int = 1) -> None:
    """One :class:`Problem` by the trust-region reflective method from its start; see :func:`fit_problems`.

    ``simulate(sets, true_output)`` runs the simulations (default :func:`simulate_sets` on ``data``);
    ``n_parallel`` problems make their requests together (:class:`_Lockstep`), so each asks for
    its share of the samples of a pass at a time. The iteration is ``least_squares``' (trf;
    :func:`agents.twin.trust_region.trf`) with a forward-difference Jacobian (:func:`jacobian`),
    simulated and factorised a few records at a time (:data:`JACOBIAN_PASS_SAMPLES` samples per
    pass) into :class:`~agents.twin.jacobian.RecordQR`. A Jacobian of at most
    :data:`DENSE_JACOBIAN_MAX_BYTES` as a dense matrix (and :data:`DENSE_JACOBIANS_TOTAL_BYTES` for
    all parallel problems) gets the exact trust-region steps of ``tr_solver="exact"`` (the same
    steps as ``least_squares`` on the dense Jacobian, whose SVD took most of the time of a small
    fit), and the simulated outputs of the current and the trial point are kept; a larger one gets
    the 2-D subspace steps of ``tr_solver="lsmr"``, and memory linear in the records: beyond the
    simulated output and residual at the current and the trial point, bounded (the final output is
    simulated again, once).
    """
    simulate, free, rough, columns = _difference_layout(data, p, simulate)
    g, k, n = p.n_global, p.rows.size, data.u.shape[1]
    inc = residual_in_increments(p.spec)
    size = 8 * k * n * free.size  # bytes of the Jacobian as a dense matrix
    exact = size <= DENSE_JACOBIAN_MAX_BYTES and size * n_parallel <= DENSE_JACOBIANS_TOTAL_BYTES
    start = p.theta.copy()
    n_shared = int(np.sum(free < g))
    positions = _record_positions(p, free, columns, n_shared)
    # records per pass: at most JACOBIAN_PASS_SAMPLES samples of this problem, and SIMULATION_BATCH_SAMPLES
    # of all problems in lock-step (as many passes per Jacobian as it takes, each one round of the lock-step)
    n_sets = len(columns) + 1
    per_pass = max(1, min(JACOBIAN_PASS_SAMPLES // (n * n_sets), SIMULATION_BATCH_SAMPLES // (n * n_sets * n_parallel)))
    # the current point (accepted: the lowest cost so far) and the last trial point, with their residuals
    # (and, with exact steps, their simulated outputs)
    at = {"key": None, "residual": p.residual, "y": p.y_sim}
    trial: dict = {"key": None}

    def full(x: np.ndarray) -> np.ndarray:
        theta = start.copy()
        theta[free] = x
        return theta

    def part(theta: np.ndarray, records: slice) -> np.ndarray:
        return np.concatenate([theta[:g], theta[g : g + k][records], theta[g + k :][records]])

    def cost(x: np.ndarray) -> float:
        trial.update(key=None, residual=None, y=None)  # a rejected trial point's residual: freed first
        y = simulate([(p.spec, full(x), p.rows)])[0]
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
            ys = simulate(passes, true_output=rough)
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
    x0 = make_strictly_feasible(np.clip(start[free], lower, upper), lower, upper)
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
    x, _, nfev = trf(cost, system, x0, cost0, lower, upper, scale, ftol=tol, max_nfev=max_iter + 1,
                     tr_solver="exact" if exact else "lsmr", n_rows=k * n)
    p.n_iter += nfev - 1
    if x.tobytes() != at["key"]:  # the last accepted step ended the iteration before its Jacobian
        at.update(trial)
    new_cost = float(np.einsum("kt,kt->", at["residual"], at["residual"]))
    if new_cost < p.cost:
        p.theta = full(x)
        p.residual, p.cost, y_start = at["residual"], new_cost, at["y"]
    at.clear()
    trial.clear()
    if exact:
        p.y_sim = y_start  # the output whose residual p has
        return
    p.y_sim = simulate([(p.spec, p.theta, p.rows)])[0]  # the output whose residual p has (deterministic)
    if p.residual is None:
        p.residual = residual(data, p.rows, p.y_sim, increments=inc)


def _record_positions(p: Problem, free: np.ndarray, columns: list[list[int]], n_shared: int) -> np.ndarray:
    """Position among the free parameters of each column of each record's block, -1 where fixed.

    Returns
    -------
    ndarray of int, shape (len(p.rows), len(columns))
        The free global parameters first (the same for every record), then the record's own
        parameter of each per-record group of ``columns`` (rest level, bias).
    """
    g, k = p.n_global, p.rows.size
    out = np.full((k, len(columns)), -1)
    out[:, :n_shared] = np.arange(n_shared)
    for j, cols in enumerate(columns[n_shared:], start=n_shared):
        cols = np.asarray(cols)
        first = g if cols[0] < g + k else g + k
        out[cols - first, j] = np.searchsorted(free, cols)
    return out


@dataclass(frozen=True, eq=False)
class GreyFit:
    """A fitted grey-box model.

    Attributes
    ----------
    spec : ModelSpec
    theta : ndarray
        Global parameters (``spec.global_names()``).
    plant : ContinuousPlant
        Linear part with its delay (without the ``time_delay`` effect).
    blocks : tuple of EffectBlock
        Fitted effect blocks.
    y0, bias : ndarray of shape (n_records,)
        Rest level of the measured output and plant-input bias of each record.
    y_sim : ndarray of shape (n_records, n_steps)
        Simulated measurement.
    rmse : float
        Root-mean-square simulation error over all real samples, units of ``y``; for a position
        output, of its increments (:func:`output_error`).
    """

    spec: ModelSpec
    theta: np.ndarray
    plant: ContinuousPlant
    blocks: tuple
    y0: np.ndarray
    bias: np.ndarray
    y_sim: np.ndarray
    rmse: float

    @classmethod
    def from_problem(cls, data: GreyData, p: Problem) -> GreyFit:
        """Collect a solved :class:`Problem` (its records must be ``data``'s)."""
        g, k = p.n_global, p.rows.size
        y, mask = (data.y, data.mask) if data.is_all(p.rows) else (data.y[p.rows], data.mask[p.rows])  # no copies
        return cls(p.spec, p.theta[:g].copy(), p.spec.plant(p.theta[:g]), p.spec.blocks(p.theta[:g]),
                   p.theta[g : g + k].copy(), p.theta[g + k :].copy(), p.y_sim,
                   rmse(output_error(y, p.y_sim, mask, p.spec), mask=mask))

    @property
    def effect_params(self) -> dict[str, dict]:
        """``{effect: {parameter: value}}`` of the fitted effects."""
        return {name: params for name, params in self.spec.effect_params(self.theta)}

    @property
    def n_params(self) -> int:
        """Global parameters (the complexity of the model; rest levels are not counted)."""
        return int(self.theta.size)
