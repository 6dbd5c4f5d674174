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


def pytest_collection_modifyitems(items):
    """Modules with a ``slow`` test first, each module's tests together and in their order.

    pytest-xdist hands the tests out in this order, so the workers end on tests of milliseconds rather
    than one finishing a test of tens of seconds (the README's ``gbo bench suite``, collected last) while
    the other waits: the longest first, as a scheduler does.
    """
    slow = {item.module for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: getattr(item, "module", None) not in slow)
