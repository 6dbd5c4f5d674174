"""The experiment record: one validator (property tests), its producers and consumers, and the result table."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import agents
import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.csvio import read_csv, write_csv
from agents.twin.records import Batch, as_records
from gbo_envs.experiment import SIGNALS, Experiment, RecordError, validate_signals

FINITE = st.floats(min_value=-1e9, max_value=1e9, allow_nan=False, allow_infinity=False)
BAD_VALUES = st.sampled_from([math.nan, math.inf, -math.inf])


@st.composite
def signals(draw, min_steps: int = 3, max_steps: int = 40):
    """Four finite signals of one length with a strictly increasing time."""
    n = draw(st.integers(min_steps, max_steps))
    steps = draw(arrays(np.float64, n - 1, elements=st.floats(1e-3, 10.0)))
    t = np.concatenate([[draw(st.floats(-10.0, 10.0))], steps]).cumsum()
    r, u, y = (draw(arrays(np.float64, n, elements=FINITE)) for _ in range(3))
    return t, r, u, y


# -- the validator: random finite input never yields NaN, bad input always raises ----------------------
@settings(max_examples=60, deadline=None)
@given(signals(), arrays(np.float64, st.integers(0, 4), elements=FINITE), st.one_of(FINITE, st.just(math.nan)))
def test_valid_finite_records_are_kept_exactly_and_never_hold_nan(sig, gains, cost):
    record = Experiment(gains=gains, t=sig[0], r=sig[1], u=sig[2], y=sig[3], cost=cost, index=2)
    for name, original in zip(SIGNALS, sig):
        values = getattr(record, name)
        assert values.dtype == np.float64 and not np.isnan(values).any()
        np.testing.assert_array_equal(values, original)
        assert not values.flags.writeable
    assert np.all(np.diff(record.t) > 0) and record.n_steps == sig[0].size and record.dt > 0
    assert record == Experiment.from_mapping(record.to_dict())


@settings(max_examples=60, deadline=None)
@given(signals(), st.sampled_from(SIGNALS), st.data())
def test_unequal_lengths_raise(sig, field, data):
    sig = dict(zip(SIGNALS, sig))
    cut = data.draw(st.integers(1, sig[field].size - 1))
    sig[field] = sig[field][:-cut]
    with pytest.raises(ValueError, match=r"t, r, u, y: must have equal lengths"):
        validate_signals(**sig)


@settings(max_examples=60, deadline=None)
@given(signals(), st.sampled_from(SIGNALS), BAD_VALUES, st.data())
def test_non_finite_values_raise_naming_the_field_and_sample(sig, field, bad, data):
    sig = {name: values.copy() for name, values in zip(SIGNALS, sig)}
    k = data.draw(st.integers(0, sig[field].size - 1))
    sig[field][k] = bad
    with pytest.raises(RecordError) as caught:
        validate_signals(**sig)
    assert caught.value.field == field and caught.value.sample == k
    assert str(caught.value).startswith(f"{field}: must be finite")


@settings(max_examples=60, deadline=None)
@given(signals(min_steps=4), st.data())
def test_time_that_does_not_increase_raises(sig, data):
    t = sig[0].copy()
    k = data.draw(st.integers(1, t.size - 1))
    t[k] = t[k - 1] - data.draw(st.floats(0.0, 5.0))
    with pytest.raises(RecordError, match=r"^t: must increase strictly") as caught:
        validate_signals(t, *sig[1:])
    assert caught.value.sample <= k


@settings(max_examples=40, deadline=None)
@given(signals(), st.sampled_from(SIGNALS), st.integers(2, 3))
def test_wrong_dimensions_raise(sig, field, ndim):
    sig = dict(zip(SIGNALS, sig))
    sig[field] = np.broadcast_to(sig[field], (2,) * (ndim - 1) + sig[field].shape)
    with pytest.raises(ValueError, match=rf"^{field}: must be a 1-D array"):
        validate_signals(**sig)


@settings(max_examples=40, deadline=None)
@given(signals(min_steps=2, max_steps=2), st.integers(3, 10))
def test_too_short_records_raise(sig, min_steps):
    with pytest.raises(ValueError, match=rf"need at least {min_steps} samples, got 2"):
        validate_signals(*sig, min_steps=min_steps)
    with pytest.raises(ValueError, match="need at least 3 samples"):
        Experiment(gains=[1.0], t=sig[0], r=sig[1], u=sig[2], y=sig[3])


@settings(max_examples=40, deadline=None)
@given(signals(min_steps=5), st.floats(1e-3, 0.5))
def test_uniform_grid_is_checked_only_when_asked(sig, jump):
    n = sig[0].size
    t = np.arange(n) * 0.01
    t[n // 2:] += jump * 0.01
    validate_signals(t, *sig[1:])  # any increasing time is a record
    with pytest.raises(RecordError, match=r"^t: must be uniformly spaced") as caught:
        validate_signals(t, *sig[1:], uniform_rtol=1e-6)
    assert caught.value.sample == n // 2


@pytest.mark.parametrize(("changes", "message"), [
    ({"gains": [[1.0, 2.0]]}, "gains: must be a 1-D array"),
    ({"gains": [1.0, math.nan]}, "gains: must be finite"),
    ({"cost": math.inf}, "cost: must be finite or NaN"),
    ({"cost": "cheap"}, "cost: must be a number"),
    ({"source": "rig"}, "source: must be one of"),
    ({"index": 1.5}, "index: must be an integer"),
    ({"metrics": [1.0, 2.0]}, "metrics: must be a mapping or 4 values"),
    ({"y": None}, "t, r, u, y: give all four signals or none, got only t, r, u"),
    ({"u": ["a", "b", "c"]}, "u: must be numeric"),
])
def test_other_fields_raise_naming_the_field(changes, message):
    t = np.arange(3) * 0.1
    fields = {"gains": [1.0, 2.0], "t": t, "r": t, "u": t, "y": t, **changes}
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        Experiment(**fields)


def test_record_without_signals_and_metrics_in_metric_order():
    record = Experiment(gains=[0.5, 1.0], cost=0.3, metrics=np.array([1.0, 2.0, 3.0, 4.0]), source="twin")
    assert not record.has_signals and record.n_steps == 0 and math.isnan(record.dt)
    assert record.metrics == dict(zip(gbo_envs.METRIC_NAMES, [1.0, 2.0, 3.0, 4.0]))
    assert "t" not in record.to_dict()
    with pytest.raises(ValueError, match="record 1, t, r, u, y: required for identification"):
        as_records([record])


# -- producers and consumers ---------------------------------------------------------------------------
def test_env_step_puts_the_record_in_info_beside_the_flat_keys():
    env = gym.make("gbo_envs/DCMotorDrift-v0")
    env.reset(seed=0)
    env.step(np.array([0.5, 1.2]))
    info = env.step(np.array([0.6, 1.1]))[4]
    record = info["experiment"]
    assert isinstance(record, Experiment) and record.source == "plant" and record.index == 1
    np.testing.assert_array_equal(record.gains, info["gains"])
    for name in SIGNALS:
        np.testing.assert_array_equal(getattr(record, name), info[name])
    assert record.cost == info["cost"] and record.metrics == info["metrics"]
    info["y"][:] = 0.0  # the flat keys stay writable copies; the record does not change
    assert record.y[-1] != 0.0 and "plant_params" in info


def test_twin_accepts_records_mappings_arrays_and_frames_alike():
    env = gym.make("gbo_envs/DCMotor-v0", noise=False)
    env.reset(seed=0)
    infos = [env.step(np.array(g))[4] for g in ([0.5, 1.2], [0.8, 1.0])]
    records = [info["experiment"] for info in infos]
    plain = [{name: info[name] for name in SIGNALS} for info in infos]
    tables = [np.column_stack([info[name] for name in SIGNALS]) for info in infos]
    for given_records in (records, infos, plain, tables):
        out = as_records(given_records)
        assert [r.index for r in out] == [0, 1]
        np.testing.assert_array_equal(out[1].y, infos[1]["y"])
    data = Batch.from_records(records)
    np.testing.assert_array_equal(data.index, [0, 1])
    np.testing.assert_array_equal(data.u[1], records[1].u)


def test_csv_round_trip_is_lossless_for_the_signals(tmp_path):
    env = gym.make("gbo_envs/DCMotorRig-v0")
    env.reset(seed=3)
    records = [env.step(np.array(g))[4]["experiment"] for g in ([0.4, 1.0], [0.9, 1.9])]
    back = read_csv(write_csv(records, tmp_path / "rig.csv", gain_names=("Kp", "Ki")), gain_names=("Kp", "Ki"))
    assert back == [record.replace(metrics={}) for record in records]  # the CSV carries no metrics


# -- the result table ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def guided():
    # the paper's Algorithm 1: its twin evaluations are rows of the result (behind include_twin)
    return agents.make("guided-bo", guidance="iterations", n_samples=50).run(gym.make("gbo_envs/DCMotor-v0"), budget=7,
                                                                             seed=0)


def test_to_pandas_has_one_row_per_real_experiment(guided):
    frame = guided.to_pandas()
    assert frame["experiment"].tolist() == list(range(1, 8)) and set(frame["source"]) == {"plant"}
    assert list(frame.columns) == ["experiment", "source", "Kp", "Ki", "cost", "best_cost", "true_cost", "unstable",
                                   "feasible", "overshoot_pct", "settling_time", "rise_time", "itae", "wall_time"]
    assert guided.n_twin > 0  # the twin rows exist, behind include_twin
    full = guided.to_pandas(include_twin=True)
    assert len(full) == 7 + guided.n_twin and set(full["source"]) == {"plant", "twin"}
    assert {"activation", "twin_iteration"} <= set(full.columns)
    np.testing.assert_array_equal(full[full.source == "plant"]["cost"], frame["cost"])


def test_records_and_samples_match_the_table(guided):
    frame = guided.to_pandas()
    assert len(guided.experiments) == 7
    assert [r.index for r in guided.experiments] == list(range(7))
    np.testing.assert_array_equal([r.cost for r in guided.experiments], frame["cost"])
    np.testing.assert_array_equal(np.array([r.gains for r in guided.experiments]), frame[["Kp", "Ki"]])
    samples = guided.samples()
    assert list(samples.columns) == ["experiment", "source", "t", "r", "u", "y"]
    assert len(samples) == 7 * guided.experiments[0].n_steps
    third = samples[samples.experiment == 3]
    np.testing.assert_array_equal(third["y"], guided.experiments[2].y)


def test_print_is_a_short_summary(guided):
    text = str(guided)
    assert text == repr(guided) and len(text) < 200
    best = guided.best_gains
    assert text == (f"TuningResult(guided-bo on gbo_envs/DCMotor-v0, seed 0: 7 real experiments "
                    f"(+{guided.n_twin} twin evaluations); best Kp = {best[0]:.4g} (input units)/(rad/s), "
                    f"Ki = {best[1]:.4g} 1/s, "
                    f"cost {guided.best_cost:.4g})")
    empty = agents.TuningResult(tuner="bo", env_id="x", gain_names=("Kp",))
    assert str(empty) == "TuningResult(bo on x, seed None: 0 real experiments)"
    assert empty.to_pandas().empty and empty.samples().empty


def test_pickled_record_is_equal_and_read_only():
    import pickle

    env = gym.make("gbo_envs/DCMotor-v0")
    env.reset(seed=0)
    record = env.step(np.array([0.5, 1.2]))[4]["experiment"]
    back = pickle.loads(pickle.dumps(record))
    assert back == record and back is not record and not back.y.flags.writeable
    assert back != record.replace(index=5) and back != record.replace(cost=record.cost + 1e-12)


def test_a_step_on_the_twin_is_a_twin_record():
    from agents.twin.env import make_twin_env

    plant = gym.make("gbo_envs/DCMotor-v0")
    twin = make_twin_env(plant, plant.unwrapped.loop.plant)
    twin.reset(seed=0)
    record = twin.step(np.array([0.5, 1.2]))[4]["experiment"]
    assert record.source == "twin" and record.has_signals and record.index == 0


def test_read_only_signals_are_kept_and_writeable_ones_copied():
    t = np.arange(4) * 0.01
    signals = np.stack([t, np.full(4, 306.0), np.arange(4.0), np.arange(4.0) + 245])
    writeable = Experiment(gains=(), t=signals[0], r=signals[1], u=signals[2], y=signals[3])
    view = signals[2]
    view.setflags(write=False)  # read-only, but its memory can still change through ``signals``
    of_view = Experiment(gains=(), t=signals[0], r=signals[1], u=view, y=signals[3])
    assert not np.shares_memory(writeable.u, signals) and not np.shares_memory(of_view.u, signals)
    signals.setflags(write=False)  # now nothing can change it: records share it, uncopied
    shared = Experiment(gains=(), t=signals[0], r=signals[1], u=signals[2], y=signals[3])
    assert shared.u.base is signals and not shared.u.flags.writeable
    np.testing.assert_array_equal(shared.u, writeable.u)
