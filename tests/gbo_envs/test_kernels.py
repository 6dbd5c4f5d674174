"""The compiled closed-loop stepping (:mod:`gbo_envs.physics.kernels`) gives the numpy loop's numbers, bit for bit.

Every actuator and sensor block of the catalogue and the rigs' encoders, with parameters drawn
by hypothesis from their ranges, in a speed loop through zero speed and a position loop, with
sensor noise and common random numbers: the kernel's commands and measurements equal those of
``ClosedLoop._step_numpy`` (the path of blocks the kernel does not know), and both paths take
the same numbers from the generator. A block class the kernel does not know (a user's
subclass) keeps the numpy loop.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gbo_envs import ClosedLoop, ContinuousPlant, PDT1Controller
from gbo_envs.physics import CoulombFriction, Saturation, build_effect, kernels
from gbo_envs.physics.encoder import PositionEncoder, SpeedEncoder
from tests.support import dc_loop, leaky_saturation

FAST = settings(max_examples=25, deadline=None, derandomize=True, database=None)
GAINS = np.array([[0.3, 1.0], [0.6, 1.5], [0.9, 1.2], [1.05, 2.0], [0.5, 1.9], [0.2, 0.9]])
SLIDER = ContinuousPlant((0.44262,), (0.070983, 0.8, 0.0), delay=0.0013, output="position")
SLIDER_GAINS = np.array([[5200.0, 45.0], [6000.0, 50.0], [5500.0, 41.0]])
COMPILED = kernels.closed_loop_kernel

#: block name -> hypothesis strategy of its parameters (in physical ranges of the DC motor loop, input ~ 10-100)
PARAMS = {
    "saturation": st.fixed_dictionaries({"limit": st.floats(20.0, 200.0)}),
    "dead_zone": st.fixed_dictionaries({"width": st.floats(0.0, 30.0)}),
    "coulomb_friction": st.fixed_dictionaries({"torque": st.floats(0.0, 15.0), "smoothing": st.sampled_from([0.0, 0.5]),
                                               "asymmetry": st.floats(-0.9, 0.9)}),
    "viscous_friction": st.fixed_dictionaries({"coefficient": st.floats(0.0, 0.2)}),
    "stiction": st.fixed_dictionaries({"breakaway": st.floats(0.0, 15.0), "threshold": st.floats(0.0, 2.0)}),
    "backlash": st.fixed_dictionaries({"width": st.floats(0.0, 10.0)}),
    "quantization": st.fixed_dictionaries({"step": st.floats(0.0, 2.0), "mode": st.sampled_from(["round", "floor"])}),
    "offset": st.fixed_dictionaries({"value": st.floats(-10.0, 10.0), "on": st.sampled_from(["actuator", "sensor"])}),
    "cogging": st.fixed_dictionaries({"amplitude": st.floats(0.0, 10.0), "period": st.floats(0.05, 7.0),
                                      "phase": st.floats(-6.0, 6.0), "synchronised": st.booleans()}),
}


def _static_map(low: float, high: float):
    """A piecewise-linear map's parameters: five increasing breakpoints in ``[low, high]`` (exactly one at 0 now
    and then, a knot the command crosses), values anywhere (flat and falling segments too), a weight in [0, 1]."""
    knots = st.lists(st.floats(low, high), min_size=5, max_size=5, unique=True).map(sorted)
    values = st.lists(st.one_of(st.floats(low, high), st.just(0.0)), min_size=5, max_size=5)
    weight = st.one_of(st.just(1.0), st.just(0.0), st.floats(0.0, 1.0))
    return st.tuples(knots, values, weight).filter(lambda t: min(np.diff(t[0])) > 1e-6).map(
        lambda t: {**{f"k{i}": t[0][i] for i in range(5)}, **{f"v{i}": t[1][i] for i in range(5)}, "weight": t[2]})


#: the static maps (not catalogue effects, but built like them): the drive's command and the sensor's output
PARAMS.update(input_map=_static_map(-150.0, 200.0), output_map=_static_map(-350.0, 400.0))


def _both_paths(loop: ClosedLoop, gains, seed: int, draws=None, monkeypatch=None):
    """``(kernel response, numpy response, kernel calls)``, and the next number of each path's generator."""
    calls = []

    def counted(*args):
        calls.append(1)
        COMPILED(*args)

    monkeypatch.setattr(kernels, "closed_loop_kernel", counted)
    rng = np.random.default_rng(seed)
    fast = loop.simulate(gains, rng=rng, draws=draws)
    fast_next = rng.random()
    with monkeypatch.context() as m:
        m.setattr(kernels, "KERNEL_CODES", {})  # no block known: the numpy loop
        rng = np.random.default_rng(seed)
        slow = loop.simulate(gains, rng=rng, draws=draws)
        slow_next = rng.random()
    return fast, slow, len(calls), (fast_next, slow_next)


def _assert_same(fast, slow, calls, nexts):
    assert calls == 1  # the kernel ran once (the numpy run did not call it)
    np.testing.assert_array_equal(fast.y, slow.y)
    np.testing.assert_array_equal(fast.u, slow.u)
    np.testing.assert_array_equal(fast.unstable, slow.unstable)
    assert nexts[0] == nexts[1]  # both paths drew the same random numbers


@pytest.mark.parametrize("name", list(PARAMS))
def test_every_catalogue_block_steps_the_same_compiled(name, monkeypatch):
    @FAST
    @given(params=PARAMS[name], step=st.sampled_from([(245.0, 306.0), (-30.0, 30.0)]),
           noise=st.sampled_from([0.0, 0.2]))
    def check(params, step, noise):
        if name == "saturation" and step[0] > 0:
            params = {"limit": max(params["limit"], 120.0)}  # the rest input at 245 rad/s is 107.8
        loop = dc_loop(build_effect(name, params), duration=0.6, output_noise_std=noise).replace(r1=step[0],
                                                                                                 r2=step[1])
        draws = np.arange(GAINS.shape[0]) % 3
        _assert_same(*_both_paths(loop, GAINS, seed=7, draws=draws, monkeypatch=monkeypatch))

    check()


def test_a_chain_of_every_block_and_a_fractional_delay_steps_the_same_compiled(monkeypatch):
    chain = [("offset", {"value": 1.0}), ("saturation", {"limit": 150.0}), ("dead_zone", {"width": 2.0}),
             ("backlash", {"width": 1.0}), ("coulomb_friction", {"torque": 3.0, "asymmetry": 0.3}),
             ("stiction", {"breakaway": 2.0, "threshold": 0.5}), ("viscous_friction", {"coefficient": 0.01}),
             ("cogging", {"amplitude": 2.0, "period": 0.3}), ("quantization", {"step": 0.1}),
             ("offset", {"value": -0.5, "on": "sensor"})]
    plant = ContinuousPlant((9.544,), (1.0, 4.145, 4.199), delay=0.0031)  # 1 whole sample and a fraction
    loop = ClosedLoop(plant, dc_loop().controller, dt=0.002, duration=1.0, r1=-30.0, r2=30.0,
                      effects=tuple(build_effect(n, p) for n, p in chain), output_noise_std=0.1)
    fast, slow, calls, nexts = _both_paths(loop, GAINS, seed=3, monkeypatch=monkeypatch)
    _assert_same(fast, slow, calls, nexts)
    assert np.ptp(fast.y[:, -100:]) > 1.0  # the loop moved (the comparison is not of constants)


@pytest.mark.parametrize("jitter", [0.0, 0.25])
def test_the_rig_encoders_step_the_same_compiled(jitter, monkeypatch):
    lines = 2048
    speed = dc_loop(Saturation(160.0), CoulombFriction(5.0), SpeedEncoder(lines, 10, jitter * 2 * np.pi / lines),
                    duration=0.6)
    for draws in (None, np.arange(GAINS.shape[0]) % 4):
        _assert_same(*_both_paths(speed, GAINS, seed=11, draws=draws, monkeypatch=monkeypatch))
    position = ClosedLoop(SLIDER, PDT1Controller(), dt=0.001, duration=0.3, r1=0.03, r2=0.04,
                          effects=(Saturation(7.0), CoulombFriction(0.5), PositionEncoder(5e-6, jitter * 5e-6),
                                   PositionEncoder(1e-6, jitter * 1e-6)), output_noise_std=1e-6)
    _assert_same(*_both_paths(position, SLIDER_GAINS, seed=5, draws=np.array([0, 1, 0]), monkeypatch=monkeypatch))


def test_position_loop_friction_acts_on_the_speed_compiled(monkeypatch):
    loop = ClosedLoop(SLIDER, PDT1Controller(), dt=0.001, duration=0.3, r1=0.03, r2=0.04,
                      effects=(CoulombFriction(0.5, asymmetry=-0.4), build_effect("cogging", {"amplitude": 0.3,
                                                                                            "period": 0.002})))
    fast, slow, calls, nexts = _both_paths(loop, SLIDER_GAINS, seed=0, monkeypatch=monkeypatch)
    _assert_same(fast, slow, calls, nexts)


def test_a_block_the_kernel_does_not_know_keeps_the_numpy_loop(monkeypatch):
    calls = []
    monkeypatch.setattr(kernels, "closed_loop_kernel", lambda *args: calls.append(1))
    own = dc_loop(leaky_saturation(130.0, 0.5), duration=1.0).simulate(GAINS)
    assert calls == []
    plain = dc_loop(Saturation(130.0), duration=1.0)
    monkeypatch.setattr(kernels, "KERNEL_CODES", {})
    clipped = plain.simulate(GAINS)
    assert np.max(np.abs(own.y - clipped.y)) > 0.1  # the user's actuate ran


#: every actuator block of the catalogue (offset on the actuator side)
ACTUATORS = ["saturation", "dead_zone", "coulomb_friction", "viscous_friction", "stiction", "backlash", "cogging",
             "offset", "input_map"]


@FAST
@given(chain=st.lists(st.sampled_from(ACTUATORS), min_size=1, max_size=3), data=st.data(), seed=st.integers(0, 50))
def test_actuators_step_through_records_as_the_numpy_loop(chain, data, seed):
    """:func:`kernels.step_actuators` (the profiles' commands through stateful actuators) equals the loop of
    ``block.actuate`` sample by sample, states carried, for chains of every actuator block."""
    specs = [(name, {**data.draw(PARAMS[name]), **({"on": "actuator"} if name == "offset" else {})})
             for name in chain]
    rng = np.random.default_rng(seed)
    u = np.cumsum(rng.normal(0.0, 3.0, (4, 400)), axis=1)  # reversals of the command
    speed = np.cumsum(rng.normal(0.0, 1.0, (4, 400)), axis=1)  # and of the speed
    blocks = [build_effect(name, params) for name, params in specs]
    for block in blocks:
        block.reset(4, None, 0.002)
    got = kernels.step_actuators(blocks, u, speed, 0.002)
    want = u.copy()
    for block in blocks:
        block.reset(4, None, 0.002)
    for k in range(u.shape[1]):
        v = want[:, k]
        for block in blocks:
            v = block.actuate(v, speed[:, k])
        want[:, k] = v
    np.testing.assert_array_equal(got, want)


def test_actuators_the_kernels_do_not_know_are_not_stepped_compiled():
    assert kernels.step_actuators([leaky_saturation(5.0, 0.1)], np.ones((1, 3)), np.zeros((1, 3)), 0.002) is None
