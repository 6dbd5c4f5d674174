"""The grey-box Jacobian, compressed record by record: exact trust-region steps for small problems (those of
``least_squares`` on the dense Jacobian), LSMR steps for large ones, the same fits.

Data as in ``test_diagnose_fast``: closed-loop step experiments of DCMotor-v0 (2 s, 1001 samples).
"""

from __future__ import annotations

import tracemalloc
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin import least_squares as greybox
from agents.twin import simulation
from agents.twin.jacobian import RecordQR, dense_jacobian
from agents.twin.least_squares import fit_problems, jacobian, make_problem, residual
from agents.twin.linear_fit import linear_fit
from agents.twin.records import Batch
from agents.twin.simulation import simulate_sets
from tests.support import loop_records

GAINS = np.array([[0.3, 1.0], [0.6, 1.5], [0.9, 1.2], [1.05, 2.0], [0.5, 1.9], [0.7, 1.1]])


def _data(n=4) -> Batch:
    return Batch.from_records(loop_records(None, gains=GAINS[:n], step=(245.0, 306.0), noise=0.1, seed=0))


def _random_blocks(rng, n_records=5, n_steps=7):
    shared = rng.normal(size=(3, n_records, n_steps))
    rest, bias = rng.normal(size=(n_records, n_steps)), rng.normal(size=(n_records, n_steps))
    columns = [np.array([0, 2, 4]), np.column_stack([[1, 3, 5, 6, 7], np.arange(5)]),
               np.array([[8, 0], [9, 2], [10, 4]])]  # bias of records 1 and 3 fixed
    return shared, rest, bias, columns


def test_dense_jacobian_places_each_block_in_its_column():
    shared, rest, bias, columns = _random_blocks(np.random.default_rng(0))
    dense = dense_jacobian(shared, [rest, bias], columns)
    assert dense.shape == (35, 11)
    np.testing.assert_array_equal(dense[:, 0], shared[0].ravel())
    np.testing.assert_array_equal(dense[7:14, 3], rest[1])  # record 1's rest level moves only its rows
    assert not dense[:7, 3].any() and not dense[14:, 3].any()
    np.testing.assert_array_equal(dense[28:, 10], bias[4])


def test_dense_jacobian_without_shared_columns():
    _, rest, bias, _ = _random_blocks(np.random.default_rng(2))
    columns = [np.empty(0, dtype=int), np.column_stack([np.arange(5), np.arange(5)]),
               np.array([[5, 0], [6, 2], [7, 4]])]
    dense = dense_jacobian(np.empty((0, 5, 7)), [rest, bias], columns)
    assert dense.shape == (35, 8)
    np.testing.assert_array_equal(dense[7:14, 1], rest[1])
    np.testing.assert_array_equal(dense[14:21, 6], bias[2])


def test_compressed_jacobian_has_the_normal_equations_of_the_dense_one():
    rng = np.random.default_rng(1)
    shared, rest, bias, columns = _random_blocks(rng, n_steps=9)
    dense = dense_jacobian(shared, [rest, bias], columns)
    f = rng.normal(size=(5, 9))
    positions = np.full((5, 5), -1)  # per record: 3 shared columns, its rest level, its bias
    positions[:, :3] = columns[0]
    positions[columns[1][:, 1], 3] = columns[1][:, 0]
    positions[columns[2][:, 1], 4] = columns[2][:, 0]
    blocks = np.stack([*shared, rest, bias])
    compressed = RecordQR(5, 5)
    compressed.add(slice(0, 2), blocks[:, :2], f[:2])  # a few records at a time
    compressed.add(slice(2, 5), blocks[:, 2:], f[2:])
    jac, rhs = compressed.system(positions, 11)
    assert jac.shape == (25, 11)
    np.testing.assert_allclose(jac.T @ jac.toarray(), dense.T @ dense, atol=1e-12)
    np.testing.assert_allclose(jac.T @ rhs, dense.T @ f.ravel(), atol=1e-12)


class _Stopped(Exception):
    """Raised by the iteration of :func:`_capture_steps` once it has seen its first system."""


def _capture_steps(monkeypatch):
    """Replace the trust-region iteration by one that records its step solver and first system, then stops."""
    seen = {}

    def first_system(cost, system, x0, *args, **kwargs):
        seen["system"], seen["tr_solver"] = system(x0), kwargs["tr_solver"]
        raise _Stopped

    monkeypatch.setattr(greybox, "trf", first_system)
    return seen


def test_jacobian_below_the_dense_limit_gets_exact_steps(monkeypatch):
    data = _data(n=2)
    base = linear_fit(data, refine=False)
    problem = make_problem(data, base.spec, base.theta, base.y0, base.bias, np.arange(data.n_records))
    seen = _capture_steps(monkeypatch)
    with pytest.raises(_Stopped):
        fit_problems(data, [problem], max_iter=5)
    assert seen["tr_solver"] == "exact"


def test_exact_steps_on_the_compressed_jacobian_are_least_squares_steps():
    """A small fit takes the steps of least_squares(tr_solver="exact") on the dense Jacobian.

    The same steps in exact arithmetic; in floating point the SVD of the compressed system rounds
    differently, and the fit's condition number (about 1e10: rest levels against the delay) turns
    that into relative differences of about 1e-6 after a few steps (measured: at most 6e-6).
    """
    data = _data(n=2)
    base = linear_fit(data, refine=False)
    theta = base.theta * np.array([1.1, 0.9, 1.2, 1.0])  # away from the minimum: steps that matter
    problem = make_problem(data, base.spec, theta, base.y0, base.bias, np.arange(data.n_records))
    free = np.flatnonzero(problem.free & (problem.lower < problem.upper))
    start = problem.theta.copy()

    def full(x):
        theta = start.copy()
        theta[free] = x
        return theta

    def fun(x):
        return residual(data, problem.rows, simulate_sets(data, [(problem.spec, full(x), problem.rows)])[0]).ravel()

    scale = np.where(problem.scale[free] > 0, problem.scale[free], 1.0)
    lower, upper = problem.lower[free], problem.upper[free]
    for budget, rtol in ((1, 1e-9), (3, 1e-4), (8, 1e-4)):
        ref = least_squares(fun, start[free], jac=lambda x: jacobian(data, problem, full(x)), bounds=(lower, upper),
                            x_scale=scale, method="trf", tr_solver="exact", ftol=1e-7, xtol=1e-12, gtol=1e-12,
                            max_nfev=budget + 1)
        fitted = replace(problem, theta=start.copy())
        fit_problems(data, [fitted], max_iter=budget)
        np.testing.assert_allclose(fitted.theta[free], ref.x, rtol=rtol)
        assert fitted.cost == pytest.approx(2.0 * ref.cost, rel=rtol)
    start_residual = fun(start[free])
    assert 2.0 * ref.cost < 0.01 * float(start_residual @ start_residual)  # the steps went far: the cost fell 100-fold


def test_jacobian_above_the_dense_limit_is_compressed_per_record(monkeypatch):
    data = _data(n=6)
    base = linear_fit(data, refine=False)
    problem = make_problem(data, base.spec, base.theta, base.y0, base.bias, np.arange(data.n_records))
    monkeypatch.setattr(greybox, "DENSE_JACOBIAN_MAX_BYTES", 0)
    seen = _capture_steps(monkeypatch)
    with pytest.raises(_Stopped):
        fit_problems(data, [problem], max_iter=5)
    assert seen["tr_solver"] == "lsmr"
    jac, rhs = seen["system"]
    n_global = int(problem.free[: problem.n_global].sum())
    per_record = n_global + 2  # its rows: the free globals, its rest level and its bias
    assert jac.shape == (per_record * data.n_records, n_global + 2 * data.n_records)
    assert jac.nnz <= per_record**2 * data.n_records  # linear in the records, not in their samples
    assert rhs.shape == (jac.shape[0],)


def test_compressed_jacobian_fit_reaches_the_dense_fit(monkeypatch):
    data = _data(n=6)
    exact = linear_fit(data)
    monkeypatch.setattr(greybox, "DENSE_JACOBIAN_MAX_BYTES", 0)
    monkeypatch.setattr(greybox, "JACOBIAN_PASS_SAMPLES", 3 * data.u.shape[1])  # one record per pass
    compressed = linear_fit(data)
    assert compressed.rmse == pytest.approx(exact.rmse, rel=1e-4)
    np.testing.assert_allclose(compressed.theta[:3], exact.theta[:3], rtol=1e-3)


def test_compressed_fit_holds_a_few_signals_not_a_jacobian(monkeypatch):
    """Peak memory of a large fit: a few arrays of the size of one signal (main's LSMR path: 47 of them)."""
    rng = np.random.default_rng(0)
    gains = np.column_stack([rng.uniform(0.3, 1.0, 24), rng.uniform(1.0, 2.0, 24)])
    data = Batch.from_records(loop_records(None, gains=gains, duration=1.0, noise=0.1, seed=0))
    base = linear_fit(data, refine=False)
    problem = make_problem(data, base.spec, base.theta, base.y0, base.bias, np.arange(data.n_records))
    monkeypatch.setattr(greybox, "DENSE_JACOBIAN_MAX_BYTES", 0)
    monkeypatch.setattr(greybox, "JACOBIAN_PASS_SAMPLES", 7 * 3 * data.u.shape[1])  # 3 records per pass
    tracemalloc.start()
    try:
        fit_problems(data, [problem], max_iter=10)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 12 * data.y.nbytes  # measured 7: the current and the trial output and residual, a simulation
    assert problem.cost < 1.01 * 0.1**2 * data.y.size  # and it fits: RMSE at the sensor noise (0.1)


def test_simulation_in_small_passes_equals_one_pass(monkeypatch):
    data = _data(n=4)
    base = linear_fit(data, refine=False)
    rows = np.arange(data.n_records)
    sets = [(base.spec, np.concatenate([base.theta * (1 + 0.01 * i), base.y0, base.bias]), rows) for i in range(3)]
    whole = simulate_sets(data, sets)
    monkeypatch.setattr(simulation, "SIMULATION_BATCH_SAMPLES", data.u.shape[1])
    for a, b in zip(whole, simulate_sets(data, sets)):
        np.testing.assert_array_equal(a, b)
