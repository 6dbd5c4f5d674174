"""The shared helpers: JSON sanitising, thread limiting, the lazy pyplot import and gain grids."""

from __future__ import annotations

import json
import math
import sys

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from agents.jsonable import jsonable, to_json
from agents.thread_limits import single_thread
from gbo_envs.gain_grid import grid_axes, grid_points
from gbo_envs.lazy_pyplot import pyplot


# -- JSON ------------------------------------------------------------------------------------------------
def test_jsonable_converts_numpy_and_containers_to_plain_python():
    value = {"a": np.float64(0.1), 2: np.arange(3), "t": (np.int64(4), np.bool_(True)), "s": {"x"},
             "nested": {"m": np.array([[1.5, 2.5]])}}
    plain = jsonable(value)
    assert plain == {"a": 0.1, "2": [0, 1, 2], "t": [4, True], "s": ["x"], "nested": {"m": [[1.5, 2.5]]}}
    assert type(plain["a"]) is float and type(plain["2"][0]) is int and type(plain["t"][1]) is bool


def test_floats_round_trip_exactly_and_keys_are_sorted():
    x = np.float64(1 / 3)
    text = to_json({"b": x, "a": [np.float32(0.1)]})
    assert text.index('"a"') < text.index('"b"')
    assert json.loads(text)["b"] == float(x)
    assert json.loads(text)["a"][0] == float(np.float32(0.1))


def test_non_finite_floats_are_kept_or_nulled_on_request():
    value = {"nan": np.nan, "inf": [np.float64(np.inf)], "ok": 1.0}
    assert math.isnan(json.loads(to_json(value))["nan"])
    assert json.loads(to_json(value, finite=True)) == {"nan": None, "inf": [None], "ok": 1.0}
    strict = to_json(value, finite=True)
    assert "NaN" not in strict and "Infinity" not in strict


def test_unknown_objects_become_their_repr_and_key_order_can_be_kept():
    class Thing:
        def __repr__(self) -> str:
            return "Thing()"

    assert jsonable([Thing()]) == ["Thing()"]
    assert to_json({"z": 1, "a": 2}, sort_keys=False) == '{"z": 1, "a": 2}'


# -- threads ---------------------------------------------------------------------------------------------
def _threads(user_api: str) -> list[int]:
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == user_api]


@pytest.fixture
def blas_on_two_threads():
    """BLAS on two threads during the test, whatever the machine's cores or the suite's limit (make test's
    xdist workers run BLAS on one thread: tests/conftest.py), so that a limit to one thread and its
    restoring both show."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=2, user_api="blas"):
        assert set(_threads("blas")) == {2}
        yield


@pytest.mark.usefixtures("blas_on_two_threads")
def test_single_thread_limits_blas_inside_and_restores_after():
    before = _threads("blas")
    assert before, "numpy should have loaded a BLAS"
    with single_thread():
        assert _threads("blas") == [1] * len(before)
    assert _threads("blas") == before


@pytest.mark.usefixtures("blas_on_two_threads")
def test_single_thread_decorates_each_call_anew():
    @single_thread()
    def inside() -> list[int]:
        return _threads("blas")

    assert inside() == inside() == [1] * len(_threads("blas"))


@pytest.mark.usefixtures("blas_on_two_threads")
def test_single_thread_inside_a_block_of_the_same_pools_sets_no_limit(monkeypatch):
    from threadpoolctl import ThreadpoolController

    calls = []
    limit = ThreadpoolController.limit
    monkeypatch.setattr(ThreadpoolController, "limit", lambda self, **kw: calls.append(kw) or limit(self, **kw))
    before = _threads("blas")
    with single_thread(user_api=None):
        with single_thread(), single_thread("openmp"):
            assert _threads("blas") == [1] * len(before)
        assert _threads("blas") == [1] * len(before)  # the inner blocks restored nothing
    assert _threads("blas") == before
    with single_thread("openmp"), single_thread():  # BLAS is not held by the OpenMP block
        assert _threads("blas") == [1] * len(before)
    assert [kw["user_api"] for kw in calls] == [None, "openmp", "blas"]


def test_single_thread_rejects_an_unknown_api():
    with pytest.raises(ValueError, match="user_api"):
        single_thread("mkl")


# -- pyplot ----------------------------------------------------------------------------------------------
def test_pyplot_is_the_pyplot_module_on_a_headless_backend():
    plt = pyplot()
    assert plt is sys.modules["matplotlib.pyplot"]
    assert plt.get_backend().lower() in ("agg", "module://matplotlib_inline.backend_inline")


# -- gain grids ------------------------------------------------------------------------------------------
def test_grid_points_run_over_every_combination_first_gain_slowest():
    axes = grid_axes([0.0, 10.0], [1.0, 30.0], 3)
    np.testing.assert_array_equal(axes[0], [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(axes[1], [10.0, 20.0, 30.0])
    points = grid_points(axes)
    assert points.shape == (9, 2)
    np.testing.assert_array_equal(points[:3], [[0.0, 10.0], [0.0, 20.0], [0.0, 30.0]])
    values = points[:, 0] * 100 + points[:, 1]
    np.testing.assert_array_equal(values.reshape(3, 3)[:, 0], [10.0, 60.0, 110.0])


def test_grid_keeps_the_dtype_of_the_bounds():
    axes = grid_axes(np.float32([0.1]), np.float32([0.7]), 4)
    np.testing.assert_array_equal(axes[0], np.linspace(np.float32(0.1), np.float32(0.7), 4))
    assert grid_points(axes).dtype == np.float32


@pytest.mark.parametrize(("low", "high", "points", "match"), [
    ([0.0], [1.0, 2.0], 3, "low, high"),
    ([[0.0]], [[1.0]], 3, "low, high"),
    ([1.0], [0.0], 3, "low <= high"),
    ([np.nan], [1.0], 3, "finite"),
    ([0.0], [1.0], 0, "points_per_gain"),
    ([0.0], [1.0], 2.5, "points_per_gain"),
])
def test_grid_axes_rejects_bad_bounds_and_counts(low, high, points, match):
    with pytest.raises(ValueError, match=match):
        grid_axes(low, high, points)


def test_grid_points_rejects_empty_axes():
    with pytest.raises(ValueError, match="axes"):
        grid_points([])
    with pytest.raises(ValueError, match="axes"):
        grid_points([np.array([])])
