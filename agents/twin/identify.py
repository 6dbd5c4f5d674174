"""Linear identification of the digital twin: SRIVC with a search over the input delay.

:func:`identify_linear` identifies the DT plant ``G_tilde`` of the paper
(subsec. Digital Twin) from closed-loop step records with SRIVC
(:mod:`agents.twin.srivc`) at each delay of a grid, refines the best delay by a
bounded scalar search, and reports the fidelity ``e_RMSE`` of eq. (RMSE)
normalised by the step height (:func:`agents.twin.fidelity.rmse`).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from agents.parameters import ArrayLike, Boolean, InstanceOf, Interval, Options, validate_params
from agents.twin import srivc
from agents.twin.fidelity import rmse
from agents.twin.records import Batch
from gbo_envs import ContinuousPlant

__all__ = ["DelaySearch", "IdentifyOptions", "LinearIdentification", "SrivcOptions", "check_orders", "identify",
           "identify_linear", "linear_constraints", "prepare_signals", "simulation_error"]

SCAN_ITER = 8  # SRIVC iterations per delay while scanning the delay grid


@dataclass(frozen=True, kw_only=True)
class DelaySearch:
    """How :func:`identify` finds the input delay (an :class:`IdentifyOptions` group).

    Attributes
    ----------
    delay : float, optional
        Known input delay in s; ``None`` searches it.
    max_delay : float, optional
        Upper end of the delay search in s (default: 20 samples of the fitted
        data, at most 20 % of the shortest record).
    delay_step : float, optional
        Spacing of the delay grid in s (default: one sample of the fitted data).
    refine_delay : bool, default True
        Refine the best grid delay by a bounded scalar search (fractional delays).
    """

    delay: float | None = None
    max_delay: float | None = None
    delay_step: float | None = None
    refine_delay: bool = True


@dataclass(frozen=True, kw_only=True)
class SrivcOptions:
    """The SRIVC solver of :func:`identify`: the samples it fits, its prefilters and iterations (an
    :class:`IdentifyOptions` group).

    Attributes
    ----------
    n_samples : int, optional
        Keep this many uniformly spaced samples per record, the paper's sampling
        length ``n_tilde`` of eq. (Ds) (paper: 100). Default ``None`` uses the
        whole record: the loop's input is held between samples, so at the full
        rate the filters are exact and the fit is best. Where the command moves
        within the hold intervals, more samples are kept, or all
        (:func:`agents.twin.records.decimate_records`).
    hold : {"auto", "zoh", "foh"}, default "auto"
        Intersample behaviour of ``u`` and ``y`` in the prefilters: zero-order
        hold (exact for a digital loop sampled at the record rate) or
        first-order hold (linear interpolation, for decimated records). "auto"
        is "zoh" for full records and "foh" when ``n_samples`` decimates.
    oversample : int, default 10
        Filter-grid refinement for ``hold="foh"``.
    max_iter : int, default 50
        Maximum SRIVC iterations per delay.
    tol : float, default 1e-8
        Convergence tolerance on the relative parameter change.
    svf_bandwidth : float, optional
        Bandwidth ``lambda`` in rad/s of the initial state-variable filter
        ``1/(s + lambda)^n`` (default: ``10 / T`` with ``T`` the record length).
    polish : bool, default False
        Safeguard: refine ``(theta, tau)`` by minimising the simulation error
        (``scipy.optimize.least_squares``) from the SRIVC estimate and keep the
        result only if it lowers the RMSE (it matters on short, noisy,
        decimated records; on full records SRIVC is already at the minimum).
    """

    n_samples: int | None = None
    hold: str = "auto"
    oversample: int = 10
    max_iter: int = 50
    tol: float = 1e-8
    svf_bandwidth: float | None = None
    polish: bool = False


#: The groups of :class:`IdentifyOptions`: field name and type.
_GROUPS = {"delay_search": DelaySearch, "solver": SrivcOptions}


@dataclass(frozen=True, kw_only=True)
class IdentifyOptions:
    """The settings of :func:`identify`: the model structure, the delay search and the SRIVC solver.

    The structure's settings are fields of their own; the delay search and the solver are groups
    (:class:`DelaySearch`, :class:`SrivcOptions`). :meth:`settings` lists every setting by its name,
    the keywords of :func:`identify_linear`; their allowed values are :func:`linear_constraints`.

    Attributes
    ----------
    n_poles : int, default 2
        Degree ``n`` of ``A(s)``.
    n_zeros : int, default 0
        Degree ``m < n`` of ``B(s)``.
    n_integrators : int, default 0
        Known poles at ``s = 0`` (1 for a position loop such as the linear motor).
    offset : bool, default True
        Estimate each record's rest levels ``(y0, u0)`` (the pre-step equilibrium);
        ``False`` takes ``y0 = y[0]`` and ``u0 = 0`` (records already in deviations).
    delay_search : DelaySearch, default DelaySearch()
        The input delay: known, or searched on a grid and refined.
    solver : SrivcOptions, default SrivcOptions()
        Decimation, prefilters and iterations of SRIVC.

    Examples
    --------
    >>> options = IdentifyOptions(n_poles=3, delay_search=DelaySearch(max_delay=0.01),
    ...                           solver=SrivcOptions(n_samples=100))
    >>> options.settings()["max_delay"], options.solver.n_samples
    (0.01, 100)
    """

    n_poles: int = 2
    n_zeros: int = 0
    n_integrators: int = 0
    offset: bool = True
    delay_search: DelaySearch = DelaySearch()
    solver: SrivcOptions = SrivcOptions()

    def settings(self) -> dict:
        """Every setting by its name (``n_poles``, ``max_delay``, ``n_samples``, ...), the groups flattened.

        Raises
        ------
        ValueError
            If a group is not of its type (``delay_search`` a :class:`DelaySearch`, ``solver`` a
            :class:`SrivcOptions`).
        """
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in _GROUPS}
        for name, kind in _GROUPS.items():
            group = getattr(self, name)
            if not isinstance(group, kind):
                raise ValueError(f"{name}: must be an instance of {kind.__name__}, got {group!r}")
            out.update({f.name: getattr(group, f.name) for f in dataclasses.fields(group)})
        return out


@functools.cache
def linear_constraints() -> dict[str, list]:
    """Allowed values of the settings of :func:`identify_linear` (:mod:`agents.parameters` constraints), shared
    by :class:`agents.twin.LinearTwin` and :class:`agents.twin.GreyBoxTwin`."""
    return {
        "n_poles": [Interval(int, 1, None)],
        "n_zeros": [Interval(int, 0, None)],
        "n_integrators": [Interval(int, 0, None)],
        "delay": [None, Interval(float, 0, None, closed="left", finite=True)],
        "max_delay": [None, Interval(float, 0, None, closed="left", finite=True)],
        "delay_step": [None, Interval(float, 0, None, closed="neither", finite=True)],
        "refine_delay": [Boolean()],
        "offset": [Boolean()],
        "n_samples": [None, Interval(int, 2, None)],
        "hold": [Options(("auto", "zoh", "foh"))],
        "oversample": [Interval(int, 1, None)],
        "max_iter": [Interval(int, 1, None)],
        "tol": [Interval(float, 0, None, closed="neither", finite=True)],
        "svf_bandwidth": [None, Interval(float, 0, None, closed="neither", finite=True)],
        "polish": [Boolean()],
    }


@dataclass(frozen=True, eq=False)
class LinearIdentification:
    """Outcome of :func:`identify_linear`.

    Attributes
    ----------
    orders : srivc.Orders
        Model structure.
    theta : ndarray of shape (orders.n_params,)
        SRIVC parameters ``[a_1 .. a_{n-k}, b_0 .. b_m]``.
    delay : float
        Input delay in s.
    rmse, rmse_abs : float
        Eq. (RMSE) on the fitted data, normalised by each record's step height
        ``|r2 - y0|`` (dimensionless), and in the units of ``y``.
    rest_levels : ndarray of shape (n_records, 2)
        Estimated ``(y0, u0)`` of each record.
    n_iter : int
        SRIVC iterations at the chosen delay.
    converged : bool
        Whether SRIVC met ``tol`` at the chosen delay.
    delay_grid, delay_rmse : ndarray of shape (n_delays,)
        Delays tried (s) and their normalised RMSE, by increasing delay.
    n_records, n_samples : int
        Records fitted and samples of the longest (after decimation).
    dt : float
        Sample time of the fitted data in s.
    """

    orders: srivc.Orders
    theta: np.ndarray
    delay: float
    rmse: float
    rmse_abs: float
    rest_levels: np.ndarray
    n_iter: int
    converged: bool
    delay_grid: np.ndarray
    delay_rmse: np.ndarray
    n_records: int
    n_samples: int
    dt: float

    @property
    def num(self) -> np.ndarray:
        """``B`` of shape (n_zeros + 1,), highest power first."""
        return self.orders.num(self.theta)

    @property
    def den(self) -> np.ndarray:
        """Monic ``A`` of shape (n_poles + 1,), highest power first."""
        return self.orders.den(self.theta)

    @property
    def params(self) -> np.ndarray:
        """``[b_0 .. b_m, a_1 .. a_{n-k}]``; for the DC motor ``(L, tau1, tau2)``."""
        o = self.orders
        return np.concatenate([self.num, self.den[1 : o.n - o.k + 1]])

    @property
    def param_names(self) -> tuple[str, ...]:
        """Names of :attr:`params`."""
        o = self.orders
        return tuple(f"b{j}" for j in range(o.m + 1)) + tuple(f"a{i}" for i in range(1, o.n - o.k + 1))

    def plant(self, output: str = "speed") -> ContinuousPlant:
        """The identified plant ``G_tilde(s) = num/den e^{-s delay}`` measuring ``output`` ("speed" or "position")."""
        return ContinuousPlant(num=tuple(self.num), den=tuple(self.den), delay=self.delay, output=output)


def check_orders(n_poles: int, n_zeros: int, n_integrators: int) -> srivc.Orders:
    """The model structure, after checking ``0 <= n_zeros < n_poles`` and ``0 <= n_integrators < n_poles``.

    Raises
    ------
    ValueError
        Naming the parameter and its allowed range.
    """
    if not 0 <= n_zeros < n_poles:
        raise ValueError(f"n_zeros: must be an integer with 0 <= n_zeros < n_poles = {n_poles}, got {n_zeros!r}")
    if not 0 <= n_integrators < n_poles:
        raise ValueError(f"n_integrators: must be an integer with 0 <= n_integrators < n_poles = {n_poles}, "
                         f"got {n_integrators!r}")
    return srivc.Orders(int(n_poles), int(n_zeros), int(n_integrators))


def prepare_signals(batch: Batch, orders: srivc.Orders, n_samples: int | None = None, hold: str = "auto",
                    oversample: int = 10, offset: bool = True, rest_levels: np.ndarray | None = None):
    """Decimate (``n_samples``) the records and lay their groups of one length on the SRIVC filter grid.

    Parameters
    ----------
    batch : Batch
        The validated records (:meth:`agents.twin.records.Batch.from_records`).
    orders : srivc.Orders
    n_samples, hold, oversample
        As in :class:`SrivcOptions`.
    offset
        As in :class:`IdentifyOptions`.
    rest_levels
        As in :func:`identify`.

    Returns
    -------
    data : Batch
        The (decimated) records.
    groups : list of ndarray of int
        The rows of each group of one length (:meth:`agents.twin.records.Batch.groups`).
    signals : list of srivc.Signals
        One per group.
    """
    if rest_levels is not None:
        rest_levels = np.asarray(rest_levels, dtype=float)
        if rest_levels.shape != (batch.n_records, 2):
            raise ValueError(f"rest_levels: expected shape ({batch.n_records}, 2), one (y0, u0) row per record, "
                             f"got {rest_levels.shape}")
    _check_excitation(batch, rest_levels)
    data = batch.thinned(n_samples)
    if data.n_samples < orders.n_params + 3:
        raise ValueError(f"records: {data.n_samples} samples in all are too few for {orders.n_params} parameters")
    if hold == "auto":
        hold = "foh" if np.any(data.lengths < batch.lengths) else "zoh"
    groups = data.groups()
    signals = []
    for rows in groups:
        m = int(data.lengths[rows[0]])
        signals.append(srivc.prepare(data.record_dt(int(rows[0])), np.ascontiguousarray(data.u[rows, :m]),
                                     np.ascontiguousarray(data.y[rows, :m]), data.r[rows, m - 1], offset, hold,
                                     int(oversample), None if rest_levels is None else rest_levels[rows]))
    return data, groups, signals


def _check_excitation(batch: Batch, rest_levels: np.ndarray | None = None) -> None:
    """Refuse records without excitation: a constant input, or a constant output, in every experiment.

    A record whose pinned rest command (``rest_levels``) differs from its input is excited by that
    step, even if the input is constant over the record (a step at its first sample from a rest).

    Raises
    ------
    ValueError
        Naming the signal; SRIVC would otherwise diverge at every delay.
    """
    rows = [(batch.u[k, :m], batch.y[k, :m]) for k, m in enumerate(batch.lengths)]  # the real samples
    stepped = [rest_levels is not None and np.isfinite(rest_levels[k, 1]) and np.any(u != rest_levels[k, 1])
               for k, (u, _) in enumerate(rows)]
    for i, name in enumerate(("u", "y")):
        if all(np.ptp(row[i]) == 0.0 and not (name == "u" and step) for row, step in zip(rows, stepped)):
            what = "input u" if name == "u" else "output y"
            raise ValueError(f"records: the {what} is constant in every experiment (e.g. all zero), so the data has "
                             "no excitation to identify a model from; record experiments with a reference step")


def simulation_error(orders: srivc.Orders, theta: np.ndarray, delay: float, signals, offset: bool = True):
    """Eq. (RMSE) of the model ``(theta, delay)`` on prepared records, with their rest levels.

    Returns
    -------
    rmse : float
        Normalised by each record's step height ``|r2 - y0|`` (dimensionless).
    rmse_abs : float
        In the units of ``y``.
    rest_levels : ndarray of shape (n_records, 2)
        ``(y0, u0)`` of each record, batch after batch.
    """
    squares, counts, levels = [], [], []  # per batch: mean squares (normalised, in units of y), samples
    for sig in signals:
        y_sim, y0, u0 = srivc.simulate(orders, theta, delay, sig, offset)
        error = (sig.y + sig.y_ref[:, None]) - y_sim
        if len(signals) == 1:
            return rmse(error, height=np.abs(sig.r2 - y0)), rmse(error), np.column_stack([y0, u0])
        squares.append([rmse(error, height=np.abs(sig.r2 - y0)) ** 2, rmse(error) ** 2])
        counts.append(error.size)
        levels.append(np.column_stack([y0, u0]))
    # several batches (more records than one holds, or records of different lengths): eq. (RMSE) over all samples,
    # from each batch's mean squares, without the errors of all batches at once
    total = np.sqrt(np.average(squares, axis=0, weights=counts))
    return float(total[0]), float(total[1]), np.concatenate(levels)


def identify(batch: Batch, options: IdentifyOptions | None = None, *, start: tuple | None = None,
             rest_levels=None) -> LinearIdentification:
    r"""Continuous-time transfer function with input delay, identified by SRIVC from closed-loop records.

    Model (:mod:`agents.twin.srivc`): ``y = y0 + B(s)/A(s) e^{-s tau} (u - u0)``
    with ``A`` monic of degree ``n_poles`` (``n_integrators`` of its roots at 0)
    and ``B`` of degree ``n_zeros``. ``(A, B)`` come from SRIVC iterations
    (S1)-(S4), started from a least-squares state-variable-filter fit; ``tau``
    minimises the simulation-error RMSE over a grid of delays, refined by a
    bounded scalar search between the neighbours of the best grid point.

    :func:`identify` takes records already validated (a :class:`~agents.twin.records.Batch`) and
    checked settings, as the workbench's pipeline passes them; :func:`identify_linear` takes records in
    any form :func:`agents.twin.records.as_records` reads and validates its settings
    (:mod:`agents.parameters`: an out-of-range setting raises, naming it and its allowed range).

    Parameters
    ----------
    batch : Batch
        The records (:meth:`agents.twin.records.Batch.from_records`), validated there.
    options : IdentifyOptions, optional
        The model structure and the settings of the search (default: :class:`IdentifyOptions`'s).
    start : tuple (theta, delay), optional
        A previous solution (``theta`` as :attr:`LinearIdentification.theta`, delay in s):
        SRIVC starts there and the delay grid shrinks to the delay +- 2 grid steps
        (much faster when records are added one by one, as in guided BO).
    rest_levels : array_like of shape (n_records, 2), optional
        Rest levels ``(y0, u0)`` (units of ``y`` and ``u``) that the data pin, per record; a
        ``NaN`` row is estimated as with ``offset``. A record that shows its rest before the
        excitation (:mod:`agents.twin.initial`) has no free level that could absorb a load.

    Returns
    -------
    LinearIdentification

    Raises
    ------
    ValueError
        ``n_zeros`` or ``n_integrators`` out of range, ``rest_levels`` of another shape, or records without
        excitation or with too few samples for the model (each named).
    RuntimeError
        SRIVC diverged at every delay.

    Examples
    --------
    >>> import gymnasium as gym, numpy as np, gbo_envs
    >>> env = gym.make("gbo_envs/DCMotor-v0", noise=False)
    >>> _ = env.reset(seed=0)
    >>> info = env.step(np.array([0.5, 1.2]))[4]
    >>> fit = identify_linear([info])
    >>> bool(np.allclose(fit.params, (9.544, 4.145, 4.199), rtol=1e-3))
    True
    """
    o = IdentifyOptions() if options is None else options
    search, solver, offset = o.delay_search, o.solver, o.offset
    delay, max_delay, delay_step = search.delay, search.max_delay, search.delay_step
    max_iter, tol = solver.max_iter, solver.tol
    orders = check_orders(o.n_poles, o.n_zeros, o.n_integrators)
    data, groups, signals = prepare_signals(batch, orders, solver.n_samples, solver.hold, solver.oversample, offset,
                                            rest_levels)
    batch_index = np.concatenate(groups)  # record of each row of the signals, group after group
    dt = min(data.record_dt(k) for k in range(data.n_records))
    horizon = min(data.span(k) for k in range(data.n_records))

    bandwidth = solver.svf_bandwidth if solver.svf_bandwidth is not None else 10.0 / horizon
    theta0 = None
    if delay is not None:
        grid = np.array([float(delay)])
    else:
        step = float(delay_step) if delay_step is not None else dt
        top = float(max_delay) if max_delay is not None else min(20 * dt, 0.2 * horizon)
        grid = np.arange(0.0, top + 0.5 * step, step)
    if start is not None:  # warm start: SRIVC from the last fit, delays next to the last delay
        theta0 = np.asarray(start[0], dtype=float)
        near = np.abs(grid - start[1]) <= 2.0 * (grid[1] - grid[0] if grid.size > 1 else 0.0) + 1e-12
        grid = grid[near] if near.any() else grid

    cache: dict[float, tuple[float, srivc.SrivcResult]] = {}

    def evaluate(tau: float, theta_start: np.ndarray | None, iterations: int) -> float:
        if theta_start is None:
            theta_start = srivc.lssvf(orders, signals, tau, bandwidth, offset)
        result = srivc.srivc(orders, signals, tau, theta_start, iterations, tol, offset)
        try:
            score = simulation_error(orders, result.theta, tau, signals, offset)[0]
        except FloatingPointError:  # a start whose pole is too fast to simulate (srivc.srivc): no model here
            score = np.inf
        cache[float(tau)] = (score, result)
        return score

    scores = []
    scan_iter = max_iter if grid.size == 1 else min(max_iter, SCAN_ITER)
    for tau in grid:  # the grid scan ranks delays after a few warm-started iterations
        scores.append(evaluate(tau, theta0, scan_iter))
        theta0 = cache[float(tau)][1].theta if np.isfinite(scores[-1]) else None
    best = int(np.argmin(scores))
    if delay is None and search.refine_delay and grid.size > 1:
        lo = grid[max(best - 1, 0)]
        hi = grid[min(best + 1, grid.size - 1)]
        warm = cache[float(grid[best])][1].theta
        # a delay without a model (inf) goes to Brent as a finite value worse than every model's: its parabolic
        # steps subtract the values, and inf - inf warned "invalid value"
        worst = 2.0 * max([s for s in scores if np.isfinite(s)], default=0.5) or 1.0

        def refined(tau: float) -> float:
            score = evaluate(tau, warm, max_iter)
            return score if np.isfinite(score) else worst

        minimize_scalar(refined, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3 * dt})
    tau_best = min(cache, key=lambda tau: cache[tau][0])
    if not cache[tau_best][1].converged and grid.size > 1:  # finish the iterations at the chosen delay
        evaluate(tau_best, cache[tau_best][1].theta, max_iter)
    score, result = cache[tau_best]
    if not np.isfinite(score):
        raise RuntimeError("identify_linear: SRIVC diverged at every delay; check the data or the model orders")

    theta = result.theta
    if solver.polish:
        bounds = (float(grid[0]), float(grid[-1])) if delay is None else None
        theta, tau_best = _polish(orders, theta, tau_best, signals, score, bounds, offset)
    fit_rmse, fit_rmse_abs, levels = simulation_error(orders, theta, tau_best, signals, offset)
    rest = np.empty((data.n_records, 2))
    rest[batch_index] = levels
    order = np.argsort(list(cache))
    return LinearIdentification(
        orders=orders, theta=theta, delay=float(tau_best), rmse=float(fit_rmse), rmse_abs=float(fit_rmse_abs),
        rest_levels=rest, n_iter=int(result.n_iter), converged=bool(result.converged),
        delay_grid=np.array(list(cache))[order], delay_rmse=np.array([cache[tau][0] for tau in cache])[order],
        n_records=data.n_records, n_samples=int(data.lengths.max()), dt=float(dt))


def identify_linear(records, *, start: tuple | None = None, rest_levels=None, **settings) -> LinearIdentification:
    """:func:`identify` on records in any form, with its settings validated: the function for users.

    Parameters
    ----------
    records : Experiment, mapping, sequence of those or of arrays (n_steps, 4), or DataFrame
        Experiment records with ``t, r, u, y`` (see :func:`agents.twin.records.as_records`), every one with
        the same sample time; validated once, into a :class:`~agents.twin.records.Batch`.
    start, rest_levels
        As in :func:`identify`.
    **settings
        The settings of :class:`IdentifyOptions` by name (:meth:`IdentifyOptions.settings`: ``n_poles``,
        ``max_delay``, ``n_samples``, ...), each checked against :func:`linear_constraints`.

    Returns
    -------
    LinearIdentification

    Raises
    ------
    ValueError
        A setting outside its allowed range (named), or bad records.
    TypeError
        A setting that :class:`IdentifyOptions` and its groups do not have.
    """
    options = checked_options({**settings, "start": start, "rest_levels": rest_levels}, "identify_linear")
    check_orders(options.n_poles, options.n_zeros, options.n_integrators)
    return identify(Batch.from_records(records), options, start=start, rest_levels=rest_levels)


def checked_options(settings: dict, caller: str) -> IdentifyOptions:
    """``settings`` (flat, as :meth:`IdentifyOptions.settings` names them) as :class:`IdentifyOptions`, each
    checked against :func:`linear_constraints` and converted
    (:func:`agents.parameters.validate_params`: a setting out of range raises ``ValueError`` naming it and its
    range); ``start`` (a tuple) and ``rest_levels`` (array-like) are checked too and left out of the options;
    an unknown setting raises ``TypeError`` naming ``caller``."""
    groups = {name: {f.name for f in dataclasses.fields(kind)} for name, kind in _GROUPS.items()}
    fields = {f.name for f in dataclasses.fields(IdentifyOptions)} - set(groups)
    unknown = sorted(set(settings) - fields - set().union(*groups.values()) - {"start", "rest_levels"})
    if unknown:
        raise TypeError(f"{caller}() got unexpected keyword argument(s) {unknown}")
    constraints = {"start": [None, InstanceOf((tuple,))], "rest_levels": [None, ArrayLike()], **linear_constraints()}
    checked = validate_params(constraints, settings)
    grouped = {name: _GROUPS[name](**{key: value for key, value in checked.items() if key in keys})
               for name, keys in groups.items()}
    return IdentifyOptions(**{name: value for name, value in checked.items() if name in fields}, **grouped)


def _polish(orders, theta, tau, signals, score, delay_bounds, offset):
    """Output-error safeguard: minimise the eq. (RMSE) simulation error from the SRIVC estimate.

    SRIVC's fixed point coincides with the simulation-error minimum for long,
    informative records; on short noisy (e.g. decimated) records it can stall
    away from it. A Gauss-Newton/trust-region search (``scipy.optimize.least_squares``)
    over ``(theta, tau)`` from the SRIVC solution is kept only if it lowers the RMSE.
    """
    free_delay = delay_bounds is not None and delay_bounds[1] > delay_bounds[0]

    def residuals(x):
        th, ta = (x[:-1], x[-1]) if free_delay else (x, tau)
        th = srivc.stabilised(orders, th)
        parts = []
        for sig in signals:
            try:
                y_sim, y0 = srivc.simulate(orders, th, float(ta), sig, offset)[:2]
            except FloatingPointError:  # a pole too fast to simulate (srivc._Prefilter)
                return np.full(sum(s.y.size for s in signals), 1e6)
            height = np.maximum(np.abs(sig.r2 - y0), 1e-12)
            parts.append((((sig.y + sig.y_ref[:, None]) - y_sim) / height[:, None]).ravel())
        res = np.concatenate(parts)
        return res if np.all(np.isfinite(res)) else np.full(res.size, 1e6)

    x0 = np.append(theta, tau) if free_delay else theta.copy()
    lower = np.full(x0.size, -np.inf)
    upper = np.full(x0.size, np.inf)
    if free_delay:
        lower[-1], upper[-1] = delay_bounds
        x0[-1] = np.clip(x0[-1], *delay_bounds)
    try:
        sol = least_squares(residuals, x0, bounds=(lower, upper), x_scale="jac", max_nfev=100 * x0.size)
    except (ValueError, np.linalg.LinAlgError):
        return theta, tau
    new_theta = srivc.stabilised(orders, sol.x[:-1] if free_delay else sol.x)
    new_tau = float(sol.x[-1]) if free_delay else tau
    new_score = simulation_error(orders, new_theta, new_tau, signals, offset)[0]
    if np.isfinite(new_score) and new_score < score * (1.0 - 1e-9):
        return new_theta, new_tau
    return theta, tau
