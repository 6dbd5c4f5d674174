"""Compiled sample-by-sample simulation of plants with actuator and sensor effect blocks (numba).

Two kernels step a batch of rows through time, one row after the other, each sample
with the same floating-point operations, in the same order, as the vectorised numpy
loops they replace, so that their outputs are bit for bit those of the numpy loops:

* :func:`closed_loop_kernel`: the loop of :meth:`gbo_envs.closed_loop.ClosedLoop.simulate`
  (sensor blocks and noise, the first-order controller ``u[k] = b0 e[k] + b1 e[k-1] - a1 u[k-1]``
  or a controller state space of any order with an output limit and anti-windup, the input delay,
  actuator blocks, the plant);
* :func:`open_loop_kernel`: the replay of recorded commands of
  :func:`agents.twin.open_loop.simulate_open_loop` (actuator blocks, a plant-input bias, the
  plant, sensor blocks), each row with its own plant (of any order) and blocks.

Both advance the plant by its exact zero-order-hold model with the delay folded in
(:meth:`gbo_envs.physics.lti.ContinuousPlant.discretize`)::

    x[k+1] = Phi x[k] + Gamma0 v[k] + Gamma1 v[k-1],    y[k] = c x[k],

each sum accumulated from left to right in the order written (state columns first).

Blocks the kernels know are those of :data:`KERNEL_CODES` (every actuator and sensor block
of the catalogue, the rigs' encoders and the static input and output maps), matched by exact
class: a subclass, or any other :class:`~gbo_envs.physics.block.EffectBlock`, makes the caller
keep its numpy loop.
:func:`pack_blocks` turns the blocks of a batch into arrays: an integer code per row and
block position, the block's numeric parameters (one value per row: merged candidate
blocks carry per-row parameter arrays) and its state (backlash, cogging, encoder). Random
numbers (encoder jitter, the speed encoder's disc phase) are drawn in Python before the
kernel runs, in the order the numpy loop draws them (:func:`draw_sensor_noise`), so that
seeded simulations give the same numbers on both paths. What needs no stepping (rest
states, holding commands, the random start angle of cogging) stays in Python.

The kernels are compiled on first use and cached on disk (``cache=True``: numba's cache
folder next to this file, or a per-user folder when the package folder is read-only, or
``NUMBA_CACHE_DIR``), so only the first process pays the compile time
(:func:`warm_up` measures it).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from gbo_envs.physics.actuator import Backlash, Cogging, DeadZone, Offset, Saturation
from gbo_envs.physics.block import EffectBlock, RowNoise
from gbo_envs.physics.encoder import PositionEncoder, SpeedEncoder
from gbo_envs.physics.friction import CoulombFriction, Stiction, ViscousFriction
from gbo_envs.physics.sensor import Quantization
from gbo_envs.physics.static_map import N_KNOTS, InputMap, OutputMap

__all__ = ["KERNEL_CODES", "LANES", "N_PARAMS", "PackedBlocks", "closed_loop_kernel", "draw_sensor_noise", "known",
           "actuators_kernel", "lfilter_kernel", "lfilter_rows", "open_loop_direct_kernel", "open_loop_kernel",
           "pack_blocks", "step_actuators", "warm_up"]

# block codes (0: no block, a padding position of a row with fewer blocks than others)
_NONE = 0
_SATURATION = 1
_DEAD_ZONE = 2
_COULOMB = 3
_VISCOUS = 4
_STICTION = 5
_BACKLASH = 6
_OFFSET_ACTUATOR = 7
_COGGING = 8
_INPUT_MAP = 9
_OFFSET_SENSOR = 20
_QUANTIZATION = 21
_POSITION_ENCODER = 22
_SPEED_ENCODER = 23
_OUTPUT_MAP = 24

#: Block class -> kernel code (``Offset`` by its side: the actuator code, the sensor one is its own).
KERNEL_CODES: dict[type, int] = {
    Saturation: _SATURATION, DeadZone: _DEAD_ZONE, CoulombFriction: _COULOMB, ViscousFriction: _VISCOUS,
    Stiction: _STICTION, Backlash: _BACKLASH, Offset: _OFFSET_ACTUATOR, Cogging: _COGGING,
    Quantization: _QUANTIZATION, PositionEncoder: _POSITION_ENCODER, SpeedEncoder: _SPEED_ENCODER,
    InputMap: _INPUT_MAP, OutputMap: _OUTPUT_MAP,
}
#: Numeric parameters per block position (the most any block needs: a static map's breakpoints, values and weight).
N_PARAMS = 2 * N_KNOTS + 1
#: State entries of the speed encoder before its ring of counts: angle, last speed, ring slot.
_ENCODER_HEAD = 3
_EPS = float(np.finfo(float).eps)  # numpy's sinc replaces a zero argument by it


def known(block: EffectBlock) -> bool:
    """Whether the kernels simulate ``block`` (its exact class is in :data:`KERNEL_CODES`)."""
    return type(block) in KERNEL_CODES


# -- packing ---------------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class PackedBlocks:
    """The blocks of one side for a batch of rows, as the kernels read them.

    Attributes
    ----------
    code : ndarray of int64, shape (batch, slots)
        Kernel code of the block at each position of each row (0: none).
    params : ndarray of float64, shape (batch, slots, N_PARAMS)
        Its numeric parameters, in the units of the block's parameters.
    state : ndarray of float64, shape (batch, slots, width)
        Its state at the start (backlash: transmitted input; cogging: position; speed encoder:
        angle in increments, last speed, ring slot, then the counts of the ring).
    noise : ndarray of int64, shape (batch, slots)
        Column of the row's random numbers in the kernel's noise matrix, or -1 (none).
    """

    code: np.ndarray
    params: np.ndarray
    state: np.ndarray
    noise: np.ndarray


def _per_row(value, rows: int) -> np.ndarray:
    """A block parameter (a float, or per-row values of a merged block) as shape (rows,)."""
    return np.broadcast_to(np.asarray(value, dtype=float).reshape(-1), (rows,))


def _block_params(block: EffectBlock, rows: int, dt: float) -> tuple[int, list, int]:
    """Kernel code, parameter columns and state width of ``block`` on ``rows`` rows at sample time ``dt``."""
    code = KERNEL_CODES[type(block)]
    if code == _OFFSET_ACTUATOR and block.side == "sensor":
        return _OFFSET_SENSOR, [block.value], 1
    if code == _SATURATION:
        return code, [block.limit], 1
    if code in (_DEAD_ZONE, _BACKLASH):
        return code, [block.width], 1
    if code == _COULOMB:
        return code, [block.torque, block.smoothing, block.asymmetry], 1
    if code == _VISCOUS:
        return code, [block.coefficient], 1
    if code == _STICTION:
        return code, [block.breakaway, block.threshold], 1
    if code == _OFFSET_ACTUATOR:
        return code, [block.value], 1
    if code == _COGGING:
        return code, [block.amplitude, block.period, block.phase, dt], 1
    if code in (_INPUT_MAP, _OUTPUT_MAP):
        return code, [*block.knots, *block.values, block.weight], 1
    if code == _QUANTIZATION:
        return code, [block.step, 1.0 if block.mode == "floor" else 0.0], 1
    if code == _POSITION_ENCODER:
        return code, [block.resolution, block.jitter], 1
    # speed encoder, as its reset(): jitter and trapezoid factor in increments, speed per count in rad/s
    increment = block.increment
    return code, [block.jitter / increment, dt / (2.0 * increment), block.speed_resolution(dt),
                  float(block.window)], _ENCODER_HEAD + block.window


def _block_state(block: EffectBlock, code: int, rows: int) -> np.ndarray | None:
    """Start state (shape (rows,)) of a stateful block after ``command_for``, else None."""
    if code == _BACKLASH:
        return _per_row(block.transmitted, rows)
    if code == _COGGING:
        return _per_row(block.position, rows)
    return None


def pack_blocks(parts, batch: int, dt: float) -> PackedBlocks | None:
    """Arrays of the blocks of one side of a batch, or None if one block is unknown to the kernels.

    Parameters
    ----------
    parts : sequence of (slot, block, rows)
        Block ``block`` acts at position ``slot`` (0 first in the order of application) of the
        rows ``rows`` (an index or slice of the batch); its parameters are floats or per-row
        arrays of shape (number of rows,) (merged blocks). Stateful blocks must have been
        started (``reset`` and, on the actuator side, ``command_for``).
    batch : int
        Rows of the batch.
    dt : float
        Sample time in s.
    """
    parts = list(parts)
    if not all(known(block) for _, block, _ in parts):
        return None
    slots = max((slot + 1 for slot, _, _ in parts), default=0)
    packed = [(slot, block, rows, *_block_params(block, len(range(batch)[rows]), dt)) for slot, block, rows in parts]
    width = max((w for *_, w in packed), default=1)
    code = np.zeros((batch, slots), dtype=np.int64)
    params = np.zeros((batch, slots, N_PARAMS))
    state = np.zeros((batch, slots, width))
    for slot, block, rows, kind, values, _ in packed:
        size = len(range(batch)[rows])
        code[rows, slot] = kind
        for j, value in enumerate(values):
            params[rows, slot, j] = _per_row(value, size)
        start = _block_state(block, kind, size)
        if start is not None:
            state[rows, slot, 0] = start
    return PackedBlocks(code=code, params=params, state=state, noise=np.full((batch, slots), -1, dtype=np.int64))


def draw_sensor_noise(sensors: PackedBlocks, blocks, rng: np.random.Generator | None, n_steps: int,
                      draws=None) -> np.ndarray:
    """Random numbers of the sensor blocks of a closed loop, drawn as its numpy loop draws them.

    The numpy loop calls the sensors in order at every sample; a noisy block draws one
    value per draw index (:class:`~gbo_envs.physics.block.RowNoise`), and the speed encoder
    draws its disc phase and the jitter of its window's past counts at its first call. Here
    the first sample's numbers are drawn block by block in that order, then those of all
    later samples at once (numpy fills an array of normal values in the order of the
    equivalent sequence of calls). The draw index of each row and block goes into
    ``sensors.noise``, the speed encoder's first-call numbers into its state.

    Parameters
    ----------
    sensors : PackedBlocks
        The sensor blocks (every row has the same chain), filled in place.
    blocks : sequence of EffectBlock
        The sensor blocks in order, one per slot of ``sensors``.
    rng : numpy.random.Generator or None
        The loop's generator (None: no noisy sensor may be present).
    n_steps : int
        Samples of the experiment.
    draws : array_like of int, shape (batch,), optional
        Draw index of each row (common random numbers), as for the loop.

    Returns
    -------
    ndarray of shape (n_steps, columns)
        Normal values; row ``r``'s value for slot ``j`` at sample ``k`` is at column
        ``sensors.noise[r, j]``.
    """
    batch = sensors.code.shape[0]
    noisy = [(slot, block) for slot, block in enumerate(blocks) if block.stochastic]
    if not noisy:
        return np.zeros((n_steps, 0))
    columns, first = 0, []
    for slot, block in noisy:
        noise = RowNoise(rng, batch, draws)
        stepping = sensors.params[0, slot, 0] != 0.0 if type(block) is SpeedEncoder else True
        if type(block) is SpeedEncoder:  # its first call: the disc's phase, then the window's past jitter
            sensors.state[:, slot, 0] = noise.uniform()
            if stepping:
                sensors.state[:, slot, _ENCODER_HEAD : _ENCODER_HEAD + block.window] = noise.standard_normal(
                    block.window).T
        if stepping:
            first.append(rng.standard_normal(noise.size))
            sensors.noise[:, slot] = columns + noise.columns
            columns += noise.size
    out = np.empty((n_steps, columns))
    out[:1] = np.concatenate(first) if first else 0.0
    out[1:] = rng.standard_normal((n_steps - 1, columns))
    return out


# -- the blocks, one row and one sample ------------------------------------------------------------------------------

# cache=True: compiled once, then loaded from numba's cache; nogil: other threads run meanwhile; error_model="numpy":
# a division by zero gives inf or NaN as in numpy (no exception check)
_jit = njit(cache=True, nogil=True, error_model="numpy")
_inline = njit(cache=True, nogil=True, error_model="numpy", inline="always")

@_inline
def _maximum(a, b):
    """``numpy.maximum`` of two floats (a NaN wins)."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a >= b else b


@_inline
def _minimum(a, b):
    """``numpy.minimum`` of two floats (a NaN wins)."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a <= b else b


@_inline
def _clip(a, low, high):
    """``numpy.clip``: ``minimum(maximum(a, low), high)``."""
    return _minimum(_maximum(a, low), high)


@_inline
def _sign(a):
    """``numpy.sign`` of a float (NaN stays NaN)."""
    if a > 0.0:
        return 1.0
    if a < 0.0:
        return -1.0
    return a * 0.0  # 0 (or NaN)


@_inline
def _sinc(x):
    """``numpy.sinc``: ``sin(pi x) / (pi x)``, the argument 0 replaced by the machine epsilon."""
    y = math.pi * x
    if y == 0.0:
        y = _EPS
    return math.sin(y) / y


@_inline
def _saturated(u, limit):
    """``Saturation.actuate``: ``clip(u, -limit, limit)``."""
    return _minimum(_maximum(u, -limit), limit)


@_inline
def _dead_zoned(u, width):
    """``DeadZone.actuate``: ``u - clip(u, -width/2, width/2)``."""
    half = width / 2.0
    return u - _clip(u, -half, half)


@_inline
def _segment(x, k_lo, k_hi, v_lo, v_hi):
    """``numpy.interp`` at ``x`` on the segment ``[k_lo, k_hi)`` of its breakpoints: its operations, its order."""
    if x == k_lo:
        return v_lo
    slope = (v_hi - v_lo) / (k_hi - k_lo)
    out = slope * (x - k_lo) + v_lo
    if math.isnan(out):  # numpy's fallback: from the other end, then the flat segment's value
        out = slope * (x - k_hi) + v_hi
        if math.isnan(out) and v_lo == v_hi:
            out = v_lo
    return out


@_inline
def _mapped(par, r, j, x):
    """``_PiecewiseLinearMap.map`` (:mod:`gbo_envs.physics.static_map`): ``(1 - w) x + w m(x)``, ``m`` through the
    breakpoints ``par[r, j, 0:5]`` and values ``par[r, j, 5:10]``, continued with the outer slopes; ``w`` is
    ``par[r, j, 10]``."""
    weight = par[r, j, 2 * N_KNOTS]
    if weight == 0.0:
        return x
    last = N_KNOTS - 1
    k_first, k_last = par[r, j, 0], par[r, j, last]
    v_first, v_last = par[r, j, N_KNOTS], par[r, j, N_KNOTS + last]
    if x < k_first:
        m = v_first + (par[r, j, N_KNOTS + 1] - v_first) / (par[r, j, 1] - k_first) * (x - k_first)
    elif x > k_last:
        m = v_last + (v_last - par[r, j, N_KNOTS + last - 1]) / (k_last - par[r, j, last - 1]) * (x - k_last)
    elif math.isnan(x):
        m = x
    elif x == k_last:
        m = v_last
    else:
        i = 0
        while x >= par[r, j, i + 1]:
            i += 1
        m = _segment(x, par[r, j, i], par[r, j, i + 1], par[r, j, N_KNOTS + i], par[r, j, N_KNOTS + i + 1])
    return (1.0 - weight) * x + weight * m


@_inline
def _static_actuate(code, par, r, j, u):
    """Plant input of a static actuator map (saturation, dead zone, offset, input map: no speed, no state), else
    ``u``."""
    if code == _SATURATION:
        return _saturated(u, par[r, j, 0])
    if code == _DEAD_ZONE:
        return _dead_zoned(u, par[r, j, 0])
    if code == _OFFSET_ACTUATOR:
        return u + par[r, j, 0]
    if code == _INPUT_MAP:
        return _mapped(par, r, j, u)
    return u


@_inline
def _actuate(code, par, state, r, j, u, speed):
    """Plant input of actuator block ``j`` of row ``r`` for the command ``u`` at mechanical ``speed``.

    The formulas of the blocks' ``actuate`` (:mod:`gbo_envs.physics.actuator`,
    :mod:`gbo_envs.physics.friction`), in input units; ``state`` is updated.
    """
    if code == _SATURATION:
        return _saturated(u, par[r, j, 0])
    if code == _DEAD_ZONE:
        return _dead_zoned(u, par[r, j, 0])
    if code == _COULOMB:
        # f = level(sign of speed) * sign(speed) while moving; at rest friction balances the drive up to its level
        # (Karnopp); with smoothing the sign is the ramp clip(speed / smoothing, -1, 1)
        torque, smoothing, asymmetry = par[r, j, 0], par[r, j, 1], par[r, j, 2]
        level = torque * (1.0 + asymmetry) if speed > 0.0 else torque * (1.0 - asymmetry)
        if smoothing > 0.0:
            return u - level * _clip(speed / smoothing, -1.0, 1.0)
        if speed == 0.0:
            return u - _clip(u, -(torque * (1.0 - asymmetry)), torque * (1.0 + asymmetry))
        return u - level * _sign(speed)
    if code == _VISCOUS:
        return u - par[r, j, 0] * speed
    if code == _STICTION:
        breakaway = par[r, j, 0]
        if abs(speed) <= par[r, j, 1]:
            return u - _clip(u, -breakaway, breakaway)
        return u - 0.0
    if code == _BACKLASH:  # play operator: v[k] = clip(v[k-1], u - width/2, u + width/2)
        half = par[r, j, 0] / 2.0
        held = _minimum(_maximum(state[r, j, 0], u - half), u + half)
        state[r, j, 0] = held
        return held
    if code == _OFFSET_ACTUATOR:
        return u + par[r, j, 0]
    if code == _INPUT_MAP:
        return _mapped(par, r, j, u)
    if code == _COGGING:
        # ripple averaged over the sample: amplitude sin(a + b/2) sinc(b / 2 pi), a = 2 pi theta / period + phase,
        # b = 2 pi speed dt / period; then theta[k+1] = theta[k] + speed dt
        amplitude, period, phase, dt = par[r, j, 0], par[r, j, 1], par[r, j, 2], par[r, j, 3]
        per_position = 2.0 * math.pi / period
        travel = per_position * speed * dt
        angle = per_position * state[r, j, 0] + phase
        out = u + amplitude * math.sin(angle + travel / 2.0) * _sinc(travel / (2.0 * math.pi))
        state[r, j, 0] = state[r, j, 0] + speed * dt
        return out
    return u


@_inline
def _quantized(y, step, floor):
    """``Quantization.measure``: ``step floor(y / step)`` (``floor``) or ``step rint(y / step)``; ``y`` at step 0."""
    if step == 0.0:
        return y
    if floor != 0.0:
        return step * np.floor(y / step)
    return step * np.rint(y / step)


@_inline
def _static_measure(code, par, r, j, y):
    """Measurement of a static sensor map (offset, quantization, output map: no noise, no state), else ``y``."""
    if code == _OFFSET_SENSOR:
        return y + par[r, j, 0]
    if code == _QUANTIZATION:
        return _quantized(y, par[r, j, 0], par[r, j, 1])
    if code == _OUTPUT_MAP:
        return _mapped(par, r, j, y)
    return y


@_inline
def _measure(code, par, state, r, j, y, noise, k, column):
    """Measurement of sensor block ``j`` of row ``r`` at sample ``k`` of the output ``y`` (output units).

    The formulas of the blocks' ``measure`` (:mod:`gbo_envs.physics.sensor`,
    :mod:`gbo_envs.physics.encoder`, :class:`~gbo_envs.physics.actuator.Offset`); a noisy
    block reads its normal value at ``noise[k, column]``; ``state`` is updated.
    """
    if code == _OFFSET_SENSOR:
        return y + par[r, j, 0]
    if code == _QUANTIZATION:
        return _quantized(y, par[r, j, 0], par[r, j, 1])
    if code == _OUTPUT_MAP:
        return _mapped(par, r, j, y)
    if code == _POSITION_ENCODER:  # q round((y + nu) / q), nu ~ N(0, jitter^2)
        resolution = par[r, j, 0]
        scaled = y / resolution
        if column >= 0:
            scaled = scaled + (par[r, j, 1] / resolution) * noise[k, column]
        return resolution * np.rint(scaled)
    if code == _SPEED_ENCODER:
        # angle in increments (trapezoid rule), count = floor(angle + jitter), speed = counts over the window
        jitter, half_sample, per_count = par[r, j, 0], par[r, j, 1], par[r, j, 2]
        window = int(par[r, j, 3])
        head = _ENCODER_HEAD
        if k == 0:  # at rest at speed y before the step: the last window counts of a constant rotation
            angle = state[r, j, 0]
            for m in range(window):
                past = angle - (2.0 * half_sample) * y * float(window - m)
                if jitter != 0.0:
                    past = past + jitter * state[r, j, head + m]
                state[r, j, head + m] = np.floor(past)
            state[r, j, 2] = 0.0
        else:
            angle = state[r, j, 0] + half_sample * (y + state[r, j, 1])
        state[r, j, 0] = angle
        state[r, j, 1] = y
        if jitter != 0.0:
            count = np.floor(angle + jitter * noise[k, column])
        else:
            count = np.floor(angle)
        slot = int(state[r, j, 2])
        speed = (count - state[r, j, head + slot]) * per_count
        state[r, j, head + slot] = count
        state[r, j, 2] = float((slot + 1) % window)
        return speed
    return y


# -- linear filters: scipy.signal.lfilter's direct form II transposed ------------------------------------------------

#: Rows a linear-filter loop advances side by side, one lane each: their recursions are independent, so the lanes
#: run in one vector register and one row's multiply-add chain runs while another's waits (12 x 9 rows of 2,501
#: samples, a filter of 4 coefficients: 2.8 ns a sample; one row at a time 5.4 ns; scipy's lfilter 6.0 ns).
LANES = 4


@_inline
def _lane_coefficients(b, a, nb, na, r, q, bb, aa):
    """Row ``r``'s coefficients as ``lfilter`` prepares them, into lane ``q`` of ``bb`` and ``aa`` (shape
    (width, LANES)): both padded with zeros to ``max(nb[r], na[r])`` (returned) and divided by ``a[r, 0]``."""
    length = max(nb[r], na[r])
    a0 = a[r, 0]
    for i in range(length):
        bb[i, q] = (b[r, i] if i < nb[r] else 0.0) / a0
        aa[i, q] = (a[r, i] if i < na[r] else 0.0) / a0
    return length


@_inline
def _df2t_lanes(z, bb, aa, length, xs, ys):
    """One sample of ``lfilter``'s direct form II transposed in every lane (state ``z[:, q]``): ``ys`` for ``xs``.

    ``y = z_0 + b_0 x``, ``z_i = z_(i+1) + x b_(i+1) - y a_(i+1)``, ``z_(L-2) = x b_(L-1) - y a_(L-1)``: the
    operations of scipy's C loop, in its order, so the outputs are its own bit for bit.
    """
    for q in range(LANES):
        x = xs[q]
        y = z[0, q] + bb[0, q] * x
        for i in range(length - 2):
            z[i, q] = z[i + 1, q] + x * bb[i + 1, q] - y * aa[i + 1, q]
        z[length - 2, q] = x * bb[length - 1, q] - y * aa[length - 1, q]
        ys[q] = y


@_inline
def _df2t(z, bb, aa, length, xs, ys):
    """:func:`_df2t_lanes` with the length a constant where it is common (the compiler unrolls those loops: 2-3x
    faster than a loop of unknown length)."""
    if length == 3:
        _df2t_lanes(z, bb, aa, 3, xs, ys)
    elif length == 4:
        _df2t_lanes(z, bb, aa, 4, xs, ys)
    elif length == 5:
        _df2t_lanes(z, bb, aa, 5, xs, ys)
    else:
        _df2t_lanes(z, bb, aa, length, xs, ys)


@_inline
def _lane_scratch(width):
    """The lanes' coefficients ``bb``, ``aa`` and state ``z`` (shape (width, LANES)), their inputs and outputs
    ``xs``, ``ys`` and the row of each lane."""
    return (np.zeros((width, LANES)), np.zeros((width, LANES)), np.zeros((width, LANES)), np.zeros(LANES),
            np.zeros(LANES), np.zeros(LANES, dtype=np.int64))


@_inline
def _lane_block(nb, na, first, rows):
    """Rows from ``first`` that share one lane block: at most :data:`LANES`, all of the same filter length."""
    length = max(nb[first], na[first])
    count = 1
    while count < LANES and first + count < rows and max(nb[first + count], na[first + count]) == length:
        count += 1
    return count


@_inline
def _start_lanes(b, a, nb, na, first, count, bb, aa, z, lane_row):
    """Coefficients and zero state of the lanes of the block of ``count`` rows from ``first``; a lane beyond
    ``count`` repeats the block's last row (its results are not written). Returns the block's filter length."""
    length = 0
    for q in range(LANES):
        r = first + min(q, count - 1)
        lane_row[q] = r
        length = _lane_coefficients(b, a, nb, na, r, q, bb, aa)
        for i in range(bb.shape[0]):
            z[i, q] = 0.0
    return length


@_jit
def lfilter_kernel(b, a, nb, na, x, source, shift, out):
    """``out[r, shift:] = lfilter(b[r, :nb[r]], a[r, :na[r]], x[source[r], : n - shift])``, zero before ``shift``.

    Parameters
    ----------
    b, a : ndarray of shape (rows, width)
        Numerator and denominator of each row in powers of ``z^-1`` (``na[r] >= 2``, ``a[r, 0] != 0``), their
        first ``nb[r]`` and ``na[r]`` entries used.
    nb, na : ndarray of int64, shape (rows,)
    x : ndarray of shape (signals, n)
        Inputs; row ``r`` filters ``x[source[r]]``.
    source : ndarray of int64, shape (rows,)
    shift : int
        Whole samples the output lags the input (a delay; ``0 <= shift``).
    out : ndarray of shape (rows, n)
        Filled.
    """
    rows, n = out.shape
    bb, aa, z, xs, ys, lane_row = _lane_scratch(max(b.shape[1], a.shape[1]))
    lead = min(shift, n)
    first = 0
    while first < rows:
        count = _lane_block(nb, na, first, rows)
        length = _start_lanes(b, a, nb, na, first, count, bb, aa, z, lane_row)
        for q in range(count):
            for k in range(lead):
                out[first + q, k] = 0.0
        for k in range(lead, n):
            for q in range(LANES):
                xs[q] = x[source[lane_row[q]], k - shift]
            _df2t(z, bb, aa, length, xs, ys)
            for q in range(count):
                out[first + q, k] = ys[q]
        first += count


def lfilter_rows(b: np.ndarray, a: np.ndarray, x: np.ndarray, source: np.ndarray | None = None,
                 shift: int = 0) -> np.ndarray:
    """``scipy.signal.lfilter`` of many rows at once, compiled, with the same numbers bit for bit.

    Row ``r`` of the result is ``lfilter(b[r], a[r], x[source[r]])`` delayed by ``shift`` samples
    (zeros first); a 1-D ``b`` or ``a`` is the same filter for every row.

    Parameters
    ----------
    b, a : array_like of shape (rows, nb), (rows, na), or 1-D
        Numerators and denominators in powers of ``z^-1``; a denominator has at least two coefficients
        (a recursive filter), the first nonzero.
    x : array_like of shape (signals, n)
        Input signals.
    source : array_like of int, shape (rows,), optional
        The signal each row filters (default: row ``r`` filters ``x[r]``).
    shift : int, default 0
        Whole samples of delay of every output.

    Returns
    -------
    ndarray of shape (rows, n)
    """
    x = np.ascontiguousarray(x, dtype=float)
    if not x.flags.writeable:  # one compiled signature: numba types a read-only array apart (and compiles again)
        x = x.copy()
    if x.ndim != 2:
        raise ValueError(f"x: expected a 2-D array of signals, got shape {x.shape}")
    source = np.arange(x.shape[0], dtype=np.int64) if source is None else np.ascontiguousarray(source, dtype=np.int64)
    rows = source.size
    b, a = (np.array(np.broadcast_to(np.atleast_2d(np.asarray(c, dtype=float)), (rows, np.shape(c)[-1])), order="C")
            for c in (b, a))  # fresh writeable C arrays: one compiled signature
    if a.shape[1] < 2 or not np.all(a[:, 0] != 0.0):  # lfilter convolves when a has one coefficient
        raise ValueError(f"a: need a denominator of at least 2 coefficients, the first nonzero; got shape {a.shape}")
    if shift < 0:
        raise ValueError(f"shift: must be >= 0 samples, got {shift}")
    out = np.empty((rows, x.shape[1]))
    nb, na = np.full(rows, b.shape[1], dtype=np.int64), np.full(rows, a.shape[1], dtype=np.int64)
    lfilter_kernel(b, a, nb, na, x, source, int(shift), out)
    return out


# -- the loops -------------------------------------------------------------------------------------------------------

@_inline
def _state_space_law(a, b, c, d, injection, clamp, limit, r, e, step, u_rest, xc, xc_next):
    """One sample of row ``r``'s controller state space (its state ``xc`` advanced in place): the command ``u``.

    The operations of :class:`gbo_envs.closed_loop._NumpyLaw`, in its order.
    """
    n = xc.shape[0]
    v = u_rest + d[r, 0] * e
    v = v + d[r, 1] * step
    for i in range(n):
        v = v + c[r, i] * xc[i]
    u = _minimum(_maximum(v, -limit), limit)
    excess = u - v
    for i in range(n):
        acc = b[r, i, 0] * e
        acc = acc + b[r, i, 1] * step
        for m in range(n):
            acc = acc + a[r, i, m] * xc[m]
        acc = acc + injection[r, i] * excess
        if clamp[i] != 0.0 and excess != 0.0 and c[r, i] * (acc - xc[i]) * excess < 0.0:
            acc = xc[i]
        xc_next[i] = acc
    for i in range(n):
        xc[i] = xc_next[i]
    return u


@_jit
def closed_loop_kernel(phi, gamma0, gamma1, c, speed_row, fractional, speed_is_output, lag, r2, b0, b1, a1,
                       ctrl_a, ctrl_b, ctrl_c, ctrl_d, ctrl_injection, ctrl_clamp, ctrl_limit, step,
                       x0, v_prev0, u_start, sensors_code, sensors_params, sensors_state, sensors_noise,
                       actuators_code, actuators_params, actuators_state, sensor_noise, output_noise,
                       u_out, y_out):
    """Step a batch of closed loops, row by row, writing the commands ``u_out`` and measurements ``y_out``.

    At sample ``k``: the sensor blocks (then the white noise ``output_noise[r, k]``, if
    given) turn ``c x[k]`` into the measurement ``y[k]``; the controller computes
    ``u[k] = b0 e[k] + b1 e[k-1] - a1 u[k-1]`` with ``e = r2 - y`` (before the record
    ``e = 0``, ``u = u_start``), or, when it has states (``ctrl_a`` of shape (batch, n_c, n_c),
    ``n_c > 0``), runs its state space of
    :class:`~gbo_envs.controllers.base.DiscreteStateSpace` on ``w = [e, step]`` from zero state
    (``v = u_start + D w + C x_c``, ``u = clip(v, -limit, limit)``,
    ``x_c[k+1] = A x_c + B w + L (u - v)``, clamped states held); the actuator blocks turn the
    delayed command ``u[k - lag]`` into the plant input ``v[k]`` at the mechanical speed
    (``y_true``, or ``speed_row x[k]`` for a position output); and
    ``x[k+1] = Phi x[k] + Gamma0 v[k] + Gamma1 v[k-1]`` (the ``Gamma1`` term only when ``fractional``).

    Parameters
    ----------
    phi, gamma0, gamma1, c, speed_row : ndarray
        The sampled plant, shapes (n, n), (n,), (n,), (n,), (n,).
    fractional, speed_is_output : bool
    lag : int
        Whole samples of input delay.
    r2 : float
        Reference after the step, in output units.
    b0, b1, a1 : ndarray of shape (batch,)
        Controller coefficients of each row (first-order recursion).
    ctrl_a, ctrl_b, ctrl_c, ctrl_d, ctrl_injection : ndarray
        The controller state space of each row, shapes (batch, n_c, n_c), (batch, n_c, 2), (batch, n_c),
        (batch, 2), (batch, n_c); ``n_c = 0``: the first-order recursion.
    ctrl_clamp : ndarray of shape (n_c,)
        Nonzero for the states held by conditional integration.
    ctrl_limit : float
        Output limit of the controller in input units (``inf``: none).
    step : float
        Reference step ``r2 - r1`` in output units.
    x0 : ndarray of shape (batch, n)
        Plant state at rest.
    v_prev0, u_start : ndarray of shape (batch,)
        Plant input and command before the record.
    sensors_*, actuators_* : ndarray
        The fields of the two :class:`PackedBlocks` (their states are updated).
    sensor_noise : ndarray of shape (n_steps, columns)
        Normal values of the noisy sensor blocks (:func:`draw_sensor_noise`).
    output_noise : ndarray of shape (batch, n_steps) or (0, 0)
        White sensor noise in output units (none if empty).
    u_out, y_out : ndarray of shape (batch, n_steps)
        Filled with the commands and the measurements.
    """
    batch, n_steps = y_out.shape
    order = phi.shape[0]
    n_sensors = sensors_code.shape[1]
    n_actuators = actuators_code.shape[1]
    noisy = output_noise.shape[0] > 0
    x = np.empty(order)
    x_next = np.empty(order)
    n_ctrl = ctrl_a.shape[1]
    xc = np.zeros(n_ctrl)
    xc_next = np.zeros(n_ctrl)
    for r in range(batch):
        for i in range(order):
            x[i] = x0[r, i]
        for i in range(n_ctrl):
            xc[i] = 0.0
        v_prev = v_prev0[r]
        u_prev = u_start[r]
        e_prev = 0.0
        for k in range(n_steps):
            y_true = c[0] * x[0]
            for i in range(1, order):
                y_true += c[i] * x[i]
            y = y_true
            for j in range(n_sensors):
                y = _measure(sensors_code[r, j], sensors_params, sensors_state, r, j, y, sensor_noise, k,
                             sensors_noise[r, j])
            if noisy:
                y = y + output_noise[r, k]
            y_out[r, k] = y
            e = r2 - y
            if n_ctrl == 0:
                u = b0[r] * e + b1[r] * e_prev - a1[r] * u_prev
            else:
                u = _state_space_law(ctrl_a, ctrl_b, ctrl_c, ctrl_d, ctrl_injection, ctrl_clamp, ctrl_limit, r, e,
                                     step, u_start[r], xc, xc_next)
            u_out[r, k] = u
            u_prev = u
            e_prev = e
            v = u_out[r, k - lag] if k >= lag else u_start[r]
            if n_actuators:
                if speed_is_output:
                    speed = y_true
                else:
                    speed = speed_row[0] * x[0]
                    for i in range(1, order):
                        speed += speed_row[i] * x[i]
                for j in range(n_actuators):
                    v = _actuate(actuators_code[r, j], actuators_params, actuators_state, r, j, v, speed)
            for i in range(order):
                acc = phi[i, 0] * x[0]
                for m in range(1, order):
                    acc += phi[i, m] * x[m]
                acc += gamma0[i] * v
                if fractional:
                    acc += gamma1[i] * v_prev
                x_next[i] = acc
            for i in range(order):
                x[i] = x_next[i]
            v_prev = v


@_jit
def open_loop_kernel(orders, transition, c, speed, u, commands, source, lags, u_rest, bias, x0, v_rest, sensors_code,
                     sensors_params, sensors_state, actuators_code, actuators_params, actuators_state,
                     y_out, y_true_out, v_out):
    """Replay recorded commands through a batch of plants with blocks, row by row.

    Row ``r`` replays the commands ``u[commands[r]]`` delayed by ``lags[r]`` whole samples
    (``u_rest[r]`` before the record) and writes its outputs into row ``source[r]``. At
    sample ``k``: ``y_true[k] = c x[k]``, the sensor blocks give the measurement ``y[k]``, the
    actuator blocks turn the delayed command into the plant input at the mechanical speed
    ``speed x[k]``, the bias is added, ``v[k] = ... + bias``, and
    ``x[k+1] = Phi x[k] + Gamma0 v[k] + Gamma1 v[k-1]`` (``v[-1] = v_rest``).

    Parameters
    ----------
    orders : ndarray of int64, shape (rows,)
        Order ``n_r`` of each row's plant.
    transition : ndarray of shape (rows, n, n + 2)
        ``[Phi Gamma0 Gamma1]`` of each row, its first ``n_r`` rows and columns of ``Phi`` used
        (``n``: the largest order).
    c, speed : ndarray of shape (rows, n)
        Output row and mechanical-speed row of each plant.
    u : ndarray of shape (batch, n_steps)
        Recorded commands, in input units.
    commands, source, lags : ndarray of int64, shape (rows,)
        Row of ``u``, row of the outputs and whole-sample input delay of each row.
    u_rest, bias, v_rest : ndarray of shape (rows,)
        Command before the record, plant-input bias and plant input before the record.
    x0 : ndarray of shape (rows, n)
        Start state.
    sensors_*, actuators_* : ndarray
        The fields of the two :class:`PackedBlocks` (their states are updated).
    y_out, y_true_out, v_out : ndarray of shape (batch, n_steps)
        Filled in the rows ``source`` with the measurement, the plant output and the plant input.
    """
    rows = source.shape[0]
    n_steps = u.shape[1]
    width = transition.shape[1]
    n_sensors = sensors_code.shape[1]
    n_actuators = actuators_code.shape[1]
    x = np.empty(width)
    x_next = np.empty(width)
    empty = np.zeros((1, 1))
    for r in range(rows):
        order = orders[r]
        if order == 2 and _static_sensors(sensors_code, r):  # the common case, its state in registers: 25 % faster
            _replay_second_order(r, transition, c, speed, u, commands, source, lags, u_rest, bias, x0, v_rest,
                                 sensors_code, sensors_params, sensors_state, actuators_code, actuators_params,
                                 actuators_state, y_out, y_true_out, v_out)
            continue
        row = source[r]
        lag = lags[r]
        command = commands[r]
        for i in range(order):
            x[i] = x0[r, i]
        v_prev = v_rest[r]
        b = bias[r]
        for k in range(n_steps):
            y_true = c[r, 0] * x[0]
            for i in range(1, order):
                y_true += c[r, i] * x[i]
            y_true_out[row, k] = y_true
            y = y_true
            for j in range(n_sensors):
                y = _measure(sensors_code[r, j], sensors_params, sensors_state, r, j, y, empty, k, -1)
            y_out[row, k] = y
            v = u[command, k - lag] if k >= lag else u_rest[r]
            if n_actuators:
                s = speed[r, 0] * x[0]
                for i in range(1, order):
                    s += speed[r, i] * x[i]
                for j in range(n_actuators):
                    v = _actuate(actuators_code[r, j], actuators_params, actuators_state, r, j, v, s)
            v = v + b
            v_out[row, k] = v
            for i in range(order):
                acc = transition[r, i, 0] * x[0]
                for m in range(1, order):
                    acc += transition[r, i, m] * x[m]
                acc += transition[r, i, width] * v
                acc += transition[r, i, width + 1] * v_prev
                x_next[i] = acc
            for i in range(order):
                x[i] = x_next[i]
            v_prev = v


@_inline
def _static_sensors(code, r):
    """Whether row ``r``'s sensor blocks are all static maps (offset, quantization, output map:
    :func:`_static_measure`)."""
    for j in range(code.shape[1]):
        if code[r, j] != _NONE and code[r, j] != _OFFSET_SENSOR and code[r, j] != _QUANTIZATION and \
                code[r, j] != _OUTPUT_MAP:
            return False
    return True


@_inline
def _replay_second_order(r, transition, c, speed, u, commands, source, lags, u_rest, bias, x0, v_rest, sensors_code,
                         sensors_params, sensors_state, actuators_code, actuators_params, actuators_state, y_out,
                         y_true_out, v_out):
    """Row ``r`` of :func:`open_loop_kernel` for a plant of two states, held in scalars, and static sensor maps:
    the same operations."""
    n_steps = u.shape[1]
    width = transition.shape[1]
    n_sensors = sensors_code.shape[1]
    n_actuators = actuators_code.shape[1]
    row = source[r]
    lag = lags[r]
    command = commands[r]
    phi00, phi01 = transition[r, 0, 0], transition[r, 0, 1]
    phi10, phi11 = transition[r, 1, 0], transition[r, 1, 1]
    g00, g10 = transition[r, 0, width], transition[r, 0, width + 1]  # Gamma0, Gamma1 of state 0
    g01, g11 = transition[r, 1, width], transition[r, 1, width + 1]  # and of state 1
    c0, c1, s0, s1 = c[r, 0], c[r, 1], speed[r, 0], speed[r, 1]
    x0_, x1_ = x0[r, 0], x0[r, 1]
    v_prev = v_rest[r]
    b = bias[r]
    for k in range(n_steps):
        y_true = c0 * x0_
        y_true += c1 * x1_
        y_true_out[row, k] = y_true
        y = y_true
        for j in range(n_sensors):
            y = _static_measure(sensors_code[r, j], sensors_params, r, j, y)
        y_out[row, k] = y
        v = u[command, k - lag] if k >= lag else u_rest[r]
        if n_actuators:
            s = s0 * x0_
            s += s1 * x1_
            for j in range(n_actuators):
                v = _actuate(actuators_code[r, j], actuators_params, actuators_state, r, j, v, s)
        v = v + b
        v_out[row, k] = v
        a0 = phi00 * x0_
        a0 += phi01 * x1_
        a0 += g00 * v
        a0 += g10 * v_prev
        a1 = phi10 * x0_
        a1 += phi11 * x1_
        a1 += g01 * v
        a1 += g11 * v_prev
        x0_, x1_ = a0, a1
        v_prev = v


@_jit
def open_loop_direct_kernel(num, den, num_len, den_len, u, commands, source, lags, u_rest, bias, v_rest, y_true0,
                            free_row,
                            free, sensors_code, sensors_params, actuators_code, actuators_params, y_out, y_true_out,
                            v_out):
    """Replay recorded commands through memoryless blocks and sampled transfer functions, row by row.

    The rows' actuator blocks are static maps of the command (no speed, no state), so the plant needs
    no state-space stepping: row ``r`` is ``y = S(y_true0 + P(z) (A(u_delayed) + bias - v_rest))`` with
    ``P(z) = num / den`` (in ``z^-1``, without the whole-sample delay ``lags[r]``) filtered as
    ``scipy.signal.lfilter`` does (:func:`_df2t_lanes`), ``A`` the actuator and ``S`` the sensor blocks. A row
    that starts moving (``free_row[r] >= 0``) adds its free response ``free[free_row[r]]`` to the plant
    output before the sensors. The same operations, in the same order, as the numpy path of
    :func:`agents.twin.open_loop.simulate_open_loop`.

    Parameters
    ----------
    num, den : ndarray of shape (rows, width)
        Each row's transfer function, its first ``num_len[r]`` and ``den_len[r]`` entries used.
    num_len, den_len : ndarray of int64, shape (rows,)
    u : ndarray of shape (batch, n_steps)
        Recorded commands, in input units.
    commands, source, lags : ndarray of int64, shape (rows,)
        Row of ``u``, row of the outputs and whole-sample input delay of each row.
    u_rest, bias, v_rest, y_true0 : ndarray of shape (rows,)
        Command before the record, plant-input bias, plant input and true output at rest.
    free_row : ndarray of int64, shape (rows,)
        Row of ``free`` holding the row's free response, or -1.
    free : ndarray of shape (moving, n_steps)
    sensors_code, sensors_params, actuators_code, actuators_params : ndarray
        The codes and parameters of the two :class:`PackedBlocks` (static maps: no state).
    y_out, y_true_out, v_out : ndarray of shape (batch, n_steps)
        Filled in the rows ``source`` with the measurement, the plant output and the plant input.
    """
    rows = source.shape[0]
    n_steps = u.shape[1]
    n_sensors = sensors_code.shape[1]
    n_actuators = actuators_code.shape[1]
    bb, aa, z, xs, ys, lane_row = _lane_scratch(max(num.shape[1], den.shape[1]))
    first = 0
    while first < rows:
        count = _lane_block(num_len, den_len, first, rows)
        length = _start_lanes(num, den, num_len, den_len, first, count, bb, aa, z, lane_row)
        # three passes over the block's rows: the blocks' maps inside the lanes' filter loop slowed it 2.5x
        for r in range(first, first + count):  # the plant input: delayed command, actuator maps, bias
            row = source[r]
            command = commands[r]
            lag = lags[r]
            for k in range(n_steps):
                v = u[command, k - lag] if k >= lag else u_rest[r]
                for j in range(n_actuators):
                    v = _static_actuate(actuators_code[r, j], actuators_params, r, j, v)
                v_out[row, k] = v + bias[r]
        for k in range(n_steps):  # the plant on the deviation from rest, then the free response of a moving start
            for q in range(LANES):
                r = lane_row[q]
                xs[q] = v_out[source[r], k] - v_rest[r]
            _df2t(z, bb, aa, length, xs, ys)
            for q in range(count):
                r = first + q
                y_true = y_true0[r] + ys[q]
                if free_row[r] >= 0:
                    y_true = y_true + free[free_row[r], k]
                y_true_out[source[r], k] = y_true
        for r in range(first, first + count):  # the sensor maps
            row = source[r]
            for k in range(n_steps):
                y = y_true_out[row, k]
                for j in range(n_sensors):
                    y = _static_measure(sensors_code[r, j], sensors_params, r, j, y)
                y_out[row, k] = y
        first += count


@_jit
def actuators_kernel(u, speed, code, params, state, out):
    """``out[r, k]``: the command ``u[r, k]`` through the actuator blocks of row ``r`` at ``speed[r, k]``, sample by
    sample (the blocks' states carried, and updated in ``state``).

    Parameters
    ----------
    u, speed : ndarray of shape (rows, n_steps)
        Commands (input units) and mechanical speeds.
    code, params, state : ndarray
        The fields of the rows' :class:`PackedBlocks` (actuator side).
    out : ndarray of shape (rows, n_steps)
        Filled with the plant inputs.
    """
    rows, n_steps = u.shape
    for r in range(rows):
        for k in range(n_steps):
            v = u[r, k]
            for j in range(code.shape[1]):
                v = _actuate(code[r, j], params, state, r, j, v, speed[r, k])
            out[r, k] = v


def step_actuators(blocks, u: np.ndarray, speed: np.ndarray, dt: float) -> np.ndarray | None:
    """The commands ``u`` through the actuator ``blocks`` (in order; started, e.g. by ``reset``) at the mechanical
    ``speed``, sample by sample: what ``for k: v = u[:, k]; v = block.actuate(v, speed[:, k])`` gives, compiled.

    Parameters
    ----------
    blocks : sequence of EffectBlock
        Actuator blocks for all rows.
    u, speed : array_like of shape (rows, n_steps)
    dt : float
        Sample time in s.

    Returns
    -------
    ndarray of shape (rows, n_steps), or None when a block is unknown to the kernels (:func:`known`).
    """
    u = np.array(u, dtype=float, order="C")  # fresh C arrays: one compiled signature
    speed = np.array(np.broadcast_to(speed, u.shape), dtype=float, order="C")
    packed = pack_blocks([(j, block, slice(None)) for j, block in enumerate(blocks)], u.shape[0], dt)
    if packed is None:
        return None
    out = np.empty_like(u)
    actuators_kernel(u, speed, packed.code, packed.params, packed.state, out)
    return out


def warm_up(which: tuple[str, ...] = ("closed_loop", "open_loop")) -> float:
    """Compile the kernels (or load them from numba's cache) on a tiny problem; the seconds it took.

    Parameters
    ----------
    which : tuple of {"closed_loop", "open_loop"}
        The kernels to compile.
    """
    start = time.perf_counter()
    empty_blocks = (np.zeros((1, 1), dtype=np.int64), np.zeros((1, 1, N_PARAMS)), np.zeros((1, 1, 1)))
    one = np.ones(1)
    if "closed_loop" in which:
        closed_loop_kernel(np.eye(1), one, one, one, one, True, True, 0, 1.0, one, one, one, np.zeros((1, 1, 1)),
                           np.zeros((1, 1, 2)), one[None, :], np.zeros((1, 2)), np.zeros((1, 1)), np.zeros(1), np.inf,
                           1.0, np.zeros((1, 1)), one,
                           one, *empty_blocks, np.full((1, 1), -1, dtype=np.int64), *empty_blocks, np.zeros((2, 0)),
                           np.zeros((0, 0)), np.empty((1, 2)), np.empty((1, 2)))
    if "open_loop" in which:
        index = np.zeros(1, dtype=np.int64)
        open_loop_kernel(np.ones(1, dtype=np.int64), np.ones((1, 1, 3)), np.ones((1, 1)), np.ones((1, 1)),
                         np.ones((1, 2)), index, index, index, one, one, np.zeros((1, 1)), one, *empty_blocks,
                         *empty_blocks, np.empty((1, 2)), np.empty((1, 2)), np.empty((1, 2)))
        two = np.ones((1, 2))
        lengths = np.full(1, 2, dtype=np.int64)
        open_loop_direct_kernel(two, two, lengths, lengths, np.ones((1, 2)), index, index, index, one, one, one, one,
                                np.full(1, -1, dtype=np.int64), np.zeros((0, 2)), *empty_blocks[:2],
                                *empty_blocks[:2], np.empty((1, 2)), np.empty((1, 2)), np.empty((1, 2)))
        lfilter_kernel(two, two, lengths, lengths, np.ones((1, 2)), index, 0, np.empty((1, 2)))
        actuators_kernel(two, two, *empty_blocks, np.empty((1, 2)))
    return time.perf_counter() - start
