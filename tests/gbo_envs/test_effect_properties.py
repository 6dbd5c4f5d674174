"""Property tests of the effect blocks (hypothesis): finite in, finite out; bad parameters raise ValueError.

For every block of the catalogue (``EFFECTS``) and the two encoders, with
parameters drawn from their declared ranges (``EffectParameter.low/high``, every
upper bound finite since issue 19,
magnitudes capped at ``CAP`` to stay physical) and finite inputs of up to
``CAP`` in size:

* actuator blocks: ``command_for`` (the rest condition) gives a finite
  command or a ``ValueError`` (a saturation below the rest input), and
  ``actuate`` gives finite plant inputs at every sample;
* sensor blocks: ``level_for`` and ``measure`` give finite values;
* plant blocks: ``modify_plant`` gives a plant with finite coefficients and
  delay, or a ``ValueError`` (a drift that takes a parameter to zero or below).

Every parameter outside its range, non-finite where the block needs it
finite, of the wrong type, or an option outside its allowed values, makes
construction raise ``ValueError``.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gbo_envs.physics import EFFECT_NAMES, EFFECTS, build_effect
from gbo_envs.physics.block import DELAY_LIMIT, MAGNITUDE_LIMIT
from gbo_envs.physics.encoder import PositionEncoder, SpeedEncoder
from gbo_envs.physics.plant_effects import DRIFT_MODES
from tests.support import DC_PLANT

#: largest parameter and input magnitude drawn (input, output and speed units)
CAP = 1e6
BATCH, SAMPLES, DT = 3, 6, 0.002
FAST = settings(max_examples=40, deadline=None, derandomize=True, database=None)  # same examples every run

finite = st.floats(-CAP, CAP, allow_nan=False, allow_infinity=False)
signals = arrays(np.float64, (SAMPLES, BATCH), elements=finite)

#: options of each block with their allowed values (drift's are checked by hand below)
OPTIONS = {"offset": {"on": ("actuator", "sensor")}, "quantization": {"mode": ("round", "floor")}}
DRIFT_PARAMETERS = ("gain", "delay", "num0", "den1", "den2")


def _in_range(spec) -> st.SearchStrategy[float]:
    """Finite values of one numeric parameter inside its declared range, capped at CAP."""
    values = st.floats(max(spec.low, -CAP), min(spec.high, CAP), allow_nan=False, allow_infinity=False)
    return values | st.just(spec.zero) if np.isinf(spec.zero) else values  # saturation: limit = inf is "off"


def _params(name: str) -> st.SearchStrategy[dict]:
    cls = EFFECTS[name]
    fields = {spec.name: _in_range(spec) for spec in cls.parameters}
    if name == "drift":
        fields.update(parameter=st.sampled_from(DRIFT_PARAMETERS), mode=st.sampled_from(DRIFT_MODES),
                      start=st.integers(0, 50))
    for option, allowed in OPTIONS.get(name, {}).items():
        fields[option] = st.sampled_from(allowed)
    return st.fixed_dictionaries(fields)


def _check_block(block, u, speed, seed: int, experiment_index: int) -> None:
    block.reset(BATCH, np.random.default_rng(seed), DT)
    if block.side == "plant":
        try:
            plant = block.modify_plant(DC_PLANT, experiment_index)
        except ValueError:
            return
        assert np.all(np.isfinite(plant.num)) and np.all(np.isfinite(plant.den)) and np.isfinite(plant.delay)
        return
    if block.side == "sensor":
        assert np.all(np.isfinite(block.level_for(u[0])))
        for row in u:
            assert np.all(np.isfinite(block.measure(row)))
        return
    try:
        command = block.command_for(u[0], speed[0])
    except ValueError:
        return
    assert np.all(np.isfinite(command))
    for row, v in zip(u, speed):
        assert np.all(np.isfinite(block.actuate(row, v)))


@pytest.mark.parametrize("name", EFFECT_NAMES)
def test_random_finite_parameters_and_inputs_give_finite_outputs(name):
    @FAST
    @given(params=_params(name), u=signals, speed=signals, seed=st.integers(0, 2**32 - 1),
           experiment_index=st.integers(0, 100))
    def check(params, u, speed, seed, experiment_index):
        _check_block(build_effect(name, params), u, speed, seed, experiment_index)

    check()


@FAST
@given(resolution=st.floats(1e-6, CAP), jitter=st.floats(0.0, CAP), y=signals, seed=st.integers(0, 2**32 - 1))
def test_position_encoder_readings_are_finite(resolution, jitter, y, seed):
    _check_block(PositionEncoder(resolution, jitter), y, y, seed, 0)


@FAST
@given(lines=st.integers(1, 100_000), window=st.integers(1, 20), jitter=st.floats(0.0, CAP), y=signals,
       seed=st.integers(0, 2**32 - 1))
def test_speed_encoder_readings_are_finite(lines, window, jitter, y, seed):
    _check_block(SpeedEncoder(lines, window, jitter), y, y, seed, 0)


# -- bad parameters -------------------------------------------------------------------------------
wrong_type = st.sampled_from(["1.0", None, True, [1.0], {"value": 1.0}, 1j])


def _bad(spec, name: str) -> st.SearchStrategy:
    """Values of one numeric parameter that its block must reject."""
    bad = [wrong_type, st.just(float("nan")), st.just(-np.inf)]
    if spec.default is not None:  # None means "the default" there
        bad[0] = bad[0].filter(lambda v: v is not None)
    if name == "drift":  # a list is drift's "one rate per drifting parameter"
        bad[0] = bad[0].filter(lambda v: not isinstance(v, list))
    if np.isfinite(spec.low):
        bad.append(st.floats(max_value=spec.low, exclude_max=True, allow_nan=False, allow_infinity=False,
                             min_value=spec.low - CAP))
    if np.isfinite(spec.high):  # above the upper bound, up to far beyond it (1e308: an overflow before)
        bad.append(st.floats(min_value=spec.high, exclude_min=True, allow_nan=False, allow_infinity=False,
                             max_value=spec.high + CAP))
        bad.append(st.floats(min_value=spec.high * 2.0, allow_nan=False, allow_infinity=False))
    if not np.isinf(spec.zero):  # only saturation (limit = inf is "off") may be infinite
        bad.append(st.just(np.inf))
    return st.one_of(bad)


def _valid(name: str) -> dict:
    """Smallest valid parameters of a block: each required parameter at a mid value of its range."""
    cls = EFFECTS[name]
    return {spec.name: 1.0 if spec.low <= 1.0 <= spec.high else spec.low
            for spec in cls.parameters if spec.default is None}


@pytest.mark.parametrize(("name", "parameter"), [(name, spec.name) for name in EFFECT_NAMES
                                                 for spec in EFFECTS[name].parameters])
def test_bad_numeric_parameters_raise_value_error(name, parameter):
    spec = next(s for s in EFFECTS[name].parameters if s.name == parameter)

    @FAST
    @given(value=_bad(spec, name))
    def check(value):
        with pytest.raises(ValueError, match=parameter):
            build_effect(name, {**_valid(name), parameter: value})

    check()


CATALOGUE_PARAMETERS = [(name, spec.name) for name in EFFECT_NAMES for spec in EFFECTS[name].parameters]


@pytest.mark.parametrize(("name", "parameter"), CATALOGUE_PARAMETERS)
def test_every_parameter_has_a_finite_upper_bound_named_in_its_error(name, parameter):
    spec = next(s for s in EFFECTS[name].parameters if s.name == parameter)
    assert np.isfinite(spec.high) and spec.high <= MAGNITUDE_LIMIT
    for value in (spec.high * (1.0 + 1e-9) + 1e-12, 1e308):
        with pytest.raises(ValueError) as info:
            build_effect(name, {**_valid(name), parameter: value})
        assert f"{name}: parameter {parameter!r}" in str(info.value)
        assert f"{spec.high:g}]" in str(info.value)  # the allowed range


@pytest.mark.parametrize("delay", [1e5, 1e308, DELAY_LIMIT * 1.001])
def test_runaway_time_delays_are_refused(delay):
    with pytest.raises(ValueError, match=r"time_delay: parameter 'delay' must be in \[0, 1000\]"):
        build_effect("time_delay", {"delay": delay})


def test_a_loop_refuses_a_delay_longer_than_its_experiment():
    import gymnasium as gym

    import gbo_envs  # noqa: F401  (registers the envs)

    env = gym.make("gbo_envs/DCMotor-v0", effects={"time_delay": {"delay": 4.9}})  # within the 5 s experiment
    assert env.unwrapped.loop.duration == 5.0
    with pytest.raises(ValueError, match=r"time_delay: parameter 'delay' must be in \[0, 4.998\].*duration = 5 s"):
        gym.make("gbo_envs/DCMotor-v0", effects={"time_delay": {"delay": 6.0}})
    loop = gym.make("gbo_envs/DCMotor-v0", effects={"drift": {"rate": 1.0, "parameter": "delay",
                                                              "mode": "exponential"}}).unwrapped.loop
    assert loop.at_experiment(5).current_plant.delay == pytest.approx(0.002 * 2**5)
    with pytest.raises(ValueError, match="drift: the plant's delay at experiment 20 is"):
        loop.at_experiment(20)


@pytest.mark.parametrize(("name", "option", "value"), [
    ("offset", "on", "plant"), ("offset", "on", 1), ("quantization", "mode", "ceil"), ("quantization", "mode", None),
    ("drift", "mode", "quadratic"), ("drift", "parameter", "den"), ("drift", "parameter", ()),
    ("drift", "parameter", 3), ("drift", "start", -1), ("drift", "start", 1.5), ("drift", "start", True),
    ("drift", "unknown", 1.0),
])
def test_bad_options_raise_value_error(name, option, value):
    with pytest.raises(ValueError, match=option):
        build_effect(name, {**_valid(name), option: value})


bad_real = st.one_of(wrong_type, st.sampled_from([np.nan, np.inf, -np.inf]),
                     st.floats(max_value=0.0, exclude_max=True, allow_nan=False, allow_infinity=False))
bad_count = st.one_of(wrong_type, st.sampled_from([1.5, np.nan, np.inf, 0]), st.integers(max_value=0))


@FAST
@given(resolution=st.one_of(bad_real, st.just(0.0)))
def test_position_encoder_rejects_bad_resolution(resolution):
    with pytest.raises(ValueError, match="resolution"):
        PositionEncoder(resolution)


@FAST
@given(lines=bad_count, window=bad_count, jitter=bad_real.filter(lambda v: v is not None),
       which=st.sampled_from(["lines", "window", "jitter"]))
def test_speed_encoder_rejects_bad_parameters(lines, window, jitter, which):
    args = {"lines": 2048, "window": 1, "jitter": 0.0}
    args[which] = {"lines": lines, "window": window, "jitter": jitter}[which]
    with pytest.raises(ValueError, match=which):
        SpeedEncoder(**args)
