"""Fixtures shared by the whole suite (constants and plain helpers: :mod:`tests.support`)."""

from __future__ import annotations

import os
import sys

import gymnasium as gym
import pytest

import gbo_envs  # noqa: F401  (registers the envs)


@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(collector):
    """The test modules' assertion-rewritten bytecode cached (``__pycache__/*-pytest-*.pyc``), also where
    PYTHONDONTWRITEBYTECODE is set (Docker images, CI; ``make setup`` writes the project's bytecode for the
    same reason).

    pytest writes its rewrite of a test module only when ``sys.dont_write_bytecode`` is false, and reads a
    cached one either way: without it every run rewrote the suite's asserts in each xdist worker, 4-5 s of
    the 12 s each worker collects. Only the import of a test module (its collection) writes bytecode.
    """
    if not isinstance(collector, pytest.Module) or not sys.dont_write_bytecode:
        return (yield)
    sys.dont_write_bytecode = False
    try:
        return (yield)
    finally:
        sys.dont_write_bytecode = True


@pytest.fixture(scope="session", autouse=True)
def _threads_share_the_cores_between_the_workers():
    """Under pytest-xdist, torch's and the BLAS's threads limited to the worker's share of the cores.

    torch and OpenBLAS each start one thread per core in every process, and their idle threads spin: with
    ``-n 2`` on two cores, two workers running BoTorch or scikit-learn's GP at the same time had four
    spinning threads of each on two cores. Two such processes side by side took 5-8 times as long per
    BoTorch run (``test_same_seed_reproduces_the_run[botorch]``: 19 s instead of 2.4 s) and 3 times as
    long for skopt and bayes-opt. The study workers run single-threaded for the same reason
    (``evaluation.study_runner``, ``agents.thread_limits``). The processes that a test starts get the
    same limit through the environment (``gbo tune`` of the README: 26.9 s -> 23.2 s with two side by
    side). ``test_shared_helpers`` sets the BLAS threads it checks ``single_thread`` against itself.
    (The collection of the whole suite imports torch.)
    """
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers <= 1:
        yield
        return
    share = max(1, (os.cpu_count() or 1) // workers)
    try:
        import torch
    except ImportError:  # the suite without the extras that bring torch
        torch = None
    if torch is not None:
        torch.set_num_threads(share)
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=share, user_api="blas"), pytest.MonkeyPatch.context() as patch:
        # and the processes a test starts (the README's commands, the CLI, the kill tests), unless set
        for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            patch.setenv(name, os.environ.get(name, str(share)))
        yield


@pytest.fixture(scope="module")
def dc_motor():
    """The noise-free DCMotor-v0 plant env (unwrapped), shared by the tests of one module."""
    return gym.make("gbo_envs/DCMotor-v0", noise=False).unwrapped


@pytest.fixture
def tuner_registry(monkeypatch):
    """The tuner registry, restored after the test: tuners a test registers do not leak into other tests."""
    from agents import registry

    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    return registry


@pytest.fixture
def study_tuners(tuner_registry, monkeypatch, request):
    """``evaluation.study_tuners`` imported afresh into a copy of the registry, and forgotten after the test.

    The module registers its tuners when it is imported. Left in ``sys.modules`` while the registry is
    restored, a later test in the same process would find it imported and its tuners unknown.
    """
    import sys

    monkeypatch.delitem(sys.modules, "evaluation.study_tuners", raising=False)
    request.addfinalizer(lambda: sys.modules.pop("evaluation.study_tuners", None))
    return tuner_registry
