"""The plant's state-space realisation is scipy's ``tf2ss``, value for value, and its checks are unchanged."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import tf2ss

from gbo_envs.physics.lti import ContinuousPlant


def _plants():
    rng = np.random.default_rng(0)
    for _ in range(500):
        n = int(rng.integers(1, 6))
        m = int(rng.integers(0, n))
        lead = 1.0 if rng.random() < 0.5 else float(rng.normal() * 10.0)
        den = (lead, *(rng.normal(size=n) * 10.0 ** rng.uniform(-3, 3, n)))
        yield tuple(rng.normal(size=m + 1) * 10.0 ** rng.uniform(-3, 3, m + 1)), den
    yield (9.544,), (1.0, 4.145, 4.199)
    yield (1e-15, 2.0), (1.0, 3.0, 2.0)  # a leading coefficient tf2ss trims
    yield (0.0, 1.0), (1.0, 2.0, 0.0)
    yield (3.0,), (2.0, 2.5, 0.0)


@pytest.mark.filterwarnings("ignore::scipy.signal.BadCoefficients")  # tf2ss on the trimmed coefficient
def test_state_space_is_tf2ss_bit_for_bit():
    for num, den in _plants():
        a, b, c = ContinuousPlant(num=num, den=den).state_space()
        ref_a, ref_b, ref_c, _ = tf2ss(num, den)
        np.testing.assert_array_equal(a, ref_a)
        np.testing.assert_array_equal(b, ref_b[:, 0])
        np.testing.assert_array_equal(c, ref_c[0])


def test_coefficients_become_python_floats_from_any_sequence():
    for num in ((2,), [2.0], np.array([2.0]), (np.float64(2.0),), 2.0):
        plant = ContinuousPlant(num=num, den=(1.0, np.float64(3.0)))
        assert plant.num == (2.0,) and plant.den == (1.0, 3.0)
        assert all(type(c) is float for c in plant.num + plant.den)
    assert repr(ContinuousPlant(num=(np.float64(9.544),), den=(1.0, 4.145, 4.199), delay=0.002)) == \
        "ContinuousPlant(num=(9.544,), den=(1.0, 4.145, 4.199), delay=0.002, output='speed')"


@pytest.mark.parametrize("num, den, message", [((1.0,), (0.0, 1.0), "leading coefficient"),
                                               ((np.nan,), (1.0, 1.0), "finite"),
                                               ((1.0,), (1.0, np.inf), "finite"),
                                               ((1.0, 2.0), (1.0, 3.0), "strictly proper"),
                                               ((0.0, 0.0, 1.0), (1.0, 3.0), None)])
def test_bad_coefficients_are_refused(num, den, message):
    if message is None:  # leading zeros of the numerator do not count
        assert ContinuousPlant(num=num, den=den).order == 1
        return
    with pytest.raises(ValueError, match=message):
        ContinuousPlant(num=num, den=den)
