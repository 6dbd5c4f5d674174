"""A tuning session that survives crashes: :meth:`agents.Tuner.run` with the session's experiment log.

The loop and its failure policy are :meth:`agents.Tuner.run`'s; the session
adds a :class:`~evaluation.sessions.recorder.SessionRecorder` that commits
every experiment to the SQLite log of :mod:`evaluation.sessions.store` before
the next one is proposed, and resumes a session from the log (see
:mod:`evaluation.sessions.recorder` for the commits, the resume and the crash
policy).
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import agents
from agents.base import TuningInterrupted, TuningStopped, checked_budget, checked_seed
from agents.run_display import env_id as env_name
from agents.space import GainSpace
from evaluation.sessions.export import load_result
from evaluation.sessions.recorder import CRASH_POLICIES, SessionRecorder
from evaluation.sessions.store import SessionStore, session_key

__all__ = ["TuningSession", "session_spec"]


def session_spec(env_id: str, env_kwargs: dict, tuner: str, tuner_params: dict, budget: int, seed: int | None,
                 env=None) -> dict[str, Any]:
    """The specification of a session (its key, :func:`~evaluation.sessions.store.session_key`, leaves out the budget).

    The env's cost weights and normalisers are part of it (rounded to 12
    digits) when the env has them, so that a resume never mixes cost scales.
    """
    spec: dict[str, Any] = {"env": str(env_id), "env_kwargs": dict(env_kwargs), "tuner": str(tuner),
                            "tuner_params": dict(tuner_params), "budget": int(budget),
                            "seed": None if seed is None else int(seed)}
    plant = getattr(env, "unwrapped", None)
    for name in ("weights", "normalizers"):
        values = getattr(plant, name, None)
        if values is not None:
            spec[name] = [float(f"{float(v):.12g}") for v in np.ravel(values)]
    return spec


class TuningSession:
    """Run, or resume, one tuning session against an experiment-log database.

    Parameters
    ----------
    db : str or Path
        SQLite file (created if missing; several sessions may share it).
    env : str or gymnasium.Env
        Env id (made with ``gym.make(env, **env_kwargs)``) or an env instance
        (e.g. an :class:`~gbo_envs.envs.external.ExternalPlantEnv`; then
        ``env_id`` and ``env_kwargs`` name it in the session key).
    tuner : str or agents.Tuner
        Registry name (made with ``agents.make(tuner, **tuner_kwargs)``) or a
        fresh tuner instance.
    budget : int
        Plant experiments the tuner learns from (skipped failures do not count).
        Rerunning with another budget extends the session, or shortens it
        (nothing is run once it holds ``budget`` experiments; none is deleted).
    seed : int or None, default 0
        Seeds the env and the tuner. ``None`` cannot be resumed exactly.
    env_kwargs, tuner_kwargs : dict, optional
    env_id : str, optional
        Name of an env instance in the key (default: its spec id or class name).
    on_crash : {"rerun", "stop"}, default "rerun"
        What to do with an experiment whose intent was committed but whose
        result was not (see :mod:`evaluation.sessions.recorder`).
    max_consecutive_skips : int, default 5
        Stop after this many failed experiments in a row that the tuner was not
        told about (failure policy ``skip``, see :meth:`agents.Tuner.run`).
    force : bool, default False
        Take the session over even if the database names another owner that
        may be alive (e.g. a process on another host that crashed). Never run
        one session from two processes at once.
    """

    def __init__(self, db: str | Path, env, tuner, budget: int, seed: int | None = 0, env_kwargs: dict | None = None,
                 tuner_kwargs: dict | None = None, env_id: str | None = None, on_crash: str = "rerun",
                 max_consecutive_skips: int = 5, force: bool = False) -> None:
        budget, seed = checked_budget(budget), checked_seed(seed)  # before the database is opened
        if on_crash not in CRASH_POLICIES:
            raise ValueError(f"on_crash: must be one of {CRASH_POLICIES}, got {on_crash!r}")
        self.env_kwargs = dict(env_kwargs or {})
        self.tuner_kwargs = dict(tuner_kwargs or {})
        if isinstance(env, str):
            self.env_id, self.env = env, gym.make(env, **self.env_kwargs)
        else:
            self.env = env
            self.env_id = env_id or env_name(env)
        if isinstance(tuner, str):
            self.tuner_name, self.tuner = tuner, agents.make(tuner, **self.tuner_kwargs)
            if "budget" not in self.tuner_kwargs and "budget" in inspect.signature(type(self.tuner)).parameters:
                # tuners that size themselves to the budget (grid) get the session's, as Tuner.run gives it
                self.tuner = agents.make(tuner, **self.tuner_kwargs, budget=int(budget))
        else:
            self.tuner_name, self.tuner = tuner.name, tuner
        self.budget = int(budget)
        self.seed = seed
        self.on_crash = on_crash
        self.max_consecutive_skips = int(max_consecutive_skips)
        self.force = bool(force)
        self.space = GainSpace.from_env(self.env)
        params = {**self.tuner_kwargs, **self.tuner.get_params()}
        self.spec = session_spec(self.env_id, self.env_kwargs, self.tuner_name, params, self.budget, seed, self.env)
        self.key = session_key(self.spec)
        self.db = Path(db)
        self.session_id: int | None = None
        #: Plant experiments the tuner had learned from when the last :meth:`run` resumed the session.
        self.n_replayed = 0
        #: Stored experiments whose proposals the last :meth:`run` asked for again (0 with a tuner snapshot).
        self.n_asked = 0

    def run(self, progress: bool | None = False):
        """Run the session to its budget, resuming from the database.

        Parameters
        ----------
        progress : bool or None, default False
            Show a tqdm progress bar (stderr); ``None``: only when stderr is a terminal (``gbo tune``).

        Returns
        -------
        agents.TuningResult
            Every stored plant and twin row of the session (see
            :func:`evaluation.sessions.export.load_result`).

        Raises
        ------
        agents.TuningStopped, ReplayMismatch, SessionBusy
            See :meth:`agents.Tuner.run` and :mod:`evaluation.sessions.recorder`;
            the database stays consistent in each case.
        agents.TuningInterrupted
            On Ctrl-C; finished experiments are kept, rerun to resume.

        ``.result`` of a :class:`~agents.TuningStopped` or
        :class:`~agents.TuningInterrupted` holds every stored experiment of the session.
        """
        with SessionStore(self.db) as store:
            info = store.open_session(self.key, self.spec, self.space.names, force=self.force)
            self.session_id = sid = info.id
            recorder = SessionRecorder(store, sid, on_crash=self.on_crash)
            status, message = "failed", None
            try:
                tuned = self.tuner.run(self.env, self.budget, seed=self.seed, progress=progress, recorder=recorder,
                                       max_consecutive_skips=self.max_consecutive_skips)
                status = "done"
            except KeyboardInterrupt as exc:
                status, message = "interrupted", "Ctrl-C; rerun the same command to resume"
                if isinstance(exc, TuningInterrupted):
                    exc.result = load_result(store, sid)
                raise
            except TuningStopped as exc:
                status, message = "stopped", str(exc)
                exc.result = load_result(store, sid)
                raise
            except BaseException as exc:
                message = f"{type(exc).__name__}: {exc}"
                raise
            finally:
                self.n_replayed, self.n_asked = recorder.n_replayed, recorder.n_asked
                store.release_session(sid, status, message)
            result = load_result(store, sid)
            # the tuner's own figures of this run (twin activations, twin evaluations, twin changes ...),
            # which the stored rows do not hold
            result.info = {**tuned.info, **result.info}
            return result
