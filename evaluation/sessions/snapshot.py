"""A tuner's whole state as bytes, so that a resume loads it instead of replaying the history.

:func:`tuner_snapshot` pickles a tuner - its data, fitted models and random
generator state, so the proposals after a resume equal those of an
uninterrupted run - except the plant env, which is stored as a reference and
bound to the resuming process's env by :func:`restore_tuner`. A tuner that
cannot be pickled (e.g. one holding local functions, as the RL tuner does)
gets no snapshot; its sessions resume by replay
(:mod:`evaluation.sessions.recorder`).

A snapshot is a pickle: loading one runs code named in it. Only the session
databases this code wrote are read (:mod:`evaluation.sessions.identity`); do not
resume from a database file of unknown origin.
"""

from __future__ import annotations

import io
import logging
import pickle

__all__ = ["restore_tuner", "tuner_snapshot"]

_log = logging.getLogger(__name__)


def _env_layers(env) -> list:
    """``env`` and every env it wraps, outermost first (``env.env`` down to ``env.unwrapped``)."""
    layers: list = []
    while env is not None and all(env is not seen for seen in layers):
        layers.append(env)
        env = getattr(env, "env", None)
    return layers


class _Pickler(pickle.Pickler):
    """Pickles a tuner with each layer of its env replaced by the layer's depth."""

    def __init__(self, handle, env) -> None:
        super().__init__(handle, protocol=pickle.HIGHEST_PROTOCOL)
        self._depth = {id(layer): depth for depth, layer in enumerate(_env_layers(env))}

    def persistent_id(self, obj):
        depth = self._depth.get(id(obj))
        return None if depth is None else ("env", depth)


class _Unpickler(pickle.Unpickler):
    """Binds the env references of :class:`_Pickler` to the layers of the resuming process's env."""

    def __init__(self, handle, env) -> None:
        super().__init__(handle)
        self._layers = _env_layers(env)

    def persistent_load(self, pid):
        kind, depth = pid
        if kind != "env" or depth >= len(self._layers):
            raise pickle.UnpicklingError(f"snapshot refers to env layer {depth}; this env has {len(self._layers)}")
        return self._layers[depth]


def tuner_snapshot(tuner, env) -> bytes | None:
    """The tuner's state as bytes (the env by reference), or None if it cannot be pickled."""
    handle = io.BytesIO()
    try:
        _Pickler(handle, env).dump(tuner)
    except Exception as exc:  # noqa: BLE001 - whatever stops pickling (a local function, a lock): no snapshot
        _log.debug("%s: no snapshot (%s); a resume replays the session", type(tuner).__name__, exc)
        return None
    return handle.getvalue()


def restore_tuner(tuner, snapshot: bytes, env) -> bool:
    """Put the state of ``snapshot`` into ``tuner`` (same class, bound to ``env``); False if it cannot be loaded.

    A snapshot written by other code (a changed tuner class, a missing module)
    is not loaded, and the caller replays the session instead.
    """
    try:
        state = _Unpickler(io.BytesIO(snapshot), env).load()
    except Exception as exc:  # noqa: BLE001 - any failure to load means: replay instead
        _log.warning("tuner snapshot not loaded (%s: %s); replaying the session instead", type(exc).__name__, exc)
        return False
    if type(state) is not type(tuner):
        _log.warning("tuner snapshot holds a %s, the session runs a %s; replaying the session instead",
                     type(state).__name__, type(tuner).__name__)
        return False
    missing = sorted(set(tuner.__dict__) - set(state.__dict__))
    if missing:  # written by an older version of the class: its state lacks what this one keeps
        _log.warning("tuner snapshot lacks %s (written by other code); replaying the session instead",
                     ", ".join(missing))
        return False
    tuner.__dict__.clear()
    tuner.__dict__.update(state.__dict__)
    return True
