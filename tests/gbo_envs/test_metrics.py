"""The four metrics and the cost, checked on responses whose values are known by hand."""

from __future__ import annotations

import numpy as np
import pytest

from gbo_envs.metrics import step_metrics, weighted_cost

T = np.linspace(0.0, 5.0, 2501)


def test_first_order_response_has_textbook_metrics():
    tau = 0.5
    y = 245.0 + 61.0 * (1.0 - np.exp(-T / tau))
    overshoot, settling, rise, itae = step_metrics(T, y, 245.0, 306.0)
    assert overshoot == 0.0
    # enters the 2 % band at t = tau ln 50 and stays (sampled every 2 ms)
    assert settling == pytest.approx(tau * np.log(50.0), abs=2e-3)
    # 10 % -> 60 %: tau (ln 10 - ln(10/4))
    assert rise == pytest.approx(tau * (np.log(1 / 0.4) - np.log(1 / 0.9)), abs=1e-5)
    # int_0^T t 61 e^{-t/tau} dt = 61 tau^2 (1 - e^{-T/tau} (1 + T/tau))
    assert itae == pytest.approx(61.0 * tau**2 * (1.0 - np.exp(-10.0) * 11.0), rel=1e-5)


def test_overshoot_is_relative_to_final_value_and_step_height():
    y = np.full(T.size, 306.0)
    y[:1000] = np.linspace(245.0, 312.1, 1000)
    y[1000:1200] = 312.1
    metrics = step_metrics(T, y, 245.0, 306.0)
    assert metrics[0] == pytest.approx(100 * 6.1 / 61.0)


def test_response_that_never_settles_or_rises_gets_the_final_time():
    y = np.full(T.size, 250.0)
    _, settling, rise, _ = step_metrics(T, y, 245.0, 306.0)
    assert settling == T[-1]
    assert rise == T[-1]


def test_downward_step_mirrors_upward_step():
    up = 245.0 + 61.0 * (1.0 - np.exp(-T / 0.3))
    down = 306.0 - (up - 245.0)
    assert np.allclose(step_metrics(T, up, 245.0, 306.0), step_metrics(T, down, 306.0, 245.0))


def test_batch_equals_rows():
    ys = np.stack([245.0 + 61.0 * (1.0 - np.exp(-T / tau)) for tau in (0.2, 0.7)])
    batch = step_metrics(T, ys, 245.0, 306.0)
    assert batch.shape == (2, 4)
    for row, y in zip(batch, ys):
        assert np.allclose(row, step_metrics(T, y, 245.0, 306.0))


def test_zero_step_height_is_rejected():
    with pytest.raises(ValueError, match="step height"):
        step_metrics(T, np.zeros(T.size), 1.0, 1.0)


def test_weighted_cost_normalises_each_metric():
    weights = np.array([0.44, 0.22, 0.22, 0.11])
    normalizers = np.array([2.0, 4.0, 1.0, 10.0])
    assert weighted_cost(normalizers, weights, normalizers) == pytest.approx(weights.sum())
    assert weighted_cost([2.0, 0.0, 0.0, 0.0], weights, normalizers) == pytest.approx(0.44)
