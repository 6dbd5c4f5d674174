"""The protocol of an experiment log that :meth:`agents.Tuner.run` commits every experiment to.

``Tuner.run(env, budget, recorder=None)`` is the one tuning loop. Without a
recorder it keeps its rows in memory only; with one it is a crash-safe
session: :class:`evaluation.sessions.SessionRecorder` implements this protocol
over an SQLite experiment log (``agents`` never imports ``evaluation``; the
loop only calls the five methods below, in this order per experiment:
``begin`` before the plant is touched, then ``finish`` or ``abandon``, then
``add_twins`` after a told experiment).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol

__all__ = ["ExperimentRecorder", "InMemory"]


class ExperimentRecorder(Protocol):
    """Where the tuning loop commits each plant experiment before it proposes the next one."""

    def resume(self, tuner, env) -> tuple[int, int]:
        """Bring a freshly set-up ``tuner`` and a freshly reset ``env`` up to the committed experiments.

        Called once, after ``tuner.setup(...)`` and ``env.reset(seed=seed)``.
        The recorder brings the tuner to its state after the committed
        experiments (the session loads a snapshot of the tuner, or replays the
        experiments through its public ``ask`` / ``tell`` / ``drain_twin_log``)
        and restores the env's random state, so the loop continues as if it
        had never stopped.

        Returns
        -------
        (int, int)
            Plant experiments the tuner has learned from, and the failed
            experiments at the end of the log that it was not told about
            (consecutive skips).
        """

    def begin(self, experiment: int, gains: Sequence[float], twins: list[dict]) -> Any:
        """Commit the intent to run plant experiment ``experiment`` (1-based) at ``gains``.

        ``twins`` are the twin evaluations made while proposing the gains.
        Returns a handle passed back to :meth:`finish`, :meth:`abandon` and :meth:`add_twins`.
        """

    def finish(self, handle: Any, record: Mapping, *, failed: bool, reason: str | None,
               told_cost: float | None) -> None:
        """Commit the outcome of the experiment begun as ``handle``.

        Parameters
        ----------
        record : mapping
            The env's ``info`` of the experiment (``{"gains": ...}`` alone when ``env.step`` raised).
        failed : bool
            Whether the experiment failed (see the failure policy of :meth:`agents.Tuner.run`).
        reason : str or None
            Why it failed.
        told_cost : float or None
            The cost the tuner is told (dimensionless), or ``None`` if it is not told.
        """

    def abandon(self, handle: Any, reason: str) -> None:
        """The experiment begun as ``handle`` was cut by Ctrl-C: it is never replayed and is run again."""

    def add_twins(self, handle: Any, twins: list[dict]) -> None:
        """Commit the twin evaluations the tuner made while learning from the experiment ``handle``."""


class InMemory:
    """The recorder of a plain run: nothing to resume, nothing to commit (the result keeps the rows)."""

    def resume(self, tuner, env) -> tuple[int, int]:
        return 0, 0

    def begin(self, experiment: int, gains: Sequence[float], twins: list[dict]) -> None:
        return None

    def finish(self, handle: Any, record: Mapping, *, failed: bool, reason: str | None,
               told_cost: float | None) -> None:
        pass

    def abandon(self, handle: Any, reason: str) -> None:
        pass

    def add_twins(self, handle: Any, twins: list[dict]) -> None:
        pass
