"""Physics of every effect block, and zero magnitude = the effect-free plant."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from gbo_envs import ClosedLoop, ContinuousPlant, PDT1Controller, PIController
from gbo_envs.physics import (
    EFFECT_NAMES,
    EFFECTS,
    Backlash,
    Cogging,
    CoulombFriction,
    DeadZone,
    Drift,
    Offset,
    Quantization,
    Saturation,
    Stiction,
    TimeDelay,
    ViscousFriction,
    build_effects,
    describe_effect,
)
from tests.support import DC_PLANT, U_REST, dc_loop

DC_GAINS = np.array([[0.54, 1.16], [1.10, 2.08], [0.11, 0.87]])
#: a double integrator (a slider, position output) with a 1.5 ms (fractional) delay
SLIDER = ContinuousPlant((1.0,), (1.0, 0.0, 0.0), delay=0.0015, output="position")
SLIDER_GAINS = np.array([[100.0, 20.0], [400.0, 30.0]])


def slider_loop(*effects, r2: float = 1.0) -> ClosedLoop:
    return ClosedLoop(SLIDER, PDT1Controller(), dt=0.001, duration=1.0, r1=0.0, r2=r2, effects=tuple(effects))


def replay(loop: ClosedLoop, applied: np.ndarray, y_start: float) -> np.ndarray:
    """Output of the exact sampled plant of ``loop`` fed with the plant inputs ``applied[k]``, from rest."""
    plant = loop._discrete
    x, v_prev = plant.equilibrium(y_start)
    x, v_prev = x[:, 0], v_prev[0]
    y = np.empty(applied.size)
    for k, v in enumerate(applied):
        y[k] = plant.c @ x
        x = plant.phi @ x + plant.gamma0 * v + plant.gamma1 * v_prev
        v_prev = v
    return y


def delayed(loop: ClosedLoop, u: np.ndarray, u_start: float) -> np.ndarray:
    """Commands as they reach the actuator after the plant's whole-sample input delay."""
    lag = loop._discrete.delay_steps
    return np.concatenate([np.full(lag, u_start), u[: u.size - lag]])


# -- catalogue and description ------------------------------------------------------------------
def test_catalogue_is_the_design_list():
    assert set(EFFECT_NAMES) == {"time_delay", "saturation", "dead_zone", "coulomb_friction", "viscous_friction",
                                 "stiction", "backlash", "quantization", "drift", "offset", "cogging", "compliance"}


@pytest.mark.parametrize("name", EFFECT_NAMES)
def test_every_block_describes_its_parameters(name):
    cls = EFFECTS[name]
    assert cls.name == name
    assert len(cls.param_names) == len(cls.param_units) == len(cls.param_bounds) >= 1
    assert cls.magnitude_param in cls.param_names
    described = describe_effect(name)
    assert tuple(p.name for p in described) == cls.param_names
    for p, (low, high) in zip(described, cls.param_bounds):
        assert low <= high and p.unit
    zero = cls.zero()
    assert zero.is_zero and zero.side in ("actuator", "sensor", "plant")
    assert build_effects({name: zero.params}) == (zero,)


# -- zero magnitude reproduces the effect-free plant ---------------------------------------------
@pytest.mark.parametrize("name", EFFECT_NAMES)
@pytest.mark.parametrize("which", ["dc_motor", "slider"])
def test_zero_magnitude_reproduces_effect_free_plant(name, which):
    make, gains = (dc_loop, DC_GAINS) if which == "dc_motor" else (slider_loop, SLIDER_GAINS)
    zero = EFFECTS[name].zero()
    bare = make()
    with_block = make(zero).at_experiment(7)
    if zero.side == "plant":
        # the plant is unchanged, so the loop stays on the linear fast path
        assert with_block.current_plant == bare.plant
        ref, got = bare.simulate(gains), with_block.simulate(gains)
    else:
        # like with like: both stepped sample by sample
        ref, got = bare.simulate(gains, method="stepping"), with_block.simulate(gains)
    assert np.max(np.abs(got.y - ref.y)) <= 1e-9
    assert np.max(np.abs(got.u - ref.u)) <= 1e-9


def test_stepping_path_is_exact_and_linear_fast_path_agrees():
    """The stepped loop against an extended-precision recursion, and the linear path against it."""
    loop = dc_loop()
    gains = DC_GAINS[:1]
    plant = loop._discrete
    wide = np.longdouble
    phi, gamma0, c = plant.phi.astype(wide), plant.gamma0.astype(wide), plant.c.astype(wide)
    x, u0 = plant.equilibrium(245.0)
    x, u_prev, e_prev = x[:, 0].astype(wide), wide(u0[0]), wide(0.0)
    b0, b1, a1 = (wide(v[0]) for v in loop.controller.coefficients(gains, loop.dt))
    applied, y_ref = u_prev, []
    for _ in range(loop.n_steps):  # one-sample delay: the plant gets the previous command
        y = c @ x
        y_ref.append(y)
        e = wide(306.0) - y
        u = b0 * e + b1 * e_prev - a1 * u_prev
        x = phi @ x + gamma0 * applied
        applied, u_prev, e_prev = u, u, e
    y_ref = np.asarray(y_ref, dtype=float)
    stepped = loop.simulate(gains, method="stepping").y[0]
    linear = loop.simulate(gains, method="linear").y[0]
    assert np.max(np.abs(stepped - y_ref)) < 1e-9
    assert np.max(np.abs(linear - stepped)) < 2e-8 * 61.0


def test_linear_method_refuses_nonlinear_loop():
    with pytest.raises(ValueError, match="method"):
        dc_loop(Saturation(200.0)).simulate(DC_GAINS, method="linear")
    with pytest.raises(ValueError, match="method"):
        dc_loop().simulate(DC_GAINS, method="exact")


# -- one physics test per block -------------------------------------------------------------------
def test_saturation_clips_at_the_limit():
    block = Saturation(limit=150.0)
    u = np.array([-300.0, -150.0, 0.0, 120.0, 151.0, 1e9])
    assert np.array_equal(block.actuate(u, np.zeros(6)), [-150.0, -150.0, 0.0, 120.0, 150.0, 150.0])
    # in the loop: the output is that of the plant fed with the clipped, delayed commands
    loop = dc_loop(block)
    response = loop.simulate(DC_GAINS[1:2])
    assert response.u[0].max() > 200.0  # the limit is active
    applied = np.clip(delayed(loop, response.u[0], U_REST), -150.0, 150.0)
    assert np.max(np.abs(replay(loop, applied, 245.0) - response.y[0])) < 1e-9
    assert not np.allclose(response.y, dc_loop().simulate(DC_GAINS[1:2]).y)


def test_saturation_below_the_holding_input_is_refused():
    with pytest.raises(ValueError, match=r"saturation: parameter 'limit'.*allowed: limit >= 107\.79"):
        dc_loop(Saturation(limit=100.0)).simulate(DC_GAINS)


def test_dead_zone_passes_nothing_inside_its_band():
    block = DeadZone(width=4.0)
    u = np.array([-2.0, -1.0, 0.0, 1.5, 2.0, 3.0, -5.0])
    out = block.actuate(u, np.zeros(u.size))
    assert np.array_equal(out[:5], np.zeros(5))
    assert np.array_equal(out[5:], [1.0, -3.0])
    assert np.allclose(block.actuate(block.command_for(np.array([5.0, -5.0]), 0.0), 0.0), [5.0, -5.0])
    loop = dc_loop(block)
    response = loop.simulate(DC_GAINS[:1])
    applied = block.actuate(delayed(loop, response.u[0], U_REST + 2.0), 0.0)
    assert np.max(np.abs(replay(loop, applied, 245.0) - response.y[0])) < 1e-9


def test_coulomb_friction_opposes_motion():
    block = CoulombFriction(torque=20.0)
    speed = np.array([-3.0, -1e-9, 1e-9, 50.0])
    assert np.array_equal(block.actuate(np.zeros(4), speed), [20.0, 20.0, -20.0, -20.0])
    # at rest it balances a drive below its level and takes only the level off a larger one
    assert np.array_equal(block.actuate(np.array([-15.0, 15.0, 35.0]), np.zeros(3)), [0.0, 0.0, 15.0])
    smooth = CoulombFriction(torque=20.0, smoothing=2.0)
    assert np.array_equal(smooth.actuate(np.zeros(3), np.array([-1.0, 1.0, 5.0])), [10.0, -10.0, -20.0])
    # in the loop the drive must supply the friction: the command at rest is 20 higher
    rubbing = dc_loop(block, duration=30.0).simulate(DC_GAINS[:2])
    assert np.allclose(rubbing.y[:, -1], 306.0, atol=1e-6)
    assert np.allclose(rubbing.u[:, -1], 306.0 / DC_PLANT.dc_gain + 20.0, atol=1e-6)
    # a slider pushed from rest moves less far against friction
    free, braked = slider_loop().simulate(SLIDER_GAINS[:1]), slider_loop(CoulombFriction(20.0)).simulate(
        SLIDER_GAINS[:1])
    assert braked.y[0, 60] < free.y[0, 60]


def test_viscous_friction_scales_with_speed():
    block = ViscousFriction(coefficient=0.05)
    speed = np.array([0.0, 100.0, 200.0, -400.0])
    drag = -block.actuate(np.zeros(4), speed)
    assert np.allclose(drag, 0.05 * speed)
    assert np.allclose(drag[2], 2.0 * drag[1])
    # settled in the loop: the command holds the plant's static input plus the drag at that speed
    damped = dc_loop(block, duration=30.0).simulate(DC_GAINS[:2])
    assert np.allclose(damped.y[:, -1], 306.0, atol=1e-6)
    assert np.allclose(damped.u[:, -1], (1.0 / DC_PLANT.dc_gain + 0.05) * 306.0, atol=1e-6)


def test_stiction_holds_below_breakaway():
    block = Stiction(breakaway=30.0)
    # at rest: a drive below breakaway applies nothing; once moving: no effect
    assert np.array_equal(block.actuate(np.array([29.0, -29.0, 40.0]), np.zeros(3)), [0.0, 0.0, 10.0])
    assert np.array_equal(block.actuate(np.array([29.0, -29.0]), np.array([0.5, -0.5])), [29.0, -29.0])
    # a slider at rest whose controller pulls with less than breakaway stays exactly put
    weak = slider_loop(block, r2=0.05).simulate(np.array([[100.0, 0.02]]))
    assert weak.u[0].max() < 30.0
    assert np.all(weak.y[0] == 0.0)
    strong = slider_loop(block, r2=1.0).simulate(np.array([[100.0, 0.02]]))
    assert strong.y[0, -1] > 0.5


def test_backlash_shows_hysteresis():
    block = Backlash(width=2.0)
    block.reset(1, None, 0.001)
    block.command_for(np.zeros(1), np.zeros(1))
    up = np.linspace(0.0, 5.0, 11)
    down = up[::-1]
    out_up = np.array([block.actuate(np.array([u]), 0.0)[0] for u in up])
    out_down = np.array([block.actuate(np.array([u]), 0.0)[0] for u in down])
    # going up the load lags by half the play, going down it leads by half the play
    assert np.allclose(out_up[2:], up[2:] - 1.0)
    assert np.allclose(out_down[4:], down[4:] + 1.0)
    # on reversal the output stays put until the input has crossed the whole play
    assert np.allclose(out_down[:5], 4.0)
    # at the same input the two branches differ by the width
    assert np.isclose(out_down[::-1][6] - out_up[6], 2.0)
    # in the loop (a gentle PI; an aggressive one hunts through the play): settled, the command
    # lies within half the play of the input the plant needs
    settled = dc_loop(block, duration=30.0).simulate(DC_GAINS[:1])
    assert np.allclose(settled.y[:, -1], 306.0, atol=1e-6)
    assert np.all(np.abs(settled.u[:, -1] - 306.0 / DC_PLANT.dc_gain) <= 1.0 + 1e-6)
    assert not np.allclose(settled.u[:, :500], dc_loop(duration=30.0).simulate(DC_GAINS[:1]).u[:, :500])


def test_quantization_has_the_stated_step():
    step = 2.0 * np.pi / (2048 * 0.002)  # encoder speed resolution of the DC motor rig, rad/s
    block = Quantization(step=step)
    assert np.array_equal(block.measure(np.array([0.0, 0.4 * step, 0.6 * step, -1.4 * step])),
                          [0.0, 0.0, step, -step])
    assert np.array_equal(Quantization(step=1.0, mode="floor").measure(np.array([0.9, -0.1])), [0.0, -1.0])
    y = dc_loop(block).simulate(DC_GAINS).y
    counts = y / step
    assert np.max(np.abs(counts - np.round(counts))) < 1e-9
    levels = np.unique(np.round(counts))
    assert np.min(np.diff(levels)) == 1.0


@pytest.mark.parametrize("on", ["actuator", "sensor"])
def test_offset_shifts(on):
    block = Offset(value=5.0, on=on)
    assert block.side == on
    assert np.array_equal(block.actuate(np.array([1.0]), 0.0), [6.0])
    assert np.array_equal(block.measure(np.array([1.0])), [6.0])
    bare, biased = dc_loop().simulate(DC_GAINS, method="stepping"), dc_loop(block).simulate(DC_GAINS)
    # the loop is linear: the integrator absorbs the bias and the measured response is unchanged,
    # the command is shifted by the bias (actuator) or by the input that moves the true output by it
    shift = -5.0 if on == "actuator" else -5.0 / DC_PLANT.dc_gain
    assert np.max(np.abs(biased.y - bare.y)) < 1e-9
    assert np.max(np.abs(biased.u - bare.u - shift)) < 1e-9


def test_cogging_ripple_has_the_stated_period():
    period, dt, n = 0.3, 0.001, 25  # speed so that one ripple period takes 25 samples
    speed = np.full(1, period / (n * dt))
    block = Cogging(amplitude=3.0, period=period)
    block.reset(1, None, dt)
    ripple = np.array([block.actuate(np.zeros(1), speed)[0] for _ in range(4 * n)])
    assert np.allclose(ripple[n:], ripple[:-n], atol=1e-12)
    for shorter in range(1, n):
        assert not np.allclose(ripple[shorter:], ripple[:-shorter], atol=1e-3)
    # averaged over a sample the peak is attenuated by sinc(1 / n)
    assert np.isclose(np.abs(ripple).max(), 3.0 * np.sinc(1.0 / n), rtol=1e-2)
    # at rest it is the plain sine of the position
    block.reset(1, None, dt)
    assert np.isclose(block.actuate(np.zeros(1), np.zeros(1))[0], 0.0)
    shifted = Cogging(3.0, period, phase=np.pi / 2)
    shifted.reset(1, None, dt)
    assert np.isclose(shifted.command_for(np.zeros(1), np.zeros(1))[0], -3.0)
    # in the speed loop it disturbs the response
    rippled = dc_loop(Cogging(5.0, 2 * np.pi / 8)).simulate(DC_GAINS, rng=np.random.default_rng(0))
    assert not np.allclose(rippled.y, dc_loop().simulate(DC_GAINS).y)


def test_cogging_of_a_turning_rotor_starts_at_a_random_angle_unless_synchronised():
    gains = np.repeat(DC_GAINS[:1], 4, axis=0)
    loop = dc_loop(Cogging(10.0))  # the DC loop starts turning at 245 rad/s
    with pytest.raises(ValueError, match="rng"):
        loop.simulate(gains)
    y = loop.simulate(gains, rng=np.random.default_rng(0)).y
    assert np.ptp(y[:, 50:], axis=0).max() > 0.1  # four experiments, four start angles
    # common random numbers: rows of the same draw see the same angle, whatever the batch
    same = loop.simulate(gains, rng=np.random.default_rng(0), draws=np.array([0, 1, 0, 1])).y
    assert np.array_equal(same[0], same[2]) and not np.array_equal(same[0], same[1])
    alone = loop.simulate(gains[:1], rng=np.random.default_rng(0), draws=np.array([1])).y
    assert np.max(np.abs(alone[0] - same[1])) < 1e-9
    # a step triggered at a fixed angle, or a replay without a generator, starts at theta = 0
    fixed = dc_loop(Cogging(10.0, synchronised=True))
    assert not fixed.stochastic
    assert np.ptp(fixed.simulate(gains).y, axis=0).max() == 0.0
    block = Cogging(10.0, phase=np.pi / 2)
    block.reset(2, None, 0.002)
    travel = 245.0 * 0.002  # rad in one sample
    expected = [-10.0 * np.cos(travel / 2) * np.sinc(travel / (2 * np.pi)), -10.0]
    assert np.allclose(block.command_for(np.zeros(2), np.array([245.0, 0.0])), expected, atol=1e-12)
    # a mechanism at rest starts at its rest position even with a generator
    block.reset(2, np.random.default_rng(0), 0.002)
    assert block.command_for(np.zeros(2), np.zeros(2)) == pytest.approx([-10.0, -10.0])
    with pytest.raises(ValueError, match="synchronised"):
        Cogging(1.0, synchronised="yes")
    # a position loop rests at the start: its cogging is the same in every experiment, no draws needed
    linear = gym.make("gbo_envs/LinearMotor-v0", effects={"cogging": {"amplitude": 0.3, "period": 0.005}}).unwrapped
    assert not linear.loop.replace(output_noise_std=0.0).stochastic
    assert dc_loop(Cogging(10.0)).output_noise_std == 0.0 and dc_loop(Cogging(10.0)).stochastic


def test_time_delay_delays_the_response_by_the_stated_time():
    extra = 0.010  # 5 samples
    loop = dc_loop(TimeDelay(delay=extra))
    assert loop.current_plant.delay == pytest.approx(0.012)
    same = ClosedLoop(ContinuousPlant(DC_PLANT.num, DC_PLANT.den, delay=0.012), PIController(), 0.002, 5.0,
                      245.0, 306.0)
    assert np.array_equal(loop.simulate(DC_GAINS).y, same.simulate(DC_GAINS).y)

    def first_move(y):
        return int(np.argmax(np.abs(y - 245.0) > 1e-12))

    base = dc_loop().simulate(DC_GAINS[:1]).y[0]
    late = loop.simulate(DC_GAINS[:1]).y[0]
    assert first_move(late) - first_move(base) == 5
    # a fractional extra delay is folded into the exact discretisation too
    frac = dc_loop(TimeDelay(delay=0.0031))
    assert frac._discrete.delay_steps == 2 and np.any(frac._discrete.gamma1 != 0.0)
    # and it works with stepping effects as well
    nonlinear = dc_loop(TimeDelay(extra), Saturation(1e6)).simulate(DC_GAINS)
    assert np.max(np.abs(nonlinear.y - same.simulate(DC_GAINS, method="stepping").y)) < 1e-9


def test_drift_changes_the_plant_between_experiments():
    block = Drift(rate=-0.01, parameter="gain")
    loop = dc_loop(block)
    assert loop.current_plant.num == DC_PLANT.num
    assert loop.at_experiment(10).current_plant.num[0] == pytest.approx(9.544 * 0.90)
    assert block.current_values(DC_PLANT, 10) == {"gain": pytest.approx(9.544 * 0.90)}
    assert not np.allclose(loop.at_experiment(10).simulate(DC_GAINS).y, loop.simulate(DC_GAINS).y)
    expo = Drift(rate=0.02, parameter=("den1", "delay"), mode="exponential")
    plant = expo.modify_plant(DC_PLANT, 3)
    assert plant.den[1] == pytest.approx(4.145 * 1.02**3) and plant.delay == pytest.approx(0.002 * 1.02**3)
    step = Drift(rate=(0.5, -0.2), parameter=("gain", "den2"), mode="step", start=4)
    assert step.modify_plant(DC_PLANT, 3) is DC_PLANT
    changed = step.modify_plant(DC_PLANT, 4)
    assert changed.num[0] == pytest.approx(9.544 * 1.5) and changed.den[2] == pytest.approx(4.199 * 0.8)
    assert step.modify_plant(DC_PLANT, 30) == changed
    with pytest.raises(ValueError, match="drift"):
        Drift(rate=-0.5).modify_plant(DC_PLANT, 2)
    with pytest.raises(ValueError, match="den5"):
        Drift(rate=0.1, parameter="den5").modify_plant(DC_PLANT, 1)


def test_blocks_are_vectorised_and_keep_no_state_between_simulations():
    blocks = (Backlash(1.0), Cogging(2.0, 0.5, synchronised=True), CoulombFriction(5.0), Stiction(3.0, 0.1),
              Quantization(0.01))
    loop = dc_loop(*blocks)
    batch = loop.simulate(DC_GAINS)
    again = loop.simulate(DC_GAINS)
    assert np.array_equal(batch.y, again.y)
    for i in range(DC_GAINS.shape[0]):
        single = loop.simulate(DC_GAINS[i])
        assert np.max(np.abs(single.y[0] - batch.y[i])) < 1e-9


def test_a_tiny_friction_smoothing_ramps_without_an_overflow_warning():
    """``clip(speed / smoothing, -1, 1)`` overflowed (a RuntimeWarning) where |speed| / smoothing passed double
    range; clipped before the division it gives the same values and no warning."""
    import warnings

    from gbo_envs.physics.friction import CoulombFriction

    speed = np.array([1e10, -5.0, 0.0, 3e-301, -1e-300])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(CoulombFriction(20.0, smoothing=1e-300).friction(np.zeros(5), speed),
                                      [20.0, -20.0, 0.0, 6.0, -20.0])
    block, speed = CoulombFriction(20.0, smoothing=0.7), np.linspace(-3.0, 3.0, 101)
    np.testing.assert_array_equal(block.friction(np.zeros(101), speed), 20.0 * np.clip(speed / 0.7, -1.0, 1.0))
