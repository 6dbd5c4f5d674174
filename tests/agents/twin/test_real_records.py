"""The workbench on records as real rigs produce them (issue 35): open loop from rest, several steps per record,
both directions, asymmetric friction, an encoder's speed quantum, coloured and filtered noise, r left out.

Data: :func:`tests.support.real_like_records` (a 0.1 s servo, 1 ms samples, two input levels per record from
rest, records alternating in sign, speed from a 1024-line encoder differenced over 4 samples: a 1.53 rad/s
quantum), or hand-built records where a verdict needs data made for it.
"""

from __future__ import annotations

import numpy as np
import pytest

from agents.twin import Batch, diagnose, read_csv, write_csv
from agents.twin.evidence import excitation_notes
from agents.twin.noise_floor import noise_floor, quantization_step
from gbo_envs import Experiment
from tests.support import SERVO_PLANT, encoder_speed, real_like_records

ASYMMETRIC = {"coulomb_friction": {"torque": 0.1, "asymmetry": -0.2}}  # 0.08 forward, 0.12 backward
QUANTUM = 2.0 * np.pi / (1024 * 4 * 1e-3)  # rad/s: the generator's encoder


def _open_loop(u, y, dt=1e-3, index=0) -> Experiment:
    t = np.arange(u.size) * dt
    return Experiment(gains=(), t=t, r=u.copy(), u=u, y=y, index=index)


def _servo(u, dt=1e-3, effects=None):
    from agents.twin.open_loop import simulate_open_loop
    from gbo_envs.physics.effects import build_effects

    return simulate_open_loop(SERVO_PLANT, u[None], dt, build_effects(effects or {})).y_true[0]


# -- how records start ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("env_id", ["DCMotor-v0", "LinearMotor-v0", "LinearMotorRig-v0"])
def test_a_fast_closed_loop_step_from_steady_state_is_not_taken_for_motion(env_id):
    """The envs' records: the reference is on from sample 0 and the output creeps out of its steady state. The
    linear motor's position moves 0.8 % of its span within 3 samples, but not in the first: it starts "steady"
    (taken as "moving" it got free initial slopes, which changed guided BO's twin on Linear+coulomb)."""
    import gymnasium as gym

    env = gym.make(f"gbo_envs/{env_id}")
    env.reset(seed=0)
    space = env.unwrapped.action_space
    records = [env.step(space.low + share * (space.high - space.low))[4]["experiment"] for share in (0.2, 0.5, 0.9)]
    assert list(Batch.from_records(records).initial.mode) == ["steady"] * 3


def test_records_that_show_their_rest_are_pinned_there():
    data = Batch.from_records(real_like_records(ASYMMETRIC))
    start = data.initial
    assert list(start.mode) == ["rest"] * 6 and not start.assumed.any()
    assert np.all(start.y0 == 0.0) and np.all(start.u0 == 0.0)
    assert np.all(start.quiet == 100)  # 0.1 s of u = 0 at 1 ms


def test_each_kind_of_start_is_told_from_the_data():
    n = 2001
    u = np.zeros(n)
    u[300:] = 0.4
    rest = _open_loop(u, _servo(u), index=0)
    on_at_once = _open_loop(np.full(n, 0.4), _servo(np.full(n, 0.4)), index=1)  # from standstill, drive just on
    y = _servo(np.full(3 * n, 0.4))[n // 4 : n // 4 + n]  # cut from a long log while the motor accelerates
    moving = _open_loop(np.full(n, 0.4), y, index=2)
    closed = Experiment(gains=(), t=np.arange(n) * 1e-3, r=np.full(n, 50.0), u=0.5 + np.sin(np.arange(n) / 50.0),
                        y=20.0 + 2.0 * (1.0 - np.cos(np.arange(n) / 400.0)), index=3)  # the step came with sample 0
    data = Batch.from_records([rest, on_at_once, moving, closed])
    assert list(data.initial.mode) == ["rest", "rest", "moving", "steady"]
    assert list(data.initial.assumed) == [False, True, False, False]
    assert data.initial.u0[1] == 0.0 and data.initial.u0[0] == 0.0
    assert list(Batch.from_records([rest, closed], initial="steady").initial.mode) == ["steady", "steady"]


def test_a_linear_fit_from_rest_starts_where_the_motor_stands():
    """Today's free rest levels put the simulation at -80 rad/s while the motor stood still; pinned, it starts at 0."""
    from agents.twin.greybox_twin import GreyBoxTwin

    data = Batch.from_records(real_like_records(ASYMMETRIC))
    fit = GreyBoxTwin(n_poles=1).fit(data).greybox_
    assert np.all(fit.y0 == 0.0) and np.all(fit.bias == 0.0)
    assert np.all(np.abs(fit.y_sim[:, :100]) < 1e-9)  # at rest until the first step


# -- observability on the data as a whole ------------------------------------------------------------------------

def _steady_records(sign_pattern, crossing=False):
    """Closed-loop-like records that start with their excitation (rest unobserved), speed of the given signs."""
    n, out = 1001, []
    for k, sign in enumerate(sign_pattern):
        t = np.arange(n) * 1e-3
        u = sign * (0.5 + 0.1 * np.sin(t * 7.0)) - (0.8 * sign if crossing else 0.0) * (t > 0.5)
        y = sign * (40.0 + 5.0 * np.sin(t * 3.0))
        out.append(Experiment(gains=(), t=t, r=np.full(n, 45.0 * sign), u=u, y=y, index=k))
    return Batch.from_records(out)


def test_friction_dead_zone_and_offset_are_absorbed_only_by_rests_the_data_do_not_show():
    hidden = excitation_notes(_steady_records([1, 1, -1]), "speed")  # directions differ, each absorbed by its rest
    assert {"coulomb_friction", "stiction", "dead_zone", "offset"} <= set(hidden)
    shown = excitation_notes(Batch.from_records(real_like_records(ASYMMETRIC, n_records=2)), "speed")
    assert not {"coulomb_friction", "stiction", "dead_zone", "offset"} & set(shown)
    one_way = real_like_records(ASYMMETRIC, n_records=3)[::2]  # from rest, one direction only: still a load to explain
    assert "coulomb_friction" not in excitation_notes(Batch.from_records(one_way), "speed")


def test_a_reversal_within_a_record_shows_friction_and_a_zero_crossing_shows_the_dead_zone():
    notes = excitation_notes(_steady_records([1, 1], crossing=True), "speed")
    assert "dead_zone" not in notes and "offset" in notes


def test_drift_needs_five_experiments_in_time_order():
    few = excitation_notes(Batch.from_records(real_like_records(None, n_records=4)), "speed")
    assert "at least 5 experiments" in few["drift"]
    assert "drift" not in excitation_notes(Batch.from_records(real_like_records(None, n_records=5)), "speed")


# -- the noise floor of real sensors -------------------------------------------------------------------------------

def test_the_floor_finds_an_encoders_quantum_and_never_falls_below_it():
    data = Batch.from_records(real_like_records(ASYMMETRIC))
    step, share = quantization_step(data.y, data.mask)
    assert step == pytest.approx(QUANTUM, rel=1e-6) and share > 0.95
    assert noise_floor(data) >= (1.0 - 1e-6) * QUANTUM / np.sqrt(12.0)


def test_a_quantum_blurred_by_the_windows_timing_jitter_is_still_a_quantum(tmp_path):
    """A lab rig's speed: whole encoder counts over a window whose length jitters by 0.02 % (the PC's clock), in
    rpm, written with two decimals. Counts of 12 per turn over 50 ms: a 100 rpm quantum, read as 99.9-100.1
    rpm steps plus changes of a few tenths between samples of the same count."""
    rng = np.random.default_rng(3)
    n, dt = 650, 0.05
    u = np.repeat(np.arange(13) * 0.25, 50)  # a staircase of 12 steps from rest, 2.5 s each, as a lab's
    speed = _servo(u, dt=dt) * 60.0 / (2.0 * np.pi)  # rpm
    window = dt * (1.0 + 2e-4 * rng.standard_normal(n))
    counts = np.round(speed / 60.0 * 12.0 * dt)  # whole counts per window
    rpm = np.round(counts * 60.0 / (12.0 * window), 2)
    path = write_csv([_open_loop(u, rpm, dt=dt)], tmp_path / "rig.csv")
    data = Batch.from_records(read_csv(path))
    assert quantization_step(data.y, data.mask)[0] == pytest.approx(100.0, rel=0.01)
    assert noise_floor(data) >= 0.99 * 100.0 / np.sqrt(12.0)


@pytest.mark.parametrize("colour", ["ar1", "moving_window"])
def test_coloured_and_filtered_noise_are_not_underestimated(colour):
    rng = np.random.default_rng(7)
    n = 10001
    u = np.zeros(n)
    u[500:5000], u[5000:] = 0.3, 0.5
    white = rng.standard_normal(n + 8)
    if colour == "ar1":  # first-order low-pass noise, correlation 0.9 per sample
        noise = np.zeros(n)
        for k in range(1, n):
            noise[k] = 0.9 * noise[k - 1] + np.sqrt(1.0 - 0.81) * white[k]
    else:  # a speed averaged over a moving window of 8 samples, as drive firmware filters it
        noise = np.convolve(white, np.full(8, 1.0 / np.sqrt(8.0)), mode="valid")[:n]
    sigma = 0.1
    data = Batch.from_records([_open_loop(u, _servo(u) + sigma * noise)])
    assert noise_floor(data) == pytest.approx(sigma * np.std(noise), rel=0.2)


# -- records of any shape ------------------------------------------------------------------------------------------

def test_an_open_loop_csv_may_leave_out_r(tmp_path):
    records = real_like_records(None, n_records=2, duration=0.5)
    path = tmp_path / "open.csv"
    frame = __import__("pandas").concat(
        [__import__("pandas").DataFrame({"experiment": rec.index + 1, "t": rec.t, "u": rec.u, "y": rec.y})
         for rec in records])
    frame.to_csv(path, index=False)
    read = read_csv(path)
    assert all(np.array_equal(rec.r, rec.u) for rec in read)
    assert all(np.array_equal(a.y, b.y) for a, b in zip(read, records))


# -- the diagnosis on real-like data -------------------------------------------------------------------------------

@pytest.mark.slow
def test_direction_dependent_friction_from_rest_is_found_and_the_error_falls_to_the_noise():
    data = Batch.from_records(real_like_records(ASYMMETRIC))
    result = diagnose(data, spec=__import__("agents.twin.model", fromlist=["ModelSpec"]).ModelSpec(n_poles=1))
    assert result.best == "coulomb_friction"
    fit = result.fits["coulomb_friction"]
    params = fit.effect_params["coulomb_friction"]
    assert params["torque"] == pytest.approx(0.1, rel=0.05) and params["asymmetry"] == pytest.approx(-0.2, abs=0.03)
    assert fit.rmse <= 0.5 * result.current.rmse  # the RMSE falls by at least half
    assert fit.rmse <= 1.5 * result.noise_rmse


@pytest.mark.slow
@pytest.mark.parametrize(("name", "effects", "levels"), [
    ("saturation", {"saturation": {"limit": 0.45}}, (0.3, 0.6)),
    # the second level inside the dead band while the motor runs: a dead zone lets it coast, friction brakes it
    # (with two levels beyond the band the two are the same constant loss: indistinguishable)
    ("dead_zone", {"dead_zone": {"width": 0.16}}, (0.5, 0.05)),
    ("time_delay", {"time_delay": {"delay": 0.03}}, (0.3, 0.6)),
])
def test_each_real_like_set_names_its_effect_and_reaches_the_noise_floor(name, effects, levels):
    data = Batch.from_records(real_like_records(effects, levels=levels))
    result = diagnose(data, spec=__import__("agents.twin.model", fromlist=["ModelSpec"]).ModelSpec(n_poles=1))
    assert result.best == name
    assert result.fits[name].rmse <= 1.5 * result.noise_rmse


def test_encoder_speed_reads_whole_counts():
    speed = encoder_speed(np.full(1000, 30.0), 1e-3, lines=1024, window=4)
    ratio = speed[4:] / QUANTUM
    assert np.allclose(ratio, np.round(ratio)) and abs(speed[4:].mean() - 30.0) < QUANTUM


# -- the ranking a physicist would sign ----------------------------------------------------------------------------

def _candidate(effect, share, rmse, delta_bic):
    return {"effect": effect, "share": share, "rmse": rmse, "delta_bic": delta_bic}


def test_an_effect_that_explains_a_few_percent_does_not_beat_one_that_explains_much_by_a_hair():
    from agents.twin.ranking import _by_share

    drift = _candidate("drift", 3.0, 0.99, -60.0)  # the lab rig of issue 35: 3 % of the residual, first by BIC
    delay = _candidate("time_delay", 44.0, 1.00, -50.0)
    assert [c["effect"] for c in _by_share([drift, delay])] == ["time_delay", "drift"]
    clearly = _candidate("drift", 3.0, 0.90, -60.0)  # unless the held-out error says so clearly (10 % lower)
    assert [c["effect"] for c in _by_share([clearly, delay])] == ["drift", "time_delay"]
    close = _candidate("offset", 40.0, 1.0, -40.0)  # shares that are close keep the BIC order
    assert [c["effect"] for c in _by_share([delay, close])] == ["time_delay", "offset"]


def test_the_catalogue_effects_go_before_a_grown_order():
    from agents.twin.ranking import _physics_first

    def kind(candidate, what):
        return {**candidate, "kind": what}

    # guided BO's twin on LinearMotor-v0 with Coulomb friction, four records: the pole pair first by BIC, 8 % ahead
    pole_pair = kind(_candidate("pole_pair", 88.7, 2.08e-5, -2422.1), "order")
    saturation = kind(_candidate("saturation", 85.4, 2.26e-5, -2236.1), "effect")
    zero = kind(_candidate("zero", 14.9, 5.30e-5, -180.6), "order")
    coulomb = kind(_candidate("coulomb_friction", 23.1, 5.00e-5, -318.9), "effect")
    ranked = _physics_first([pole_pair, saturation, zero, coulomb])
    assert [c["effect"] for c in ranked] == ["saturation", "coulomb_friction", "pole_pair", "zero"]


@pytest.mark.parametrize("dt", [1e-4, 5e-2])
def test_sample_times_from_a_tenth_of_a_millisecond_to_fifty(dt):
    from agents.twin.linear_fit import linear_fit
    from agents.twin.model import ModelSpec

    n = 400
    u = np.zeros(n)
    u[20:] = 0.4
    plant = SERVO_PLANT if dt > 1e-3 else __import__("gbo_envs").ContinuousPlant((4e4,), (1.0, 400.0))  # 2.5 ms lag
    from agents.twin.open_loop import simulate_open_loop

    y = simulate_open_loop(plant, u[None], dt).y_true[0]
    fit = linear_fit(Batch.from_records([_open_loop(u, y, dt=dt)]), ModelSpec(n_poles=1))
    assert fit.rmse <= 1e-3 * np.ptp(y)
    assert fit.plant.dc_gain == pytest.approx(plant.dc_gain, rel=1e-3)


def test_a_record_cut_from_a_long_log_gets_its_moving_state_estimated():
    """A second-order plant's record that starts while it accelerates: a rest level and a bias cannot start it
    with a slope; the estimated initial state does."""
    from agents.twin.linear_fit import linear_fit
    from agents.twin.model import ModelSpec
    from agents.twin.open_loop import simulate_open_loop

    plant = __import__("gbo_envs").ContinuousPlant((9.544,), (1.0, 4.145, 4.199), delay=0.002)
    n, dt = 1500, 0.002
    u = np.full(3 * n, 40.0)
    u[2 * n:] = 60.0
    y = simulate_open_loop(plant, u[None], dt).y_true[0]
    records = [_open_loop(u[n // 3 : n // 3 + n], y[n // 3 : n // 3 + n], dt=dt, index=0),
               _open_loop(u[n + n // 2 : n + n // 2 + n], y[n + n // 2 : n + n // 2 + n], dt=dt, index=1)]
    data = Batch.from_records(records)
    assert list(data.initial.mode) == ["moving", "moving"]
    fit = linear_fit(data, ModelSpec())
    assert fit.start.shape == (2, 1) and abs(fit.start[0, 0]) > 10.0  # rad/s per s: the first accelerates
    assert fit.rmse < 1e-3
    assert fit.plant.dc_gain == pytest.approx(plant.dc_gain, rel=1e-3)
    rested = linear_fit(Batch.from_records(records, initial="steady"), ModelSpec())
    assert rested.rmse > 100.0 * fit.rmse
