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

by a bounded Levenberg-Marquardt iteration, started from the SRIVC fit of the
linear part and data-based guesses of the effect parameters. Many problems
(candidate models, starts, cross-validation folds) advance in lock-step, so
that each iteration is one vectorised simulation of all of them; the Jacobian
is a forward difference in which the per-record nuisance parameters are
perturbed all at once (each only moves its own record).

Parameters of effects whose simulation error is not differentiable (the
quantization step) are not moved by the iteration; they are chosen from a
grid (see :func:`agents.twin.workbench.effect_starts`) and refined on a finer
grid at the end.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from agents.twin.fidelity import rmse
from agents.twin.open_loop import simulate_open_loop
from agents.twin.records import as_records
from gbo_envs.physics.effects import EFFECTS, build_effect
from gbo_envs.physics.lti import ContinuousPlant

__all__ = ["FITTED_PARAMETERS", "GreyData", "GreyFit", "ModelSpec", "Problem", "fit_problems", "residual",
           "simulate_sets"]

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


@dataclass(frozen=True, eq=False)
class GreyData:
    """Records stacked for grey-box fitting (shorter records padded, masked out).

    Attributes
    ----------
    t, r, u, y : ndarray of shape (n_records, n_steps)
        Time (s), reference, commanded input and measured output; padded with the last value.
    mask : ndarray of bool, shape (n_records, n_steps)
        True on real samples.
    dt : float
        Common sample time in s.
    index : ndarray of int, shape (n_records,)
        Experiment index of each record (0 for the first; used by ``drift``).
    """

    t: np.ndarray
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    mask: np.ndarray
    dt: float
    index: np.ndarray

    @classmethod
    def from_records(cls, records, experiment_index: Sequence[int] | None = None) -> GreyData:
        """Validate records (:func:`agents.twin.records.as_records`) and stack them.

        ``experiment_index`` defaults to each record's ``experiment_index`` entry
        when all have one, else to their position.
        """
        items = records if isinstance(records, (list, tuple)) else None
        data = as_records(records, min_steps=3)
        dts = np.array([rec.dt for rec in data])
        if np.any(np.abs(dts - dts[0]) > 1e-6 * dts[0]):
            raise ValueError(f"records: every experiment must have the same sample time, got {sorted(set(dts))}")
        if experiment_index is None:
            given = [it.get("experiment_index") for it in items] if items and all(
                isinstance(it, Mapping) for it in items) else None
            experiment_index = given if given and all(g is not None for g in given) else range(len(data))
        index = np.asarray(list(experiment_index), dtype=int)
        if index.size != len(data):
            raise ValueError(f"experiment_index: need {len(data)} values, got {index.size}")
        index = index - index.min()
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
        return cls(**arrays, mask=mask, dt=float(dts[0]), index=index)

    @property
    def n_records(self) -> int:
        """Number of records."""
        return self.u.shape[0]

    @property
    def n_samples(self) -> int:
        """Real samples in all."""
        return int(self.mask.sum())

    def subset(self, rows: Sequence[int]) -> GreyData:
        """The records ``rows`` (experiment indices kept)."""
        rows = np.asarray(rows, dtype=int)
        return GreyData(self.t[rows], self.r[rows], self.u[rows], self.y[rows], self.mask[rows], self.dt,
                        self.index[rows])


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
    lam: float = 1e-3
    n_iter: int = 0
    done: bool = False
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
        u.append(data.u[rows])
        y0.append(theta[g : g + k])
        bias.append(theta[g + k :])
        index.append(data.index[rows])
        owner += [s] * k
    out = [np.full((rows.size, data.u.shape[1]), np.nan) for _, _, rows in sets]
    if not owner:
        return out
    with np.errstate(all="ignore"):
        res = simulate_open_loop(plants, np.concatenate(u), data.dt, chains, y0=np.concatenate(y0),
                                 bias=np.concatenate(bias), experiment_index=np.concatenate(index))
    owner = np.array(owner)
    y = res.y_true if true_output else res.y
    for s in set(owner.tolist()):
        out[s] = y[owner == s]
    return out


def residual(data: GreyData, rows: np.ndarray, y_sim: np.ndarray) -> np.ndarray:
    """Simulation error ``y_sim - y`` of the records ``rows``, the residual :func:`fit_problems` minimises.

    Padding samples give 0; a non-finite simulated value (a diverged model) gives a large finite
    penalty, ``1e6 (1 + max |y|)``, so that the cost stays comparable.

    Returns
    -------
    ndarray of shape (len(rows), n_steps)
        In the units of ``y``.
    """
    err = np.where(data.mask[rows], y_sim - data.y[rows], 0.0)
    return np.where(np.isfinite(err), err, 1e6 * (1.0 + np.abs(data.y[rows]).max()))


def fit_problems(data: GreyData, problems: list[Problem], max_iter: int = 25, tol: float = 1e-7) -> list[Problem]:
    """Advance bounded Levenberg-Marquardt on all problems in lock-step until each converges.

    Each iteration simulates, in one batch, the forward-difference sets of the
    problems whose Jacobian is stale, then the trial points of all active
    problems. The step solves ``(J^T J + lam diag(J^T J)) d = -J^T e`` in the
    scaled parameters and is clipped to the bounds; ``lam`` falls by 3 on
    success and grows by 4 on failure.

    Returns
    -------
    list of Problem
        The same objects, with ``theta``, ``cost``, ``residual`` and ``y_sim`` set.
    """
    sims = simulate_sets(data, [(p.spec, p.theta, p.rows) for p in problems])
    rough = [any(not smooth for name, _ in p.spec.effects for _, smooth in FITTED_PARAMETERS[name])
             for p in problems]
    base_true: dict[int, np.ndarray] = {}
    for p, y in zip(problems, sims):
        p.y_sim, p.residual = y, residual(data, p.rows, y)
        p.cost = float(np.sum(p.residual**2))
        p.done = not np.any(p.free)
    jac: dict[int, np.ndarray] = {}
    for _ in range(max_iter):
        active = [p for p in problems if not p.done]
        if not active:
            break
        # 1. Jacobians of the problems whose point moved
        sets, layout = [], []
        for i, p in enumerate(problems):
            if p.done or i in jac:
                continue
            g = p.n_global
            cols = [j for j in range(g) if p.free[j]]
            steps = {}
            for j in cols:
                h = 1e-6 * max(abs(p.theta[j]), p.scale[j])
                h = h if p.theta[j] + h <= p.upper[j] else -h
                trial = p.theta.copy()
                trial[j] += h
                steps[j] = h
                sets.append((p.spec, trial, p.rows))
                layout.append((i, ("global", j, h)))
            for block, start in (("y0", g), ("bias", g + p.rows.size)):
                if not p.free[start]:
                    continue
                h = 1e-6 * max(float(np.max(np.abs(p.theta[start : start + p.rows.size]))), p.scale[start])
                trial = p.theta.copy()
                trial[start : start + p.rows.size] += h
                sets.append((p.spec, trial, p.rows))
                layout.append((i, (block, start, h)))
        if sets:
            sims = simulate_sets(data, sets)
            need = sorted({i for i, _ in layout if rough[i]})
            if need:  # quantized output: differentiate the plant output before the sensor instead
                smooth = simulate_sets(data, sets, true_output=True)
                sims = [smooth[n] if rough[i] else y for n, ((i, _), y) in enumerate(zip(layout, sims))]
                base = simulate_sets(data, [(problems[i].spec, problems[i].theta, problems[i].rows) for i in need],
                                     true_output=True)
                base_true.update({i: residual(data, problems[i].rows, y) for i, y in zip(need, base)})
            columns: dict[int, np.ndarray] = {}
            for (i, (kind, start, h)), y in zip(layout, sims):
                p = problems[i]
                mat = columns.setdefault(i, np.zeros((p.residual.size, p.theta.size)))
                ref = base_true[i] if rough[i] else p.residual
                diff = (residual(data, p.rows, y) - ref) / h
                if kind == "global":
                    mat[:, start] = diff.ravel()
                else:
                    n = data.u.shape[1]
                    for r in range(p.rows.size):
                        mat[r * n : (r + 1) * n, start + r] = diff[r]
            jac.update(columns)
        # 2. trial steps
        trials = []
        for i, p in enumerate(problems):
            if p.done:
                continue
            J = jac[i][:, p.free] * p.scale[p.free]
            e = p.residual.ravel()
            jtj = J.T @ J
            grad = J.T @ e
            diag = np.maximum(np.diag(jtj), 1e-12 * max(np.max(np.diag(jtj)), 1e-300))
            try:
                d = -np.linalg.solve(jtj + p.lam * np.diag(diag), grad)
            except np.linalg.LinAlgError:
                d = -np.linalg.lstsq(jtj + p.lam * np.diag(diag), grad, rcond=None)[0]
            theta = p.theta.copy()
            theta[p.free] = np.clip(p.theta[p.free] + d * p.scale[p.free], p.lower[p.free], p.upper[p.free])
            trials.append((i, theta))
        sims = simulate_sets(data, [(problems[i].spec, th, problems[i].rows) for i, th in trials])
        for (i, theta), y in zip(trials, sims):
            p = problems[i]
            p.n_iter += 1
            res = residual(data, p.rows, y)
            cost = float(np.sum(res**2))
            if cost < p.cost:
                gain = (p.cost - cost) / max(p.cost, 1e-300)
                p.theta, p.cost, p.residual, p.y_sim = theta, cost, res, y
                p.lam = max(p.lam / 3.0, 1e-9)
                jac.pop(i, None)
                if gain < tol:
                    p.done = True
            else:
                p.lam *= 4.0
                if p.lam > 1e8:
                    p.done = True
            if p.n_iter >= max_iter:
                p.done = True
    return problems


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
        Root-mean-square simulation error over all real samples, units of ``y``.
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
        return cls(p.spec, p.theta[:g].copy(), p.spec.plant(p.theta[:g]), p.spec.blocks(p.theta[:g]),
                   p.theta[g : g + k].copy(), p.theta[g + k :].copy(), p.y_sim,
                   rmse(data.y[p.rows] - p.y_sim, mask=data.mask[p.rows]))

    @property
    def effect_params(self) -> dict[str, dict]:
        """``{effect: {parameter: value}}`` of the fitted effects."""
        return {name: params for name, params in self.spec.effect_params(self.theta)}

    @property
    def n_params(self) -> int:
        """Global parameters (the complexity of the model; rest levels are not counted)."""
        return int(self.theta.size)
