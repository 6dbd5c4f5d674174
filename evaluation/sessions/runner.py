"""A tuning session that survives crashes: every experiment is committed before the next is proposed.

The loop is :meth:`agents.Tuner.run`'s, with the experiment log of
:mod:`evaluation.sessions.store` around each step:

1. ``ask()``; commit an *intent* row (status ``running``, the gains, and the
   twin evaluations made while proposing) - before the plant is touched;
2. ``env.step(gains)``;
3. commit the record (status ``ok`` or ``failed``, cost, metrics, ``t, r, u, y``
   as BLOBs, the env's random state) in one transaction;
4. ``tell()``, then commit the twin evaluations made while learning.

Resume (rerunning the same session): the tuner is rebuilt with the same seed
and ``setup``, and the stored experiments are replayed in order - for each,
``ask()`` must return the stored gains (else :class:`ReplayMismatch`: the
tuner is not deterministic) and ``tell()`` gets the stored gains, cost and
record. This replays the tuner's random draws too, so later proposals equal
those of an uninterrupted run. The env is reset with the seed and its
``np_random`` state and experiment counter are restored from the last
committed row, so its noise continues as if it had never stopped.

Crash policy (``on_crash``): an intent row still ``running`` on resume means
the process died between committing the intent and committing the result, so
the plant may have run that experiment (on a simulated env this cannot be
told apart from a crash before the step). ``"rerun"`` (default) marks it
``lost-in-crash`` (kept, never replayed) and runs the experiment again;
``"stop"`` raises :class:`SessionStopped` so that a person can check the rig
first, then rerun with ``on_crash="rerun"``.
"""

from __future__ import annotations

import hashlib
import inspect
import logging
from pathlib import Path
from typing import Any

import numpy as np

from agents.jsonable import to_json
from agents.space import GainSpace
from agents.utils import env_id as env_name
from agents.utils import progress_bar
from evaluation.sessions.store import SessionStore
from gbo_envs.envs.external import ExperimentFailed

__all__ = ["CRASH_POLICIES", "ReplayMismatch", "SessionStopped", "TuningSession", "env_state", "restore_env_state",
           "session_spec"]

#: Values of ``on_crash``.
CRASH_POLICIES = ("rerun", "stop")

_log = logging.getLogger(__name__)


class SessionStopped(RuntimeError):
    """The session stopped before its budget (failure policy ``stop``, too many skips, or an open intent)."""


class ReplayMismatch(RuntimeError):
    """On resume, the tuner proposed other gains than the stored ones: it is not deterministic."""


def session_spec(env_id: str, env_kwargs: dict, tuner: str, tuner_params: dict, budget: int, seed: int | None,
                 env=None) -> dict[str, Any]:
    """The specification that identifies a session (its key is the SHA-256 of its JSON).

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
    seed : int or None, default 0
        Seeds the env and the tuner. ``None`` cannot be resumed exactly.
    env_kwargs, tuner_kwargs : dict, optional
    env_id : str, optional
        Name of an env instance in the key (default: its spec id or class name).
    on_crash : {"rerun", "stop"}, default "rerun"
        What to do with an experiment whose intent was committed but whose
        result was not (see the module docstring).
    max_consecutive_skips : int, default 5
        Stop after this many failed experiments in a row that the tuner was not
        told about (failure policy ``skip``, or an env error).
    force : bool, default False
        Take the session over even if the database names another owner that
        may be alive (e.g. a process on another host that crashed). Never run
        one session from two processes at once.
    """

    def __init__(self, db: str | Path, env, tuner, budget: int, seed: int | None = 0, env_kwargs: dict | None = None,
                 tuner_kwargs: dict | None = None, env_id: str | None = None, on_crash: str = "rerun",
                 max_consecutive_skips: int = 5, force: bool = False) -> None:
        import gymnasium as gym

        import agents

        if int(budget) < 1:
            raise ValueError(f"budget: must be an integer >= 1, got {budget}")
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
        self.key = hashlib.sha256(to_json(self.spec).encode()).hexdigest()
        self.db = Path(db)
        self.session_id: int | None = None
        #: Plant experiments replayed from the database at the start of the last :meth:`run`.
        self.n_replayed = 0

    def run(self, progress: bool = False):
        """Run the session to its budget, resuming from the database.

        Parameters
        ----------
        progress : bool, default False
            Show a tqdm progress bar (stderr).

        Returns
        -------
        agents.TuningResult
            Every stored plant and twin row of the session (see
            :func:`evaluation.sessions.export.load_result`).

        Raises
        ------
        ReplayMismatch, SessionStopped, SessionBusy
            See the module docstring; the database stays consistent in each case.
        KeyboardInterrupt
            On Ctrl-C; finished experiments are kept, rerun to resume.
        """
        from evaluation.sessions.export import load_result

        with SessionStore(self.db) as store:
            info = store.open_session(self.key, self.spec, self.space.names, force=self.force)
            self.session_id = sid = info.id
            status, message = "failed", None
            try:
                told, skips = self._replay(store, sid)
                self._loop(store, sid, told, skips, progress)
                status = "done"
            except KeyboardInterrupt:
                status, message = "interrupted", "Ctrl-C; rerun the same command to resume"
                raise
            except SessionStopped as exc:
                status, message = "stopped", str(exc)
                raise
            except BaseException as exc:
                message = f"{type(exc).__name__}: {exc}"
                raise
            finally:
                store.release_session(sid, status, message)
            return load_result(store, sid)

    # -- resume --------------------------------------------------------------------------------------
    def _replay(self, store: SessionStore, sid: int) -> tuple[int, int]:
        """Rebuild tuner and env state from the stored rows; return (experiments told, trailing skips)."""
        rows = store.experiments(sid)
        plant = [r for r in rows if r.source == "plant" and r.status not in ("lost-in-crash", "interrupted")]
        for row in plant:
            if row.status != "running":
                continue
            if self.on_crash == "stop":
                raise SessionStopped(
                    f"experiment {row.experiment} (gains {row.gains}) was started before a crash and its result "
                    "was never stored: the plant may have run it. Check the rig, then rerun with on_crash='rerun' "
                    "(gbo tune --on-crash rerun) to run it again")
            store.abandon_plant(row.id, "lost-in-crash", "intent found on resume; the experiment is run again")
            _log.warning("session %s: experiment %s was cut by a crash; running it again", sid, row.experiment)
        plant = [r for r in plant if r.status != "running"]
        tell_twins = {r.parent_id for r in rows if r.source == "twin" and r.phase == "tell"
                      and r.status == "ok"}
        self.tuner.setup(self.space, seed=self.seed, env=self.env)
        self.env.reset(seed=self.seed)
        told = skips = 0
        for row in plant:
            proposal = self.tuner.ask()
            self.tuner._drain_twin_log()  # stored with the intent
            span = self.space.high - self.space.low
            if not np.all(np.abs(np.asarray(proposal) - np.asarray(row.gains)) <= 1e-9 * span):
                raise ReplayMismatch(
                    f"replaying experiment {row.experiment} (row {row.seq}): {self.tuner_name} proposed {proposal}, "
                    f"the database holds {row.gains}; the tuner is not deterministic for a fixed seed, so this "
                    "session cannot be resumed (start a new session with another seed or database)")
            if row.told:
                self.tuner.tell(row.gains, row.told_cost, row.record() if row.status == "ok" else None)
                twins = self.tuner._drain_twin_log()
                if twins and row.id not in tell_twins:  # the crash came between tell and its commit
                    store.add_twins(sid, row.experiment, row.id, "tell", twins)
                told, skips = told + 1, 0
            else:
                skips += 1
        if plant and plant[-1].env_state is not None:
            restore_env_state(self.env, plant[-1].env_state)
        self.n_replayed = told
        return told, skips

    # -- the loop ------------------------------------------------------------------------------------
    def _loop(self, store: SessionStore, sid: int, told: int, skips: int, progress: bool) -> None:
        bar = progress_bar(self.budget, f"{self.tuner_name} on {self.env_id}", progress, initial=told)
        try:
            while told < self.budget:
                if skips >= self.max_consecutive_skips:
                    raise SessionStopped(f"{skips} failed experiments in a row; fix the plant, then rerun to resume")
                gains = self.tuner.ask()
                experiment = told + 1
                row_id = store.begin_plant(sid, experiment, gains, self.tuner._drain_twin_log())
                failure: ExperimentFailed | None = None
                try:
                    _, _, _, _, info = self.env.step(np.asarray(gains, dtype=np.float64))
                except ExperimentFailed as exc:
                    failure, info = exc, dict(exc.record)
                except KeyboardInterrupt:
                    store.abandon_plant(row_id, "interrupted", "Ctrl-C during the experiment; it is run again")
                    raise
                except Exception as exc:
                    store.finish_plant(row_id, "failed", {"gains": gains}, reason=f"{type(exc).__name__}: {exc}",
                                       told=False, told_cost=None, env_state=env_state(self.env))
                    raise
                state = env_state(self.env)
                if failure is None and not info.get("failed", False):
                    store.finish_plant(row_id, "ok", info, told=True, told_cost=float(info["cost"]), env_state=state)
                    self.tuner.tell(gains, float(info["cost"]), info)
                elif failure is None:  # penalised failure: the tuner learns the penalty cost
                    penalty = float(info["cost"])
                    record = {k: v for k, v in info.items() if k != "cost"}
                    store.finish_plant(row_id, "failed", record, reason=str(info.get("failure_reason")), told=True,
                                       told_cost=penalty, env_state=state)
                    self.tuner.tell(gains, penalty, None)
                else:
                    store.finish_plant(row_id, "failed", info, reason=failure.reason, told=False, told_cost=None,
                                       env_state=state)
                    if failure.policy == "stop":
                        raise SessionStopped(f"experiment {experiment} failed ({failure.reason}); "
                                             "the failure policy is 'stop'. Rerun to resume.") from failure
                    skips += 1
                    _log.warning("session %s: experiment %s failed and is skipped: %s", sid, experiment,
                                 failure.reason)
                    continue
                store.add_twins(sid, experiment, row_id, "tell", self.tuner._drain_twin_log())
                told, skips = told + 1, 0
                bar.update(1)
        finally:
            bar.close()




def env_state(env) -> dict[str, Any]:
    """The state of a plant env that a resume must restore: ``np_random``, experiment counter, best cost."""
    plant = env.unwrapped
    state: dict[str, Any] = {"np_random": plant.np_random.bit_generator.state}
    if hasattr(plant, "experiment_index"):
        state["experiment_index"] = int(plant.experiment_index)
    if hasattr(plant, "_best_cost"):
        state["best_cost"] = float(plant._best_cost)
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
        plant._best_cost = float(state["best_cost"])
