"""The compiled open-loop replay gives the numpy loop's numbers, bit for bit, also for rows of different orders.

Rows with every actuator and sensor block the twin fits (one block per row, merged blocks
with per-row parameters, chains of several blocks, memoryless blocks that take the direct
path beside them), speed and position plants, whole and fractional delays, and plants of 2
and 4 poles in one call: :func:`agents.twin.open_loop.simulate_open_loop` through the kernel
equals the numpy stepping (blocks unknown to the kernel), and each row equals that row alone.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.twin.open_loop import simulate_open_loop
from gbo_envs.physics import ContinuousPlant, CoulombFriction, kernels
from gbo_envs.physics.effects import build_effects
from tests.support import leaky_saturation

FAST = settings(max_examples=20, deadline=None, derandomize=True, database=None)
SPEED = ContinuousPlant(num=(9.544,), den=(1.0, 4.145, 4.199), delay=0.002)
SPEED_FRACTIONAL = ContinuousPlant(num=(9.544,), den=(1.0, 4.145, 4.199), delay=0.0051)
POSITION = ContinuousPlant(num=(3.0,), den=(1.0, 2.5, 0.0), delay=0.0031, output="position")
#: four poles (a two-mass resonance at 12 rad/s behind the motor), the same static gain as SPEED
FOUR_POLES = ContinuousPlant(num=(9.544 * 144.0,), den=tuple(np.polymul([1.0, 4.145, 4.199], [1.0, 2.4, 144.0])),
                             delay=0.002)
COMPILED = kernels.open_loop_kernel
#: static maps: a one-way drive whose gain falls with the command, a sensor that clips below 0 and above 30
BELT_DRIVE = {"k0": -1.0, "k1": 0.0, "k2": 1.0, "k3": 3.0, "k4": 5.0, "v0": 0.0, "v1": 0.0, "v2": 2.06, "v3": 3.865,
              "v4": 5.25}
CLIPPING_SENSOR = {"k0": -1.0, "k1": 0.0, "k2": 15.0, "k3": 30.0, "k4": 31.0, "v0": 0.0, "v1": 0.0, "v2": 15.0,
                   "v3": 30.0, "v4": 30.0}

#: one spec per row: every block the twin fits, alone, merged with others of its class and in chains
SPECS = ([{"coulomb_friction": {"torque": t}} for t in (1.0, 2.5, 4.0)]
         + [{"coulomb_friction": {"torque": 3.0, "smoothing": 0.5, "asymmetry": a}} for a in (-0.5, 0.5)]
         + [{"backlash": {"width": w}} for w in (1.0, 3.0)]
         + [{"cogging": {"amplitude": a, "period": 0.7, "phase": 0.3}} for a in (1.0, 2.0)]
         + [{"stiction": {"breakaway": b, "threshold": 0.5}, "saturation": {"limit": 30.0}} for b in (2.0, 6.0)]
         + [{"viscous_friction": {"coefficient": c}, "quantization": {"step": 0.37, "mode": m}}
            for c, m in ((0.1, "round"), (0.2, "floor"))]
         + [{"offset": {"value": 2.0}, "dead_zone": {"width": 3.0}, "backlash": {"width": 1.0}},
            {"viscous_friction": {"coefficient": 0.1}, "offset": {"value": 0.5, "on": "sensor"}},
            {"saturation": {"limit": 20.0}}, {"dead_zone": {"width": 2.0}}, {}]
         # a one-way drive whose gain falls, before a friction (the belt's), and a clipping sensor's map
         + [{"input_map": BELT_DRIVE, "coulomb_friction": {"torque": 1.0, "smoothing": 0.2}},
            {"viscous_friction": {"coefficient": 0.1}, "output_map": CLIPPING_SENSOR}])


def _rows(plants, specs, seed=3, n=600):
    rng = np.random.default_rng(seed)
    chains = [build_effects(s) for s in specs]
    u = np.cumsum(rng.normal(0.0, 2.0, (len(chains), n)), axis=1)  # drifting commands, speed reversals
    return plants, chains, u, rng.normal(0.0, 5.0, len(chains)), rng.normal(0.0, 1.0, len(chains))


def _both_paths(monkeypatch, plants, chains, u, y0, bias):
    calls = []

    def counted(*args):
        calls.append(1)
        COMPILED(*args)

    monkeypatch.setattr(kernels, "open_loop_kernel", counted)
    fast = simulate_open_loop(plants, u, 0.002, chains, y0=y0, bias=bias)
    with monkeypatch.context() as m:
        m.setattr(kernels, "KERNEL_CODES", {})
        slow = simulate_open_loop(plants, u, 0.002, [build_effects(_spec(c)) for c in chains], y0=y0, bias=bias)
    return fast, slow, len(calls)


def _spec(chain) -> list:
    """The effect spec of a chain of blocks (fresh blocks: the batch's have run)."""
    return [(b.name, {**{p: getattr(b, p) for p in b.param_names}, **{o: getattr(b, o) for o in b.options}})
            for b in chain]


def _assert_same(fast, slow):
    for name in ("y", "y_true", "v", "u_rest", "v_rest"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=name)


def test_every_twin_block_replays_the_same_compiled(monkeypatch):
    plants = [(SPEED, SPEED_FRACTIONAL, POSITION)[i % 3] for i in range(len(SPECS))]
    fast, slow, calls = _both_paths(monkeypatch, *_rows(plants, SPECS))
    assert calls == 1
    _assert_same(fast, slow)
    assert np.all(np.isfinite(fast.y)) and np.ptp(fast.y) > 10.0


def test_rows_of_2_and_4_poles_replay_together(monkeypatch):
    specs = [{"coulomb_friction": {"torque": 2.0}}, {"backlash": {"width": 2.0}}, {"saturation": {"limit": 25.0}},
             {"cogging": {"amplitude": 1.0}}, {}]
    plants = [SPEED, FOUR_POLES, FOUR_POLES, SPEED_FRACTIONAL, FOUR_POLES]
    rows = _rows(plants, specs)
    fast, slow, calls = _both_paths(monkeypatch, *rows)
    assert calls == 1
    _assert_same(fast, slow)
    _, _, u, y0, bias = rows
    for row, (plant, spec) in enumerate(zip(plants, specs)):
        alone = simulate_open_loop(plant, u[row], 0.002, build_effects(spec), y0=y0[row], bias=bias[row])
        for name in ("y", "y_true", "v"):
            np.testing.assert_array_equal(getattr(fast, name)[row], getattr(alone, name)[0], err_msg=name)
    # the resonance shows: the 4-pole rows differ from the 2-pole plant under the same input
    two = simulate_open_loop(SPEED, u[1], 0.002, build_effects(specs[1]), y0=y0[1], bias=bias[1])
    assert np.max(np.abs(two.y[0] - fast.y[1])) > 0.1


@FAST
@given(torques=st.lists(st.floats(0.0, 8.0), min_size=2, max_size=5), asymmetry=st.floats(-1.0, 1.0),
       smoothing=st.sampled_from([0.0, 0.3]), seed=st.integers(0, 100))
def test_merged_friction_blocks_replay_the_same_compiled(torques, asymmetry, smoothing, seed):
    specs = [{"coulomb_friction": {"torque": t, "asymmetry": asymmetry, "smoothing": smoothing}} for t in torques]
    with pytest.MonkeyPatch.context() as monkeypatch:
        fast, slow, calls = _both_paths(monkeypatch, *_rows([SPEED] * len(specs), specs, seed=seed, n=300))
    assert calls == 1
    _assert_same(fast, slow)


def test_mixed_orders_replay_in_numpy_too(monkeypatch):
    """The numpy loop (a block the kernel does not know) also takes rows of 2 and 4 poles in one call."""
    monkeypatch.setattr(kernels, "KERNEL_CODES", {})
    plants = [SPEED, FOUR_POLES]
    _, chains, u, y0, bias = _rows(plants, [{"coulomb_friction": {"torque": 2.0}}] * 2)
    both = simulate_open_loop(plants, u, 0.002, chains, y0=y0, bias=bias)
    for row, plant in enumerate(plants):
        alone = simulate_open_loop(plant, u[row], 0.002, (CoulombFriction(2.0),), y0=y0[row], bias=bias[row])
        np.testing.assert_array_equal(both.y[row], alone.y[0])


def test_a_block_the_kernel_does_not_know_replays_in_numpy(monkeypatch):
    calls = []
    monkeypatch.setattr(kernels, "open_loop_kernel", lambda *args: calls.append(1))
    plants, chains, u, y0, bias = _rows([SPEED] * 2, [{}, {}])
    chains = [(leaky_saturation(5.0, 0.1), CoulombFriction(1.0)), (CoulombFriction(1.0),)]
    res = simulate_open_loop(plants, u, 0.002, chains, y0=y0, bias=bias)
    assert calls == []
    assert np.all(np.isfinite(res.y)) and np.max(np.abs(res.v[0])) > 5.0  # the leak passed the limit


#: rows whose blocks are static maps (the direct path): each memoryless block, merged ones with per-row parameters,
#: chains, a sensor offset after a quantizer, and the plant alone
MEMORYLESS_SPECS = ([{"saturation": {"limit": lim}} for lim in (5.0, 12.0, 30.0)]
                    + [{"dead_zone": {"width": w}} for w in (1.0, 4.0)]
                    + [{"offset": {"value": v}} for v in (-2.0, 3.0)]
                    + [{"quantization": {"step": q, "mode": m}} for q, m in ((0.37, "round"), (0.5, "floor"))]
                    + [{"offset": {"value": 0.4, "on": "sensor"}, "quantization": {"step": 0.25}},
                       {"dead_zone": {"width": 2.0}, "saturation": {"limit": 20.0}, "offset": {"value": 1.0}},
                       {"input_map": BELT_DRIVE}, {"output_map": CLIPPING_SENSOR, "offset": {"value": 0.5}},
                       {"input_map": {**BELT_DRIVE, "weight": 0.4}, "saturation": {"limit": 12.0}}, {}, {}])


def _direct_both_paths(monkeypatch, plants, chains, u, y0, bias, initial=None):
    calls = []
    compiled = kernels.open_loop_direct_kernel

    def counted(*args):
        calls.append(1)
        compiled(*args)

    monkeypatch.setattr(kernels, "open_loop_direct_kernel", counted)
    fast = simulate_open_loop(plants, u, 0.002, chains, y0=y0, bias=bias, initial=initial)
    with monkeypatch.context() as m:
        m.setattr(kernels, "KERNEL_CODES", {})
        slow = simulate_open_loop(plants, u, 0.002, [build_effects(_spec(c)) for c in chains], y0=y0, bias=bias,
                                  initial=initial)
    return fast, slow, len(calls)


def test_memoryless_rows_replay_the_same_compiled(monkeypatch):
    """The direct path's kernel (static maps, the plant as ``lfilter`` runs its transfer function) gives the numpy
    path's numbers bit for bit: plants of 2 and 4 poles, speed and position, whole and fractional delays."""
    plants = [(SPEED, SPEED_FRACTIONAL, POSITION, FOUR_POLES)[i % 4] for i in range(len(MEMORYLESS_SPECS))]
    rows = _rows(plants, MEMORYLESS_SPECS)
    fast, slow, calls = _direct_both_paths(monkeypatch, *rows)
    assert calls == 1
    _assert_same(fast, slow)
    assert np.all(np.isfinite(fast.y)) and np.ptp(fast.y) > 10.0
    bias = rows[-1]
    assert np.any(fast.y != fast.y_true) and np.max(np.abs(fast.v[0] - bias[0])) == pytest.approx(5.0)  # they act


@FAST
@given(limits=st.lists(st.floats(0.5, 40.0), min_size=1, max_size=4), step=st.floats(0.01, 2.0),
       slopes=st.lists(st.floats(-50.0, 50.0), min_size=3, max_size=3), seed=st.integers(0, 100))
def test_memoryless_rows_that_start_moving_replay_the_same_compiled(limits, step, slopes, seed):
    """Rows that start moving add their free response before the sensor, in the kernel as in numpy."""
    specs = [{"saturation": {"limit": lim}, "quantization": {"step": step}} for lim in limits] + [{}]
    plants = [FOUR_POLES if i % 2 else SPEED for i in range(len(specs))]
    rows = _rows(plants, specs, seed=seed, n=300)
    initial = np.tile(np.array(slopes), (len(specs), 1))
    initial[0] = 0.0  # one row at rest among the moving ones
    with pytest.MonkeyPatch.context() as monkeypatch:
        fast, slow, calls = _direct_both_paths(monkeypatch, *rows, initial=initial)
    assert calls == 1
    _assert_same(fast, slow)


def test_compiled_lfilter_is_scipys_bit_for_bit():
    """:func:`gbo_envs.physics.kernels.lfilter_rows` against ``scipy.signal.lfilter``: orders 1-6, numerators
    shorter and longer than the denominator, a leading coefficient other than 1, inf and NaN inputs, a shift."""
    from scipy.signal import lfilter

    rng = np.random.default_rng(7)
    for _ in range(300):
        order = int(rng.integers(1, 7))
        a = np.real(np.poly(rng.uniform(-0.999, 0.999, order))) * (rng.uniform(0.1, 10.0) if rng.random() < 0.3 else 1)
        b = rng.normal(size=int(rng.integers(1, order + 4))) * 10.0 ** int(rng.integers(-6, 3))
        x = rng.normal(size=(int(rng.integers(1, 11)), int(rng.integers(1, 120)))) * 100.0
        if rng.random() < 0.1:
            x[0, 3 % x.shape[1]] = np.inf
        if rng.random() < 0.1:
            x[-1, 0] = np.nan
        shift = int(rng.integers(0, 4))
        want = np.zeros_like(x)
        if shift < x.shape[1]:
            want[:, shift:] = lfilter(b, a, x[:, : x.shape[1] - shift], axis=-1)
        got = kernels.lfilter_rows(b, a, x, shift=shift)
        np.testing.assert_array_equal(got, want)
        assert np.array_equal(np.signbit(got), np.signbit(want))


def test_compiled_lfilter_refuses_a_denominator_it_cannot_run():
    with pytest.raises(ValueError, match="a: need a denominator of at least 2 coefficients"):
        kernels.lfilter_rows([1.0], [1.0], np.ones((1, 5)))
    with pytest.raises(ValueError, match="first nonzero"):
        kernels.lfilter_rows([1.0], [0.0, 1.0], np.ones((1, 5)))


@pytest.mark.parametrize("with_friction", [False, True])
def test_rows_of_different_maps_replay_each_its_own(with_friction):
    """Maps that agree below zero and differ above it, in one call: each row is its own map's, as alone (a copy
    of one map with the others' values as per-row arrays once kept the first map's breakpoints and values)."""
    fitted = {**CLIPPING_SENSOR, "v2": 22.0, "v3": 18.0}
    drive = {**BELT_DRIVE, "v3": 2.5}
    specs = [{"output_map": CLIPPING_SENSOR}, {"output_map": fitted}, {"input_map": BELT_DRIVE},
             {"input_map": drive}]
    if with_friction:
        specs = [{**s, "coulomb_friction": {"torque": 0.5}} for s in specs]
    _, chains, u, y0, bias = _rows([SPEED] * len(specs), specs, seed=5)
    u = np.abs(u) + 1.0  # commands and outputs above zero, where the maps differ
    both = simulate_open_loop(SPEED, u, 0.002, chains, y0=np.abs(y0), bias=bias)
    for row, spec in enumerate(specs):
        alone = simulate_open_loop(SPEED, u[row], 0.002, build_effects(spec), y0=abs(y0[row]), bias=bias[row])
        np.testing.assert_array_equal(both.y[row], alone.y[0], err_msg=str(spec))
