"""Fixtures shared by the whole suite (constants and plain helpers: :mod:`tests.support`)."""

from __future__ import annotations

import gymnasium as gym
import pytest

import gbo_envs  # noqa: F401  (registers the envs)


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
    """``benchmarks.study_tuners`` imported afresh into a copy of the registry, and forgotten after the test.

    The module registers its tuners when it is imported. Left in ``sys.modules`` while the registry is
    restored, a later test in the same process would find it imported and its tuners unknown.
    """
    import sys

    monkeypatch.delitem(sys.modules, "benchmarks.study_tuners", raising=False)
    request.addfinalizer(lambda: sys.modules.pop("benchmarks.study_tuners", None))
    return tuner_registry
