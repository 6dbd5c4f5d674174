"""Encoders with jitter before the count: unbiased readings, the stated noise, common random numbers."""

from __future__ import annotations

import numpy as np
import pytest

from gbo_envs.physics.block import RowNoise
from gbo_envs.physics.encoder import PositionEncoder, SpeedEncoder

DT = 0.002


def _readings(block, value: float, batch: int = 2000, samples: int = 400, seed: int = 0) -> np.ndarray:
    block.reset(batch, np.random.default_rng(seed), DT)
    y = np.full(batch, value)
    return np.array([block.measure(y) for _ in range(samples)])


@pytest.mark.parametrize("jitter_increments", [0.0, 0.25, 1.0])
def test_speed_encoder_is_unbiased_with_the_stated_noise(jitter_increments):
    encoder = SpeedEncoder(lines=2048, window=10, jitter=jitter_increments * 2 * np.pi / 2048)
    step = encoder.speed_resolution(DT)
    readings = _readings(encoder, 306.0)
    np.testing.assert_allclose(readings / step, np.round(readings / step), atol=1e-6)  # whole counts
    assert readings.mean() == pytest.approx(306.0, abs=0.005)
    # two independent quantisation errors (variance step^2 / 6) and two jitters
    expected = np.sqrt(step**2 / 6 + 2 * (jitter_increments * step) ** 2)
    assert np.sqrt(np.mean((readings - 306.0) ** 2)) == pytest.approx(expected, rel=0.05)


def test_speed_encoder_window_sets_resolution_and_lag():
    one, ten = SpeedEncoder(2048, 1), SpeedEncoder(2048, 10)
    assert one.speed_resolution(DT) == pytest.approx(10 * ten.speed_resolution(DT))
    # a ramp in speed is read with the window's mean delay of (M - 1) dt / 2
    ten.reset(1, np.random.default_rng(0), DT)
    slope = 100.0  # rad/s^2
    speeds = np.array([ten.measure(np.array([245.0 + slope * k * DT]))[0] for k in range(500)])
    true = 245.0 + slope * np.arange(500) * DT
    lag = np.mean(true[100:] - speeds[100:]) / slope
    assert lag == pytest.approx(4.5 * DT, abs=0.5 * DT)


def test_position_encoder_dithers_between_levels():
    sensor = PositionEncoder(resolution=5e-6, jitter=1.25e-6)
    readings = _readings(sensor, 0.030 + 2.5e-6)  # half-way between two levels
    levels, counts = np.unique(np.round(readings / 5e-6).astype(int), return_counts=True)
    assert set(levels[counts > 0.4 * readings.size]) == {6000, 6001}  # the two neighbours, about equally often
    assert readings.mean() == pytest.approx(0.030 + 2.5e-6, abs=5e-8)
    assert not PositionEncoder(5e-6).stochastic and sensor.stochastic


def test_rows_with_the_same_draw_see_the_same_noise():
    encoder = SpeedEncoder(2048, 10, jitter=0.001)
    encoder.reset(6, np.random.default_rng(4), DT, draws=np.array([0, 1, 2, 0, 1, 2]))
    y = np.full(6, 250.0)
    for _ in range(20):
        out = encoder.measure(y)
        np.testing.assert_array_equal(out[:3], out[3:])
    noise = RowNoise(np.random.default_rng(1), 4, draws=np.array([1, 0, 1, 0]))
    values = noise.standard_normal(3)
    assert values.shape == (3, 4) and np.array_equal(values[:, 0], values[:, 2])


@pytest.mark.parametrize(("build", "parameter"), [
    (lambda: SpeedEncoder(lines=0), "lines"),
    (lambda: SpeedEncoder(lines=2048.5), "lines"),
    (lambda: SpeedEncoder(lines=2048, window=0), "window"),
    (lambda: SpeedEncoder(lines=2048, jitter=-1.0), "jitter"),
    (lambda: PositionEncoder(resolution=0.0), "resolution"),
    (lambda: PositionEncoder(resolution=float("inf")), "resolution"),
    (lambda: PositionEncoder(resolution=5e-6, jitter=float("nan")), "jitter"),
])
def test_bad_encoder_parameters_are_named(build, parameter):
    with pytest.raises(ValueError, match=parameter):
        build()


def test_noisy_encoder_needs_a_generator():
    with pytest.raises(ValueError, match="rng"):
        SpeedEncoder(2048).reset(3, None, DT)
