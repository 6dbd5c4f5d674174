"""The twin's checks of the records before a fit (issue 57): a log whose output answers its input in the same
sample is warned of, causal logs open or closed loop are not; values beyond 1e100 and records too short for
the model are refused with the experiment named; ``n_jobs`` is capped at the usable cores."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.signal import lfilter

from agents.twin.fits import fit_structure
from agents.twin.model import ModelSpec
from agents.twin.record_checks import NonCausalRecordWarning
from agents.twin.records import Batch
from agents.twin.workers import check_n_jobs, worker_processes
from tests.support import loop_records


def open_loop(same_sample: bool, n: int = 3, seed: int = 0) -> list[dict]:
    """Open-loop records of ``y[k] = 0.8 y[k-1] + 0.2 u[k-1]`` (or ``u[k]``: non-causal) under a held +-1 input."""
    rng = np.random.default_rng(seed)
    records = []
    for _ in range(n):
        u = np.repeat(rng.choice([-1.0, 1.0], 50), 10)
        y = lfilter([0.2] if same_sample else [0.0, 0.2], [1.0, -0.8], u) + 0.001 * rng.standard_normal(u.size)
        records.append({"t": np.arange(u.size) * 0.01, "r": u, "u": u, "y": y})
    return records


def non_causal_warnings(records) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        Batch.from_records(records)
    return [str(w.message) for w in caught if issubclass(w.category, NonCausalRecordWarning)]


def test_a_log_whose_output_answers_its_input_in_the_same_sample_is_warned_of():
    said = non_causal_warnings(open_loop(same_sample=True))
    assert len(said) == 1 and "answers the input u within the same sample" in said[0]


def test_the_same_plant_logged_causally_is_not_warned_of():
    assert non_causal_warnings(open_loop(same_sample=False)) == []


def test_closed_loop_records_are_not_warned_of_although_the_controller_reads_y_in_the_same_sample():
    records = loop_records(gains=np.array([[0.3, 1.0], [0.9, 1.2], [1.05, 2.0]]), duration=0.5)
    assert non_causal_warnings(records) == []


def test_values_beyond_1e100_are_refused_naming_the_experiment_and_sample():
    records = open_loop(same_sample=False)
    records[1]["y"] = records[1]["y"] * 1e305
    with pytest.raises(ValueError, match=r"experiment 2, sample 1, y = .*: values must be within \+-1e\+100"):
        Batch.from_records(records)


def test_records_shorter_than_the_model_are_refused_before_the_fit():
    records = [{name: values[:5] for name, values in record.items()} for record in open_loop(same_sample=False)]
    data = Batch.from_records(records)
    with pytest.raises(ValueError, match="experiment 1 has 5 samples; a fit of linear.2p0z. .*needs at least 7"):
        fit_structure(data)
    with pytest.raises(ValueError, match=r"n_poles \(--poles\): must be an integer from 1 to 8, got 20"):
        fit_structure(Batch.from_records(open_loop(same_sample=False)), spec=ModelSpec(n_poles=20))


def test_n_jobs_above_the_cores_is_capped_and_warned_of(monkeypatch):
    import agents.twin.workers as workers

    monkeypatch.setattr(workers, "cpu_count", lambda: 2)
    assert check_n_jobs(16) == 2 and check_n_jobs(10**20) == 2 and check_n_jobs(-1) == -1
    with pytest.raises(ValueError, match="from 1 to the 2 usable cores"):
        check_n_jobs(-10**20)
    with pytest.warns(UserWarning, match=r"n_jobs \(--jobs\) = 16 is more than the 2 usable cores; using 2"):
        with worker_processes(16):
            pass
