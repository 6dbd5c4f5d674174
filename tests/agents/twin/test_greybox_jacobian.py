"""The grey-box Jacobian kept as its blocks: the same matrix, memory linear in the records, the same fits.

Data as in ``test_diagnose_fast``: closed-loop step experiments of DCMotor-v0 (2 s, 1001 samples).
"""

from __future__ import annotations

import numpy as np
import pytest

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin import greybox
from agents.twin.fitting import linear_fit, make_problem
from agents.twin.greybox import GreyData, fit_problems, simulate_sets
from agents.twin.jacobian import RecordJacobian
from tests.support import loop_records

GAINS = np.array([[0.3, 1.0], [0.6, 1.5], [0.9, 1.2], [1.05, 2.0], [0.5, 1.9], [0.7, 1.1]])


def _data(n=4) -> GreyData:
    return GreyData.from_records(loop_records(None, gains=GAINS[:n], step=(245.0, 306.0), noise=0.1, seed=0))


def _random_jacobian(rng, n_records=5, n_steps=7):
    shared = rng.normal(size=(3, n_records, n_steps))
    rest, bias = rng.normal(size=(n_records, n_steps)), rng.normal(size=(n_records, n_steps))
    columns = [np.array([0, 2, 4]), np.column_stack([[1, 3, 5, 6, 7], np.arange(5)]),
               np.array([[8, 0], [9, 2], [10, 4]])]  # bias of records 1 and 3 fixed
    return RecordJacobian(shared, [rest, bias], columns), shared, rest, bias


def test_record_jacobian_products_are_those_of_its_dense_matrix():
    rng = np.random.default_rng(0)
    jac, shared, rest, bias = _random_jacobian(rng)
    dense = jac.toarray()
    assert dense.shape == (35, 11)
    np.testing.assert_array_equal(dense[:, 0], shared[0].ravel())
    np.testing.assert_array_equal(dense[7:14, 3], rest[1])  # record 1's rest level moves only its rows
    assert not dense[:7, 3].any() and not dense[14:, 3].any()
    np.testing.assert_array_equal(dense[28:, 10], bias[4])
    v, w = rng.normal(size=11), rng.normal(size=35)
    np.testing.assert_allclose(jac.matvec(v), dense @ v, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(jac.rmatvec(w), dense.T @ w, rtol=1e-12, atol=1e-12)


def _capture_jacobian(monkeypatch):
    """Replace least_squares by one that records the Jacobian at the start, then stops."""
    seen = {}

    def first_jacobian(fun, x0, jac, **kwargs):
        fun(x0)
        seen["jac"], seen["tr_solver"] = jac(x0), kwargs["tr_solver"]
        raise StopIteration

    monkeypatch.setattr(greybox, "least_squares", first_jacobian)
    return seen


def test_jacobian_above_the_dense_limit_is_kept_as_blocks(monkeypatch):
    data = _data(n=6)
    base = linear_fit(data, refine=False)
    problem = make_problem(data, base.spec, base.theta, base.y0, base.bias, np.arange(data.n_records))
    monkeypatch.setattr(greybox, "DENSE_JACOBIAN_BYTES", 0)
    seen = _capture_jacobian(monkeypatch)
    with pytest.raises(StopIteration):
        fit_problems(data, [problem], max_iter=5)
    jac = seen["jac"]
    assert isinstance(jac, RecordJacobian) and seen["tr_solver"] == "lsmr"
    n_samples = data.u.size
    n_global = int(problem.free[: problem.n_global].sum())
    assert jac.shape == (n_samples, n_global + 2 * data.n_records)
    stored = jac.shared.nbytes + sum(block.nbytes for block in jac.per_record)
    assert stored == 8 * n_samples * (n_global + 2)  # linear in the data, not n_samples * n_records


def test_jacobian_below_the_dense_limit_is_dense(monkeypatch):
    data = _data(n=2)
    base = linear_fit(data, refine=False)
    problem = make_problem(data, base.spec, base.theta, base.y0, base.bias, np.arange(data.n_records))
    seen = _capture_jacobian(monkeypatch)
    with pytest.raises(StopIteration):
        fit_problems(data, [problem], max_iter=5)
    assert isinstance(seen["jac"], np.ndarray) and seen["tr_solver"] == "exact"


def test_block_jacobian_fit_reaches_the_dense_fit(monkeypatch):
    data = _data(n=6)
    exact = linear_fit(data)
    monkeypatch.setattr(greybox, "DENSE_JACOBIAN_BYTES", 0)
    monkeypatch.setattr(greybox, "SIMULATION_BATCH_SAMPLES", data.u.shape[1])  # one record per pass
    blocks = linear_fit(data)
    assert blocks.rmse == pytest.approx(exact.rmse, rel=1e-3)
    np.testing.assert_allclose(blocks.theta[:3], exact.theta[:3], rtol=1e-2)


def test_simulation_in_small_passes_equals_one_pass(monkeypatch):
    data = _data(n=4)
    base = linear_fit(data, refine=False)
    rows = np.arange(data.n_records)
    sets = [(base.spec, np.concatenate([base.theta * (1 + 0.01 * i), base.y0, base.bias]), rows) for i in range(3)]
    whole = simulate_sets(data, sets)
    monkeypatch.setattr(greybox, "SIMULATION_BATCH_SAMPLES", data.u.shape[1])
    for a, b in zip(whole, simulate_sets(data, sets)):
        np.testing.assert_array_equal(a, b)
