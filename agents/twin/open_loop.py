"""Open-loop simulation of a plant with effect blocks, driven by a recorded command ``u``.

A closed-loop record holds the commanded plant input ``u`` (the controller
output) and the measured output ``y``. Replaying ``u`` through a model of the
plant (``G(s)`` with its input delay, plus actuator, sensor and plant-side
effect blocks from :mod:`gbo_envs.physics`) gives the model's simulated output,
whose difference from ``y`` is the simulation error a digital twin minimises.
The same blocks as in :class:`gbo_envs.closed_loop.ClosedLoop` are called in
the same order and at the same place in the loop:

* plant-side blocks change the plant of each row before its exact ZOH
  discretisation (``modify_plant(plant, experiment_index)``);
* the command, delayed by the plant's whole-sample input delay, goes through
  the actuator blocks (``actuate(u, speed)`` at the true mechanical speed of
  the sample), plus a constant plant-input ``bias`` (a load, or the rest-level
  mismatch of an imperfect model);
* the plant output goes through the sensor blocks (``measure``).

Every row of the batch is one experiment under one model: rows may have their
own plant, their own effect blocks (the same classes or not) and their own
rest levels, so many candidate models, parameter perturbations and records
run in one vectorised pass over time. Rows whose blocks are of the same class
are simulated with one call per sample whenever the block accepts arrays of
per-row parameter values (checked once against the per-row blocks).

Each row starts at rest: the measured output reads ``y0`` (sensor blocks
inverted with ``level_for``), the plant rests at the equilibrium of that true
output with plant input ``v_rest``, and the command before the record is the
one that holds it, ``command_for`` of the actuator blocks applied to
``v_rest - bias`` (which also sets the state of stateful blocks).
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from gbo_envs.physics.block import EffectBlock
from gbo_envs.physics.compliance import Compliance
from gbo_envs.physics.lti import ContinuousPlant, DiscretePlant
from gbo_envs.physics.plant_effects import TimeDelay

__all__ = ["MEMORYLESS_EFFECTS", "SAME_IN_EVERY_EXPERIMENT", "OpenLoopResult", "simulate_open_loop"]

#: Catalogue effects that are static maps ignoring the speed (no state): rows whose actuator and
#: sensor blocks are all of these are simulated without a loop over time (the whole record is
#: mapped through the blocks at once and filtered exactly by the linear plant).
MEMORYLESS_EFFECTS = frozenset({"saturation", "dead_zone", "offset", "quantization", "input_map", "output_map"})
#: Catalogue plant-side blocks whose ``modify_plant`` ignores the experiment index: rows of one plant with
#: only these share one modified plant whatever their experiment (a drift, or a user's block, does not).
SAME_IN_EVERY_EXPERIMENT = (Compliance, TimeDelay)


@dataclass(frozen=True, eq=False)
class OpenLoopResult:
    """Outcome of :func:`simulate_open_loop`.

    Attributes
    ----------
    y : ndarray of shape (batch, n_steps)
        Simulated measurement (after the sensor blocks), in output units.
    y_true : ndarray of shape (batch, n_steps)
        Simulated plant output before the sensor blocks.
    v : ndarray of shape (batch, n_steps)
        Plant input applied over each sample (after the actuator blocks and the bias).
    u_rest : ndarray of shape (batch,)
        Command that holds each row at rest before the record starts.
    v_rest : ndarray of shape (batch,)
        Plant input at rest.
    """

    y: np.ndarray
    y_true: np.ndarray
    v: np.ndarray
    u_rest: np.ndarray
    v_rest: np.ndarray


def simulate_open_loop(
    plant: ContinuousPlant | Sequence[ContinuousPlant],
    u: np.ndarray,
    dt: float,
    effects: Sequence[EffectBlock] | Sequence[Sequence[EffectBlock]] = (),
    y0: np.ndarray | float | None = None,
    bias: np.ndarray | float = 0.0,
    experiment_index: np.ndarray | int = 0,
    initial: np.ndarray | None = None,
    command_rows: np.ndarray | None = None,
) -> OpenLoopResult:
    """Replay recorded commands through plants with effect blocks, vectorised over rows.

    Parameters
    ----------
    plant : ContinuousPlant or sequence of ContinuousPlant
        Linear part of the plant, one for all rows or one per row (length batch).
    u : array_like of shape (batch, n_steps) or (n_steps,)
        Commanded plant input of each row (the controller output as recorded),
        sampled every ``dt`` and held over the sample (zero-order hold).
    dt : float
        Sample time in s.
    effects : sequence of EffectBlock, or sequence (length batch) of such sequences
        Effect blocks of all rows, or of each row, in application order (see
        :class:`gbo_envs.closed_loop.ClosedLoop`). Stateful blocks keep their
        state during the call: do not share one block object between rows that
        should not share state, nor between concurrent calls.
    y0 : array_like of shape (batch,) or float, optional
        Measured output at rest before the record, in output units (default 0).
    bias : array_like of shape (batch,) or float, default 0.0
        Constant plant-input bias added after the actuator blocks, in input units.
    experiment_index : array_like of int, shape (batch,), or int, default 0
        Experiment index of each row for plant-side blocks (``drift``).
    initial : array_like of shape (batch, m), optional
        A start that is not at rest (a record cut from a long log): the plant's state at the first
        sample moves from the rest state so that the free response, with the output unchanged at
        the first sample, has the mean slope ``initial[:, j]`` (output units per s) over the first
        ``j + 1`` samples (``j = 0 .. m - 1``, at most the row's order minus one). Default: at rest.
    command_rows : array_like of int, shape (batch,), optional
        The row of ``u`` each row replays, so that many rows replay one record without copies of it
        (``u`` of shape (records, n_steps)); default: row ``r`` replays ``u[r]``.

    Returns
    -------
    OpenLoopResult

    Notes
    -----
    Without actuator and sensor blocks the rows are linear and are filtered
    exactly with their sampled transfer functions (``scipy.signal.lfilter``);
    otherwise the rows are stepped sample by sample, all at once.

    Examples
    --------
    >>> from gbo_envs.physics import ContinuousPlant, Saturation
    >>> g = ContinuousPlant(num=(9.544,), den=(1.0, 4.145, 4.199), delay=0.002)
    >>> res = simulate_open_loop(g, np.full((1, 500), 150.0), 0.002, (Saturation(120.0),), y0=0.0,
    ...                          bias=0.0)
    >>> round(float(res.y[0, -1]), 1)  # after 1 s, on its way to 120 * 9.544 / 4.199 = 272.7
    163.9
    """
    u = np.atleast_2d(np.asarray(u, dtype=float))
    n = u.shape[1]
    if command_rows is None:
        commands = np.arange(u.shape[0], dtype=np.int64)
    else:
        commands = np.asarray(command_rows, dtype=np.int64).reshape(-1)
        if commands.size and (commands.min() < 0 or commands.max() >= u.shape[0]):
            raise ValueError(f"command_rows: rows of u are 0 .. {u.shape[0] - 1}, got {commands.min()} .. "
                             f"{commands.max()}")
    batch = commands.size
    if not np.isfinite(dt) or dt <= 0.0:
        raise ValueError(f"dt: sample time must be > 0 s, got {dt}")
    plants = [plant] * batch if isinstance(plant, ContinuousPlant) else list(plant)
    if len(plants) != batch:
        raise ValueError(f"plant: need one plant or one per row ({batch}), got {len(plants)}")
    chains = _row_chains(effects, batch)
    y0 = np.broadcast_to(np.asarray(0.0 if y0 is None else y0, dtype=float), (batch,)).copy()
    bias = np.broadcast_to(np.asarray(bias, dtype=float), (batch,)).copy()
    index = np.broadcast_to(np.asarray(experiment_index, dtype=int), (batch,))
    if initial is not None:
        initial = np.asarray(initial, dtype=float).reshape(batch, -1)
        if not np.any(initial):
            initial = None

    # plant-side blocks, then one exact discretisation per distinct plant; rows with the same plant, plant-side
    # blocks and experiment share them (a fit's Jacobian passes repeat each plant for all its records). What a
    # chain of blocks implies is found once per distinct chain (the rows of one parameter set share their chain).
    traits = {}
    for chain in chains:
        if id(chain) not in traits:
            plant_blocks = tuple(block for block in chain if block.side == "plant")
            traits[id(chain)] = (plant_blocks, all(type(b) in SAME_IN_EVERY_EXPERIMENT for b in plant_blocks),
                                 all(b.side == "plant" or b.name in MEMORYLESS_EFFECTS for b in chain))
    continuous, discrete = [], []
    shared: dict[tuple, tuple[ContinuousPlant, DiscretePlant]] = {}
    for row in range(batch):
        plant_blocks, same_everywhere, _ = traits[id(chains[row])]
        # the experiment only counts for a block that may change the plant between experiments (drift)
        experiment = 0 if same_everywhere else int(index[row])
        key = (id(plants[row]), id(chains[row]) if plant_blocks else 0, experiment)
        if key not in shared:
            p = _modified(plants[row], plant_blocks, experiment)
            shared[key] = p, _sampled(p, float(dt))
        continuous.append(shared[key][0])
        discrete.append(shared[key][1])
    direct = np.array([traits[id(chain)][2] for chain in chains], dtype=bool)
    # both paths write their rows straight into the outputs (no copies of a part's results)
    out = {"y": np.empty((batch, n)), "y_true": np.empty((batch, n)), "v": np.empty((batch, n)),
           "u_rest": np.empty(batch), "v_rest": np.empty(batch)}
    for flag, fn in ((True, _direct), (False, _stepping)):
        rows = np.flatnonzero(direct == flag)
        if rows.size == 0:
            continue
        start = None if initial is None else initial[rows]
        if rows.size < batch:
            fn([continuous[r] for r in rows], [discrete[r] for r in rows], [chains[r] for r in rows], u,
               commands[rows], rows, dt, y0[rows], bias[rows], out, start)
        else:
            fn(continuous, discrete, chains, u, commands, rows, dt, y0, bias, out, start)
    return OpenLoopResult(**out)


@dataclass(frozen=True)
class _BlocksByValue:
    """Plant-side blocks that compare and hash by value: each block's class and
    :attr:`~gbo_envs.physics.block.EffectBlock.params` (what ``build_effects`` rebuilds it from).
    ``hash_`` is the value's hash, computed once (the cache looks it up on every row of a simulation)."""

    value: tuple
    hash_: int = field(compare=False)
    blocks: tuple = field(compare=False)

    def __hash__(self) -> int:
        return self.hash_


def _modified(plant: ContinuousPlant, blocks: Sequence[EffectBlock], experiment_index: int) -> ContinuousPlant:
    """``plant`` through the plant-side ``blocks`` at ``experiment_index``, remembered by value
    (:func:`_modified_by_value`). A block whose parameters do not hash (arrays) is applied anew."""
    if not blocks:
        return plant
    value = tuple((type(b), tuple(b.params.items())) for b in blocks)
    try:
        by_value = _BlocksByValue(value, hash(value), tuple(blocks))
    except TypeError:
        return _through(plant, blocks, experiment_index)
    return _modified_by_value(plant, experiment_index, by_value)


@functools.lru_cache(maxsize=8192)
def _modified_by_value(plant: ContinuousPlant, experiment_index: int, blocks: _BlocksByValue) -> ContinuousPlant:
    """:func:`_through`, remembered: a fit's trial points and Jacobian columns ask for the same few modified
    plants again (the compliance block multiplied its polynomials into the plant 13,620 times in one
    diagnosis of the dead-zone bench case, 12 records)."""
    return _through(plant, blocks.blocks, experiment_index)


def _through(plant: ContinuousPlant, blocks: Sequence[EffectBlock], experiment_index: int) -> ContinuousPlant:
    """``plant`` modified by each plant-side block in turn (:meth:`EffectBlock.modify_plant`)."""
    for block in blocks:
        plant = block.modify_plant(plant, experiment_index)
    return plant


@functools.lru_cache(maxsize=8192)
def _sampled(plant: ContinuousPlant, dt: float) -> DiscretePlant:
    """``plant.discretize(dt)``, remembered: a fit's finite-difference columns and trial points ask for the
    same plants again (35,204 discretisations of 7,187 plants in one diagnosis of 12 records). Shared
    between calls: its arrays are read-only."""
    sampled = plant.discretize(dt)
    for array in (sampled.phi, sampled.gamma0, sampled.gamma1, sampled.c, sampled.a, sampled.b):
        array.setflags(write=False)
    return sampled


def _row_chains(effects, batch: int) -> list[tuple[EffectBlock, ...]]:
    effects = tuple(effects) if effects is not None else ()
    if all(isinstance(b, EffectBlock) for b in effects):
        return [effects] * batch
    if len(effects) != batch:
        raise ValueError(f"effects: need one chain of blocks or one per row ({batch}), got {len(effects)}")
    chains, checked = [], set()
    for row, chain in enumerate(effects):
        chain = tuple(chain)  # the same object for a tuple: rows of one chain share it, and it is checked once
        if id(chain) not in checked:
            if not all(isinstance(b, EffectBlock) for b in chain):
                raise ValueError(f"effects: row {row} must be a sequence of effect blocks, got {chain!r}")
            checked.add(id(chain))
        chains.append(chain)
    return chains


def _rest(continuous: list[ContinuousPlant], discrete: list[DiscretePlant], y_true0: np.ndarray):
    """State of shape (batch, order), rest input and rest speed of each row at true output ``y_true0``.

    ``order`` is the largest of the rows' orders; a row of a lower order has zeros in its last states.
    """
    batch = len(discrete)
    order = max(d.order for d in discrete)  # lower orders padded with zero states
    x = np.zeros((batch, order))
    v_rest = np.empty(batch)
    speed = np.empty(batch)
    groups: dict[int, list[int]] = {}
    for row, d in enumerate(discrete):
        groups.setdefault(id(d), []).append(row)
    for rows in groups.values():
        d, c = discrete[rows[0]], continuous[rows[0]]
        xs, vs = d.equilibrium(y_true0[rows])
        x[rows, : d.order] = xs.T
        v_rest[rows] = vs
        row_speed = d.c if c.output != "position" else d.velocity_row()
        speed[rows] = row_speed @ xs
    return x, v_rest, speed


@dataclass(frozen=True, eq=False)
class _Rest:
    """Rows sorted by :func:`_sorted_rows` (``source`` is each sorted row's row of the batch), their block stages
    and rest state."""

    continuous: list
    discrete: list
    groups: list
    source: np.ndarray  # row of the batch (of the outputs) of each sorted row
    commands: np.ndarray  # row of ``u`` each sorted row replays
    bias: np.ndarray
    y_true0: np.ndarray  # true rest output (sensors inverted)
    x0: np.ndarray  # plant state at rest, (batch, order)
    v_rest: np.ndarray  # plant input at rest
    u_rest: np.ndarray  # command that holds the rest (actuators inverted)
    lags: np.ndarray  # whole-sample input delay of each row
    dx: np.ndarray | None = None  # the state's move from rest of a row that starts moving, (batch, order)


def _prepare_rest(continuous, discrete, chains, commands, rows, y0, bias, dt: float, column: bool,
                  initial=None) -> _Rest:
    """Sort the rows, then go from the measured ``y0`` to the rest state.

    Measured ``y0`` -> true output (sensors inverted) -> plant equilibrium -> holding
    command (actuators inverted). ``rows`` are the rows of the batch these rows are, ``commands``
    the rows of ``u`` they replay;
    ``column``: the blocks take column parameters (the direct path) rather than one
    value per row (the stepping path).
    """
    perm = _sorted_rows(chains)
    continuous, discrete, chains = [continuous[r] for r in perm], [discrete[r] for r in perm], [chains[r] for r in perm]
    y0, bias = y0[perm], bias[perm]
    groups = _groups(chains, column=column)
    y_true0 = y0.copy()
    for sl, sensors, _ in groups:
        for stage in reversed(sensors):
            for block, part in stage.parts:
                idx = _global(sl, part)
                y_true0[idx] = _flat(block.level_for, y_true0[idx]) if column else block.level_for(y_true0[idx])
    x0, v_rest, speed0 = _rest(continuous, discrete, y_true0)
    u_rest = _holding_command(groups, v_rest - bias, speed0, dt, column)
    dx = None
    if initial is not None:  # a start that is not at rest: the state moves, the output at the first sample does not
        dx = _moving_start(discrete, initial[perm], dt, x0.shape[1])
        x0 = x0 + dx
    return _Rest(continuous=continuous, discrete=discrete, groups=groups, source=np.asarray(rows)[perm],
                 commands=np.asarray(commands, dtype=np.int64)[perm], bias=bias,
                 y_true0=y_true0, x0=x0, v_rest=v_rest, u_rest=u_rest,
                 lags=np.array([d.delay_steps for d in discrete], dtype=np.int64), dx=dx)


def _moving_start(discrete: list[DiscretePlant], initial: np.ndarray, dt: float, order: int) -> np.ndarray:
    """The move ``dx`` of each row's state from rest, shape (batch, order), for the free-response slopes ``initial``.

    Row ``i``'s ``dx`` solves ``c Phi^q dx = 0`` for ``q = 0`` and ``(q) dt initial[i, q - 1]`` for ``q = 1 .. m``
    (the observability rows of its sampled plant), by least squares with the least norm where ``m``
    is below the row's order minus one; zero where ``initial`` is, NaN where the row's sampled plant
    is not finite.
    """
    batch, m = initial.shape
    dx = np.zeros((batch, order))
    for row in np.flatnonzero(np.any(initial != 0.0, axis=1)):
        d = discrete[row]
        rows_obs, c = [], d.c.copy()
        for _ in range(min(m, d.order - 1) + 1):
            rows_obs.append(c)
            c = c @ d.phi
        obs = np.array(rows_obs)
        if not np.isfinite(obs).all():
            # e^{A dt} overflowed (a fit's trial pole run far into the right half-plane): the row diverges, and
            # its NaN start says so in the output; LAPACK must not see it (it printed DLASCL's "illegal value")
            dx[row] = np.nan
            continue
        target = np.concatenate([[0.0], initial[row, : obs.shape[0] - 1] * dt * np.arange(1, obs.shape[0])])
        dx[row, : d.order] = np.linalg.lstsq(obs, target, rcond=None)[0]
    return dx


def _free_response(d: DiscretePlant, dx: np.ndarray, n: int) -> np.ndarray:
    """``c Phi^q dx`` for ``q = 0 .. n - 1``: the free response of the rows ``dx`` (shape (rows, order)) of one plant.

    As the impulse response ``h`` of ``c (zI - Phi)^-1 dx`` (``h[q + 1] = c Phi^q dx``), filtered (as
    ``scipy.signal.lfilter`` does: :func:`gbo_envs.physics.kernels.lfilter_rows`) with the numerator ``c M_k dx``
    and denominator of the Faddeev-LeVerrier recursion of :func:`_transfer_functions`.
    """
    order = d.order
    den = np.zeros(order + 1)
    den[0] = 1.0
    num = np.zeros((dx.shape[0], order + 1))
    mk = np.zeros((order, order))
    for k in range(1, order + 1):
        mk = d.phi @ mk + den[k - 1] * np.eye(order)
        den[k] = -np.trace(d.phi @ mk) / k
        num[:, k] = dx[:, :order] @ (mk.T @ d.c)  # c M_k dx, per row
    # heavy dependency: numba (kept off the diagnose start-up path)
    from gbo_envs.physics import kernels

    impulse = np.zeros((1, n + 1))
    impulse[0, 0] = 1.0
    return kernels.lfilter_rows(num, den, impulse, source=np.zeros(num.shape[0], dtype=np.int64))[:, 1:]


def _scatter(out: dict, rest: _Rest, **values: np.ndarray) -> None:
    """Put the sorted rows' ``values`` (and their rest inputs) into the rows ``rest.source`` of the outputs."""
    values.update(u_rest=rest.u_rest, v_rest=rest.v_rest)
    whole = rest.source.size == out["u_rest"].size and np.array_equal(rest.source, np.arange(rest.source.size))
    for name, value in values.items():
        if whole:  # every row, in order: the arrays themselves (C-ordered, as the kernel writes them)
            out[name] = np.ascontiguousarray(value)
        else:
            out[name][rest.source] = value


def _direct(continuous, discrete, chains, u, commands, rows, dt, y0, bias, out, initial=None) -> None:
    """Rows ``rows`` whose blocks are static maps: ``y = S(y_rest + P(z) (A(u_delayed) + bias - v_rest))``.

    ``A`` is the actuator and ``S`` the sensor map; ``P(z)`` is the exact sampled plant without its
    whole-sample delay, run on the deviation from rest as ``scipy.signal.lfilter`` runs it. In the
    compiled kernel (:func:`gbo_envs.physics.kernels.open_loop_direct_kernel`, one pass over the samples)
    when it knows every block of the rows, else in :func:`_direct_numpy`: the same numbers. The results
    go into the rows ``rows`` of the outputs ``out``.
    """
    # heavy dependency: numba (kept off the diagnose start-up path)
    from gbo_envs.physics import kernels

    compiled = all(kernels.known(b) for chain in chains for b in chain if b.side != "plant")
    # the numpy maps take their parameters as column vectors, the kernel one value per row
    rest = _prepare_rest(continuous, discrete, chains, commands, rows, y0, bias, dt, column=not compiled,
                         initial=initial)
    if not compiled:
        _direct_numpy(rest, u, out)
        return
    batch, n = len(rest.discrete), u.shape[1]
    sensors, actuators = _packed(rest.groups, batch, dt)
    tf = _transfer_functions(rest.discrete)
    width = max(max(num.size, den.size) for num, den in tf.values())
    num_rows, den_rows = np.zeros((batch, width)), np.zeros((batch, width))
    num_len, den_len = np.empty(batch, dtype=np.int64), np.empty(batch, dtype=np.int64)
    for row, d in enumerate(rest.discrete):
        num, den = tf[id(d)]
        num_rows[row, : num.size], den_rows[row, : den.size] = num, den
        num_len[row], den_len[row] = num.size, den.size
    free_row, free = _free_responses(rest, n)
    kernels.open_loop_direct_kernel(num_rows, den_rows, num_len, den_len, _kernel_input(u), rest.commands,
                                    rest.source, rest.lags,
                                    rest.u_rest, rest.bias, rest.v_rest, rest.y_true0, free_row, free,
                                    sensors.code, sensors.params, actuators.code, actuators.params, out["y"],
                                    out["y_true"], out["v"])
    _scatter(out, rest)  # the rest inputs; the kernel wrote the signals


def _direct_numpy(rest: _Rest, u: np.ndarray, out: dict) -> None:
    """:func:`_direct` in numpy (blocks the kernel does not know): the maps act on whole records at once,
    their parameters as column vectors, one per row."""
    # heavy dependency: numba (kept off the diagnose start-up path)
    from gbo_envs.physics import kernels

    n = u.shape[1]
    discrete, groups, bias, v_rest = rest.discrete, rest.groups, rest.bias, rest.v_rest
    v = _delayed(u, rest.commands, rest.lags, rest.u_rest)
    for sl, _, actuators in groups:
        for stage in actuators:
            for block, part in stage.parts:
                idx = _global(sl, part)
                v[idx] = block.actuate(v[idx], np.zeros_like(v[idx]))
    v += bias[:, None]
    y_true = np.empty((len(discrete), n))
    tf_cache = _transfer_functions(discrete)
    same_plant: dict[int, list[int]] = {}
    for row, d in enumerate(discrete):
        same_plant.setdefault(id(d), []).append(row)
    for key, idx in same_plant.items():  # one filter per distinct plant, row by row along the last axis
        num, den = tf_cache[key]
        idx = np.array(idx)
        y_true[idx] = rest.y_true0[idx, None] + kernels.lfilter_rows(num, den, v[idx] - v_rest[idx, None])
    free_row, free = _free_responses(rest, n)
    for row in np.flatnonzero(free_row >= 0):  # rows that start moving: their free response from the moved state
        y_true[row] += free[free_row[row]]
    y = y_true.copy()
    for sl, sensors, _ in groups:
        for stage in sensors:
            for block, part in stage.parts:
                idx = _global(sl, part)
                y[idx] = block.measure(y[idx])
    _scatter(out, rest, y=y, y_true=y_true, v=v)


def _free_responses(rest: _Rest, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(free_row, free)``: for each sorted row, its row of ``free`` (the free response from its moved state,
    :func:`_free_response`, shape (moving, n)), or -1 for a row that starts at rest."""
    free_row = np.full(len(rest.discrete), -1, dtype=np.int64)
    if rest.dx is None:
        return free_row, np.zeros((0, n))
    moving = np.flatnonzero(np.any(rest.dx != 0.0, axis=1))
    free_row[moving] = np.arange(moving.size)
    free = np.empty((moving.size, n))
    for i, row in enumerate(moving):
        free[i] = _free_response(rest.discrete[row], rest.dx[row : row + 1], n)[0]
    return free_row, free


def _kernel_input(u: np.ndarray) -> np.ndarray:
    """The commands as the kernels take them: one compiled signature, a C-ordered writeable float array."""
    return u if u.flags.c_contiguous and u.flags.writeable and u.dtype == float else np.array(u, dtype=float,
                                                                                               order="C")


def _packed(groups, batch: int, dt: float):
    """``(sensors, actuators)``: the rows' blocks packed for the kernels (:func:`gbo_envs.physics.kernels.pack_blocks`),
    each ``None`` when a block of its side is unknown to them."""
    # heavy dependency: numba (kept off the diagnose start-up path)
    from gbo_envs.physics import kernels

    sides = {}
    for side in ("sensor", "actuator"):
        parts = [(j, block, _global(sl, part)) for sl, sensors, actuators in groups
                 for j, stage in enumerate(sensors if side == "sensor" else actuators) for block, part in stage.parts]
        sides[side] = kernels.pack_blocks(parts, batch, dt)
    return sides["sensor"], sides["actuator"]


def _transfer_functions(discrete: list[DiscretePlant]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``{id(plant): (num, den)}`` in ``z^-1`` of the distinct sampled plants, without the whole-sample delay.

    The same transfer function as :meth:`DiscretePlant.transfer_function` (whose
    ``scipy.signal.ss2tf`` costs two polynomial root computations per plant),
    for all plants of one order at once by the Faddeev-LeVerrier recursion:
    ``det(zI - Phi) = sum_j c_j z^j`` and ``adj(zI - Phi) = sum_k M_k z^(n-k)`` with
    ``M_1 = I``, ``M_k = Phi M_(k-1) + c_(n-k+1) I`` and ``c_(n-k) = -tr(Phi M_k) / k``,
    so that ``c (zI - Phi)^-1 (Gamma0 + Gamma1 z^-1)`` has denominator coefficients
    ``c_(n-i)`` of ``z^-i`` and numerator ``c M_k Gamma0`` of ``z^-k`` (and
    ``c M_k Gamma1`` one power later).
    """
    unique = {id(d): d for d in discrete}
    by_order: dict[int, list[DiscretePlant]] = {}
    for d in unique.values():
        by_order.setdefault(d.order, []).append(d)
    out = {}
    for order, plants in by_order.items():
        phi = np.stack([d.phi for d in plants])
        g = np.stack([np.stack([d.gamma0, d.gamma1], axis=-1) for d in plants])  # (m, n, 2)
        c = np.stack([d.c for d in plants])
        m = len(plants)
        eye = np.broadcast_to(np.eye(order), (m, order, order))
        den = np.zeros((m, order + 1))
        den[:, 0] = 1.0
        num = np.zeros((m, order + 2))
        mk = np.zeros((m, order, order))
        for k in range(1, order + 1):
            mk = phi @ mk + den[:, k - 1, None, None] * eye
            den[:, k] = -np.trace(phi @ mk, axis1=1, axis2=2) / k
            cg = np.einsum("mi,mij,mjs->ms", c, mk, g)  # c M_k [Gamma0, Gamma1]
            num[:, k] += cg[:, 0]
            num[:, k + 1] += cg[:, 1]
        for i, d in enumerate(plants):
            nonzero = np.flatnonzero(num[i])
            out[id(d)] = (num[i, : nonzero[-1] + 1 if nonzero.size else 0], den[i])  # trailing zeros trimmed
    return out


def _delayed(u: np.ndarray, source: np.ndarray, lags: np.ndarray, u_rest: np.ndarray) -> np.ndarray:
    """Rows ``source`` of the commands ``u`` (shape (records, n_steps)), row ``i`` delayed by ``lags[i]`` >= 0 samples
    and preceded by ``u_rest[i]``; filled by slices per distinct delay (no index arrays of the data's size)."""
    batch, n = source.size, u.shape[1]
    out = np.empty((batch, n))
    in_order = source.size == u.shape[0] and np.array_equal(source, np.arange(batch))
    for lag in np.unique(lags):
        rows = np.flatnonzero(lags == lag)
        lag = min(int(lag), n)
        if in_order and rows.size == batch:  # every row: plain slices, no copy of the commands
            out[:, :lag] = u_rest[:, None]
            out[:, lag:] = u[:, : n - lag]
        else:
            out[rows, :lag] = u_rest[rows, None]
            out[rows, lag:] = u[source[rows], : n - lag]
    return out


def _sorted_rows(chains) -> np.ndarray:
    """Row order that makes rows with the same block classes, then the same blocks, contiguous."""
    keys: dict[int, tuple] = {}  # per distinct chain: the rows of one parameter set share theirs
    blocks: dict[tuple, int] = {}  # each distinct set of blocks, numbered as it first comes (not by address)
    for chain in chains:
        if id(chain) not in keys:
            same = blocks.setdefault(tuple(id(b) for b in chain), len(blocks))
            keys[id(chain)] = (repr(tuple((type(b).__name__, b.side) for b in chain if b.side != "plant")), same)
    return np.array(sorted(range(len(chains)), key=lambda r: keys[id(chains[r])]), dtype=int)


def _flat(fn, values: np.ndarray) -> np.ndarray:
    """Apply a block map with column parameters to a vector of shape (rows,)."""
    return np.asarray(fn(values[:, None]), dtype=float).reshape(values.shape)


def _holding_command(groups, u_rest: np.ndarray, speed0: np.ndarray, dt: float, column: bool) -> np.ndarray:
    """Invert the actuator blocks at rest (``command_for``, which also sets block state)."""
    u_rest = u_rest.copy()
    for sl, sensors, actuators in groups:
        size = sl.stop - sl.start
        for stage in sensors + actuators:
            stage.reset(size, dt)
        for stage in reversed(actuators):
            for block, part in stage.parts:
                idx = _global(sl, part)
                try:
                    if column:
                        u_rest[idx] = np.asarray(block.command_for(u_rest[idx][:, None], speed0[idx][:, None]),
                                                 dtype=float).reshape(-1)
                    else:
                        u_rest[idx] = block.command_for(u_rest[idx], speed0[idx])
                except (ValueError, TypeError):  # no command holds this rest (a limit below it): keep the input
                    pass
    return u_rest


def _groups(chains, column: bool):
    """Contiguous runs of rows with the same block classes: ``(slice, sensor stages, actuator stages)``."""
    stepped: dict[int, tuple] = {}  # per distinct chain: its actuator and sensor blocks
    for chain in chains:
        if id(chain) not in stepped:
            stepped[id(chain)] = tuple(b for b in chain if b.side != "plant")
    signature = [tuple((type(b), b.side) for b in stepped[id(chain)]) for chain in chains]
    rng = _ProbeDraws()
    groups = []
    start, batch = 0, len(chains)
    while start < batch:
        stop = start
        while stop < batch and signature[stop] == signature[start]:
            stop += 1
        blocks = [stepped[id(chains[r])] for r in range(start, stop)]
        stages = [_Stage([row[j] for row in blocks], rng, column) for j in range(len(blocks[0]))]
        groups.append((slice(start, stop), [s for s in stages if s.side == "sensor"],
                       [s for s in stages if s.side == "actuator"]))
        start = stop
    return groups


class _ProbeDraws:
    """The random probe inputs of :func:`_merged`, from one generator per simulation (seed 12345), made at the
    first probe: most simulations merge nothing, and a generator costs 36 us to make."""

    def __init__(self) -> None:
        self._rng: np.random.Generator | None = None

    def normal(self, loc: float, scale: float, shape) -> np.ndarray:
        if self._rng is None:
            self._rng = np.random.default_rng(12345)
        return self._rng.normal(loc, scale, shape)


class _Stage:
    """One block position of a group of rows with the same block classes.

    ``parts`` is ``[(block, part)]``: one block for all rows (the same object,
    or a copy whose numeric parameters are per-row arrays), else one block per
    contiguous run of rows. With ``column=True`` merged parameters are column
    vectors of shape (rows, 1), for inputs of shape (rows, n_steps).
    """

    def __init__(self, blocks: list[EffectBlock], rng: _ProbeDraws, column: bool) -> None:
        self.side = blocks[0].side
        self.parts: list[tuple[EffectBlock, slice]] = []
        if all(b is blocks[0] for b in blocks):
            self.parts = [(blocks[0], slice(None))]
            return
        merged = _merged(blocks, rng, column)
        if merged is not None:
            self.parts = [(merged, slice(None))]
            return
        start = 0
        while start < len(blocks):  # rows of one block are contiguous (see _sorted_rows)
            stop = start
            while stop < len(blocks) and blocks[stop] is blocks[start]:
                stop += 1
            self.parts.append((blocks[start], slice(start, stop)))
            start = stop

    def reset(self, size: int, dt: float) -> None:
        for block, part in self.parts:
            block.reset(len(range(size)[part]), None, dt)


def _merged(blocks: list[EffectBlock], rng: _ProbeDraws, column: bool) -> EffectBlock | None:
    """One block whose numeric parameters are per-row arrays, if its class computes them row-wise correctly.

    Probed: on random inputs, the merged block must give what each row's own block gives. Rows that share a
    block object (the records of one parameter set) are probed together through that block.
    """
    first = blocks[0]
    distinct = {id(b): b for b in blocks}
    if any(type(b) is not type(first) for b in distinct.values()) or any(
            getattr(b, name) != getattr(first, name) for b in distinct.values() for name in type(first).options):
        return None
    merged = copy.copy(first)
    rows_of: dict[int, list[int]] = {}
    for row, b in enumerate(blocks):
        rows_of.setdefault(id(b), []).append(row)
    for name in first.param_names:
        values = np.empty(len(blocks))
        for key, rows in rows_of.items():
            values[rows] = float(getattr(distinct[key], name))
        if np.all(values == values[0]):
            continue
        setattr(merged, name, values[:, None] if column else values)
    size = len(blocks)
    scale = np.empty(size)
    for key, rows in rows_of.items():
        scale[rows] = distinct[key].magnitude
    scale = np.where(np.isfinite(scale), np.maximum(np.abs(scale), 1.0), 1.0)
    shape = (size, 3) if column else (size,)
    probe_u = rng.normal(0.0, 1.5, shape) * (scale[:, None] if column else scale)
    probe_s = rng.normal(0.0, 1.0, shape)
    try:
        with np.errstate(all="ignore"):
            merged.reset(size, None, 1e-3)
            got = merged.measure(probe_u) if first.side == "sensor" else merged.actuate(probe_u, probe_s)
            want = np.empty(shape)
            for key, rows in rows_of.items():
                b = distinct[key]
                b.reset(len(rows), None, 1e-3)
                want[rows] = np.asarray(b.measure(probe_u[rows]) if first.side == "sensor" else b.actuate(
                    probe_u[rows], probe_s[rows]), dtype=float)
            got = np.broadcast_to(np.asarray(got, dtype=float), shape)
    except (ValueError, TypeError):
        return None
    if not np.allclose(got, want, rtol=1e-12, atol=1e-12, equal_nan=True):
        return None
    return merged


def _stepping(continuous, discrete, chains, u, commands, rows, dt, y0, bias, out, initial=None) -> None:
    """Sample-by-sample simulation of the rows ``rows``, grouped by the classes of their blocks.

    The rows may have plants of different orders. The rest state and the blocks' start are
    computed in Python (:func:`_prepare_rest`); the stepping runs in the compiled kernel
    (:func:`gbo_envs.physics.kernels.open_loop_kernel`) when it knows every actuator and
    sensor block of the rows, else in :func:`_step_numpy`, which gives the same numbers.
    The results go into the rows ``rows`` of the outputs ``out``.
    """
    rest = _prepare_rest(continuous, discrete, chains, commands, rows, y0, bias, dt, column=False, initial=initial)
    continuous, discrete, groups = rest.continuous, rest.discrete, rest.groups
    batch, order = rest.x0.shape
    # per row: [Phi Gamma0 Gamma1] of its order, padded with zeros to the largest order
    transition = np.zeros((batch, order, order + 2))
    c_rows = np.zeros((batch, order))
    speed_rows = np.zeros((batch, order))
    for row, (d, p) in enumerate(zip(discrete, continuous)):
        m = d.order
        transition[row, :m, :m] = d.phi
        transition[row, :m, order] = d.gamma0
        transition[row, :m, order + 1] = d.gamma1
        c_rows[row, :m] = d.c
        speed_rows[row, :m] = d.c if p.output != "position" else d.velocity_row()

    # heavy dependency: numba (kept off the diagnose start-up path)
    from gbo_envs.physics import kernels

    sensors, actuators = _packed(groups, batch, dt)
    if sensors is None or actuators is None:
        y, y_true, v = _step_numpy(groups, rest, u, transition, c_rows, speed_rows)
        _scatter(out, rest, y=y, y_true=y_true, v=v)
        return
    kernels.open_loop_kernel(np.array([d.order for d in discrete], dtype=np.int64), transition, c_rows, speed_rows,
                             _kernel_input(u), rest.commands, rest.source, rest.lags, rest.u_rest, rest.bias, rest.x0,
                             rest.v_rest,
                             sensors.code, sensors.params, sensors.state, actuators.code, actuators.params,
                             actuators.state, out["y"], out["y_true"], out["v"])
    _scatter(out, rest)  # the rest inputs; the kernel wrote the signals


def _step_numpy(groups, rest: _Rest, u, transition, c_rows, speed_rows):
    """The stepping of :func:`_stepping` in numpy, vectorised over the rows (blocks the kernel does not know).

    Every sum is accumulated from left to right, as the compiled kernel does; rows of a lower
    order carry zero states. Returns ``(y, y_true, v)`` of shape (rows, n_steps) in the sorted
    order of the rows.
    """
    batch, order = rest.x0.shape
    n = u.shape[1]
    bias = rest.bias
    u_delayed = np.ascontiguousarray(_delayed(u, rest.commands, rest.lags, rest.u_rest).T)  # (n, batch)
    # batch-last layout: every operation of a step is elementwise over the rows (a batched matmul of
    # tiny matrices costs 17 us with 360 rows, the elementwise products and sum 4.5 us)
    transition = np.ascontiguousarray(transition.transpose(1, 2, 0))
    c_rows, speed_rows = np.ascontiguousarray(c_rows.T), np.ascontiguousarray(speed_rows.T)
    same_speed = bool(np.array_equal(speed_rows, c_rows))
    stacked = np.empty((order + 2, batch))  # [state, v[k], v[k-1]]
    stacked[:order] = rest.x0.T
    stacked[order + 1] = rest.v_rest
    state = stacked[:order]
    products = np.empty((order, order + 2, batch))
    weighted = np.empty((order, batch))
    y_rec = np.empty((n, batch))
    yt_rec = np.empty((n, batch))
    v_rec = np.empty((n, batch))
    sensor_ops = [(block.measure, _global(sl, part)) for sl, sensors, _ in groups for stage in sensors
                  for block, part in stage.parts]
    actuator_ops = [(block.actuate, _global(sl, part)) for sl, _, actuators in groups for stage in actuators
                    for block, part in stage.parts]
    for step in range(n):
        y_true = yt_rec[step]
        np.multiply(c_rows, state, out=weighted)
        np.add.reduce(weighted, axis=0, out=y_true)
        if sensor_ops:
            y_meas = y_true.copy()
            for measure, idx in sensor_ops:
                y_meas[idx] = measure(y_meas[idx])
            y_rec[step] = y_meas
        v = v_rec[step]
        v[:] = u_delayed[step]
        if actuator_ops:
            if same_speed:
                speed = y_true
            else:
                np.multiply(speed_rows, state, out=weighted)
                speed = weighted.sum(axis=0)
            for actuate, idx in actuator_ops:
                v[idx] = actuate(v[idx], speed[idx])
        v += bias
        stacked[order] = v
        np.multiply(transition, stacked, out=products)  # x[k+1] = Phi x[k] + Gamma0 v[k] + Gamma1 v[k-1]
        np.add.reduce(products, axis=1, out=state)
        stacked[order + 1] = v
    if not sensor_ops:
        y_rec = yt_rec.copy()
    return y_rec.T, yt_rec.T, v_rec.T


def _global(group: slice, part):
    """Index of a stage part (relative to its group) in the whole batch."""
    if isinstance(part, slice):
        if part == slice(None):
            return group
        return slice(group.start + part.start, group.start + part.stop)
    return group.start + part
