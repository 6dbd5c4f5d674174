"""Short names for tuners: ``agents.make("bo")`` as ``gym.make`` does for envs."""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["register", "make", "registered_names"]

_REGISTRY: dict[str, str | type] = {}


def register(name: str, entry_point: str | type) -> None:
    """Register a tuner under a short name.

    Parameters
    ----------
    name : str
        Registry name, e.g. ``"my-tuner"``.
    entry_point : str or type
        The tuner class, or ``"module:Class"`` imported on first use (so that
        optional dependencies load only when needed).
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"name: expected a non-empty string, got {name!r}")
    _REGISTRY[name] = entry_point


def registered_names() -> list[str]:
    """All registered tuner names, sorted."""
    return sorted(_REGISTRY)


def make(name: str, **kwargs: Any):
    """A new tuner by registry name, with keyword arguments passed to its constructor.

    Raises
    ------
    ValueError
        For an unknown name (the message lists the known ones).
    """
    if name not in _REGISTRY:
        raise ValueError(f"name: unknown tuner {name!r}; registered tuners: {', '.join(registered_names())}")
    entry = _REGISTRY[name]
    if isinstance(entry, str):
        module, _, attr = entry.partition(":")
        entry = getattr(importlib.import_module(module), attr)
    return entry(**kwargs)
