"""The session's side of the tuning loop: commit every experiment to the log, and resume from it.

:class:`SessionRecorder` implements :class:`agents.recorder.ExperimentRecorder`
over one session of a :class:`~evaluation.sessions.store.SessionStore`;
:meth:`agents.Tuner.run` drives it:

1. ``ask()``; :meth:`~SessionRecorder.begin` commits an *intent* row (status
   ``running``, the gains, and the twin evaluations made while proposing) -
   before the plant is touched;
2. ``env.step(gains)``;
3. :meth:`~SessionRecorder.finish` commits the record (status ``ok`` or
   ``failed``, cost, metrics, ``t, r, u, y`` as BLOBs, the env's random state)
   and a snapshot of the tuner as it proposed the experiment
   (:mod:`evaluation.sessions.snapshot`) in one transaction;
4. ``tell()``, then :meth:`~SessionRecorder.add_twins` commits the twin
   evaluations made while learning.

Resume (:meth:`~SessionRecorder.resume`, rerunning the same session): the
tuner was set up with the same seed and the env reset with it. The tuner's
snapshot is loaded - its data, models and random generator state as when it
proposed the last finished experiment - and, if that experiment was told,
``tell()`` gets its stored gains, cost and record: the tuner is then exactly
where an uninterrupted run's is, in time independent of the number of stored
experiments. Without a snapshot (a tuner that cannot be pickled, or a snapshot
that cannot be loaded), the stored experiments after the last snapshot (all
of them without one) are replayed in order - for each, ``ask()`` must return
the stored gains (else :class:`ReplayMismatch`: the tuner is not
deterministic) and ``tell()`` gets the stored gains, cost and record, which
replays the tuner's random draws too. The env's ``np_random`` state and
experiment counter are then restored from the last committed row, so its noise
continues as if it had never stopped.

Crash policy (``on_crash``): an intent row still ``running`` on resume means
the process died between committing the intent and committing the result, so
the plant may have run that experiment (on a simulated env this cannot be
told apart from a crash before the step). ``"rerun"`` (default) marks it
``lost-in-crash`` (kept, never replayed) and runs the experiment again;
``"stop"`` raises :class:`agents.TuningStopped` so that a person can check the
rig first, then rerun with ``on_crash="rerun"``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np

from agents.base import TuningStopped
from evaluation.sessions.snapshot import restore_tuner, tuner_snapshot
from evaluation.sessions.store import ExperimentRow, SessionStore

__all__ = ["CRASH_POLICIES", "ReplayMismatch", "SessionRecorder", "env_state", "restore_env_state"]

#: Values of ``on_crash``.
CRASH_POLICIES = ("rerun", "stop")

_log = logging.getLogger(__name__)


class ReplayMismatch(RuntimeError):
    """On resume, the tuner proposed other gains than the stored ones: it is not deterministic."""


class SessionRecorder:
    """The experiment log of one session, as the tuning loop's recorder.

    Parameters
    ----------
    store : SessionStore
        Open store holding the session.
    session_id : int
    on_crash : {"rerun", "stop"}, default "rerun"
        What to do with an intent found on resume (see the module docstring).

    Attributes
    ----------
    n_replayed : int
        Plant experiments the tuner had learned from when :meth:`resume` returned.
    n_asked : int
        Stored experiments whose proposal :meth:`resume` asked the tuner for
        again (0 when it loaded a snapshot of the last one).
    """

    def __init__(self, store: SessionStore, session_id: int, on_crash: str = "rerun") -> None:
        if on_crash not in CRASH_POLICIES:
            raise ValueError(f"on_crash: must be one of {CRASH_POLICIES}, got {on_crash!r}")
        self.store = store
        self.session_id = session_id
        self.on_crash = on_crash
        self.n_replayed = 0
        self.n_asked = 0
        self._env = None
        self._tuner = None
        self._snapshots = True  # False once the tuner turned out not to pickle

    # -- resume --------------------------------------------------------------------------------------
    def resume(self, tuner, env) -> tuple[int, int]:
        """Bring ``tuner`` and ``env`` to the stored experiments; return (told, trailing skips).

        ``env`` and ``tuner`` are also those whose states :meth:`finish` stores.

        Raises
        ------
        agents.TuningStopped
            With ``on_crash="stop"`` when an experiment was cut by a crash.
        ReplayMismatch
            When the tuner proposes other gains than the stored ones.
        """
        store, sid = self.store, self.session_id
        self._env, self._tuner = env, tuner
        rows = store.experiments(sid)
        plant = [r for r in rows if r.source == "plant" and r.status not in ("lost-in-crash", "interrupted")]
        for row in plant:
            if row.status != "running":
                continue
            if self.on_crash == "stop":
                raise TuningStopped(
                    f"experiment {row.experiment} (gains {row.gains}) was started before a crash and its result "
                    "was never stored: the plant may have run it. Check the rig, then rerun with on_crash='rerun' "
                    "(gbo tune --on-crash rerun) to run it again")
            store.abandon_plant(row.id, "lost-in-crash", "intent found on resume; the experiment is run again")
            _log.warning("session %s: experiment %s was cut by a crash; running it again", sid, row.experiment)
        plant = [r for r in plant if r.status != "running"]
        tell_twins = {r.parent_id for r in rows if r.source == "twin" and r.phase == "tell" and r.status == "ok"}
        start = 0
        snapshot = store.snapshot(sid)
        if snapshot is not None:
            row_id, state = snapshot
            index = next((i for i, row in enumerate(plant) if row.id == row_id), None)
            if index is not None and restore_tuner(tuner, state, env):
                self._learn(tuner, plant[index], tell_twins)
                start = index + 1
        span = tuner.space.high - tuner.space.low
        for row in plant[start:]:
            proposal = tuner.ask()
            tuner.drain_twin_log()  # stored with the intent
            self.n_asked += 1
            if not np.all(np.abs(np.asarray(proposal) - np.asarray(row.gains)) <= 1e-9 * span):
                raise ReplayMismatch(
                    f"replaying experiment {row.experiment} (row {row.seq}): {tuner.name} proposed {proposal}, "
                    f"the database holds {row.gains}; the tuner is not deterministic for a fixed seed, so this "
                    "session cannot be resumed (start a new session with another seed or database)")
            self._learn(tuner, row, tell_twins)
        if plant and plant[-1].env_state is not None:
            restore_env_state(env, plant[-1].env_state)
        told = sum(row.told for row in plant)
        skips = next((i for i, row in enumerate(reversed(plant)) if row.told), len(plant))
        self.n_replayed = told
        return told, skips

    def _learn(self, tuner, row: ExperimentRow, tell_twins: set[int]) -> None:
        """Tell ``tuner`` a stored experiment it was told (storing its twin rows if a crash lost them)."""
        if not row.told:
            return
        tuner.tell(row.gains, row.told_cost, row.record() if row.status == "ok" else None)
        twins = tuner.drain_twin_log()
        if twins and row.id not in tell_twins:  # the crash came between tell and its commit
            self.store.add_twins(self.session_id, row.experiment, row.id, "tell", twins)

    # -- one experiment ------------------------------------------------------------------------------
    def begin(self, experiment: int, gains, twins: list[dict]) -> tuple[int, int]:
        """Commit the intent (and the twin rows of ``ask``); the handle is ``(row id, experiment)``."""
        return self.store.begin_plant(self.session_id, experiment, gains, twins), experiment

    def finish(self, handle: tuple[int, int], record: Mapping, *, failed: bool, reason: str | None,
               told_cost: float | None) -> None:
        """Commit the outcome with the env's state and the tuner's snapshot.

        A failed experiment's cost is stored only as ``told_cost``. The tuner
        has proposed this experiment and not yet learned from it: the snapshot
        plus a ``tell`` of this row is the tuner of an uninterrupted run.
        """
        if failed:
            record = {k: v for k, v in record.items() if k != "cost"}
        snapshot = None
        if self._snapshots and self._tuner is not None:
            snapshot = tuner_snapshot(self._tuner, self._env)
            self._snapshots = snapshot is not None
        self.store.finish_plant(handle[0], "failed" if failed else "ok", record, reason=reason,
                                told=told_cost is not None, told_cost=told_cost, env_state=env_state(self._env),
                                snapshot=snapshot)

    def abandon(self, handle: tuple[int, int], reason: str) -> None:
        """Mark the intent ``interrupted`` (Ctrl-C): it is not replayed and is run again."""
        self.store.abandon_plant(handle[0], "interrupted", reason)

    def add_twins(self, handle: tuple[int, int], twins: list[dict]) -> None:
        """Commit the twin rows of ``tell``."""
        row_id, experiment = handle
        self.store.add_twins(self.session_id, experiment, row_id, "tell", twins)


def env_state(env) -> dict[str, Any]:
    """The state of a plant env that a resume must restore: ``np_random``, experiment counter, best cost."""
    plant = env.unwrapped
    state: dict[str, Any] = {"np_random": plant.np_random.bit_generator.state}
    if hasattr(plant, "experiment_index"):
        state["experiment_index"] = int(plant.experiment_index)
    if hasattr(plant, "best_cost"):
        state["best_cost"] = float(plant.best_cost)
    return state


def restore_env_state(env, state: dict[str, Any]) -> None:
    """Inverse of :func:`env_state` on a freshly reset env."""
    plant = env.unwrapped
    generator = plant.np_random.bit_generator
    if state["np_random"].get("bit_generator") != type(generator).__name__:
        raise ReplayMismatch(f"env random state: stored {state['np_random'].get('bit_generator')}, "
                             f"the env uses {type(generator).__name__}")
    generator.state = state["np_random"]
    if "experiment_index" in state:
        plant.experiment_index = int(state["experiment_index"])
    if "best_cost" in state:
        plant.best_cost = float(state["best_cost"])
