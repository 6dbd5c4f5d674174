"""The tuner interface every tuner implements, and the one ``run`` loop they share.

Modelled on Optuna's ``BaseSampler``: a tuner proposes gains with ``ask`` and
learns from a finished experiment with ``tell``. The public methods validate
and call the private ``_ask`` / ``_tell`` that a tuner implements. A third
party writes a tuner by subclassing :class:`Tuner` and implementing those two.
"""

from __future__ import annotations

import abc
import logging
import numbers
import time
from typing import Any

import numpy as np

from agents.recorder import ExperimentRecorder, InMemory
from agents.result import TuningResult, constraint_columns, env_constraints
from agents.run_display import env_id, progress_bar
from agents.space import GainSpace
from gbo_envs.envs.external import ExperimentFailed
from gbo_envs.experiment import Experiment

__all__ = ["MAX_BUDGET", "MAX_SEED", "Tuner", "TuningInterrupted", "TuningStopped", "checked_budget", "checked_seed"]

_log = logging.getLogger(__name__)

#: Most plant experiments of one run (a budget beyond it is a typo, and some tuners size arrays to it).
MAX_BUDGET = 10**6
#: Largest seed: what every seeded library accepts (numpy's legacy ``RandomState``, scikit-learn, torch).
MAX_SEED = 2**32 - 1


def _is_integer(value) -> bool:
    """Whether ``value`` is an integer and not a bool (``2.5`` and ``True`` are not budgets or seeds)."""
    return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))


def checked_budget(budget, name: str = "budget") -> int:
    """``budget`` as an int from 1 to :data:`MAX_BUDGET` plant experiments, else ``ValueError`` naming ``name``."""
    if not _is_integer(budget) or not 1 <= budget <= MAX_BUDGET:
        raise ValueError(f"{name}: must be an integer from 1 to {MAX_BUDGET} (plant experiments), got {budget!r}")
    return int(budget)


def checked_seed(seed, name: str = "seed") -> int | None:
    """``seed`` as None or an int from 0 to :data:`MAX_SEED`, else ``ValueError`` naming ``name``."""
    if seed is not None and (not _is_integer(seed) or not 0 <= seed <= MAX_SEED):
        raise ValueError(f"{name}: must be None or an integer from 0 to {MAX_SEED}, got {seed!r}")
    return None if seed is None else int(seed)


class TuningInterrupted(KeyboardInterrupt):
    """Raised by :meth:`Tuner.run` on Ctrl-C; ``.result`` holds every finished experiment."""

    def __init__(self, result: TuningResult) -> None:
        super().__init__(f"tuning interrupted after {result.n_experiments} plant experiments")
        self.result = result


class TuningStopped(RuntimeError):
    """Raised when the failure policy of :meth:`Tuner.run` stops it before its budget.

    A failed experiment under ``on_failure="stop"``, too many skipped failures
    in a row, or (in a session) an experiment cut by a crash with
    ``on_crash="stop"``. ``.result`` holds the finished experiments (``None``
    when stopped before the loop started).
    """

    def __init__(self, message: str, result: TuningResult | None = None) -> None:
        super().__init__(message)
        self.result = result


class Tuner(abc.ABC):
    """Base class of all tuners.

    Subclasses take keyword arguments only, give every one a default, and
    implement :meth:`_ask` and :meth:`_tell`; they may override the no-op
    hook :meth:`_setup`. The feasible set comes from the env in :meth:`run`
    (or from :meth:`setup` when driving ``ask``/``tell`` by hand).

    Attributes
    ----------
    name : str
        Short registry name (``"bo"``, ``"random"``, ...), used in results.
    space : GainSpace
        Feasible set, set by :meth:`setup`.
    rng : numpy.random.Generator
        The tuner's only source of randomness, seeded by :meth:`setup`.
    """

    name: str = "tuner"
    #: ``progress`` of the current :meth:`run`, for a tuner's inner loops (e.g. RL pre-training)
    _run_progress: bool | None = False

    # -- the interface -----------------------------------------------------------------------------
    def setup(self, space: GainSpace, seed: int | None = None, env=None) -> None:
        """Prepare a fresh tuning session on ``space`` (forgets all data).

        Parameters
        ----------
        space : GainSpace or gymnasium.spaces.Box
            The feasible set; an env's ``action_space`` is read as :meth:`GainSpace.from_env` reads it (with the
            gain names of ``env`` when it is that env's).
        seed : int, optional
            Seeds :attr:`rng`; the same seed gives the same proposals for the same costs.
        env : gymnasium.Env, optional
            The plant env, for tuners that use more than the cost (e.g. a twin).
        """
        seed = checked_seed(seed)
        if not isinstance(space, GainSpace):
            plant = getattr(env, "unwrapped", None)
            own = plant is not None and space is getattr(plant, "action_space", None)
            space = GainSpace.from_env(env) if own else GainSpace.from_box(space)
        self.space = space
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self.env = env
        self._twin_log: list[dict] = []
        self._events: list[str] = []
        self._setup()

    def ask(self) -> tuple[float, ...]:
        """Gains for the next plant experiment, as plain floats inside the feasible set."""
        self._require_setup()
        return tuple(float(g) for g in self.space.check(self._ask(), name=f"{self.name}.ask()"))

    def tell(self, gains, cost: float, record: dict | None = None) -> None:
        """Report a finished plant experiment.

        Parameters
        ----------
        gains : sequence of float of length n_gains
            The gains that were run (inside the feasible set).
        cost : float
            Measured cost ``J`` (finite).
        record : dict, optional
            The experiment record (an env step's ``info``: ``t, r, u, y, metrics, ...``).

        Raises
        ------
        ValueError
            If ``gains`` has the wrong shape, is not finite or is out of bounds,
            or ``cost`` is not a finite number.
        """
        self._require_setup()
        if isinstance(gains, (bool, np.bool_)) or np.asarray(gains).dtype == np.bool_ or (
                isinstance(gains, (list, tuple)) and any(isinstance(g, (bool, np.bool_)) for g in gains)):
            raise TypeError(f"tell(gains): must be real numbers, got the boolean value(s) {gains!r}")
        checked = self.space.check(gains, name="tell(gains)")
        try:
            cost = float(cost)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"tell(cost): expected a finite number, got {cost!r}") from exc
        if not np.isfinite(cost):
            raise ValueError(f"tell(cost): must be finite, got {cost}")
        self._tell(checked, cost, record)

    @abc.abstractmethod
    def _ask(self) -> np.ndarray:
        """Return gains of shape (n_gains,) inside :attr:`space`."""

    @abc.abstractmethod
    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        """Learn from validated gains of shape (n_gains,) and their finite cost."""

    def _setup(self) -> None:  # noqa: B027 - an optional hook, as Optuna's sampler hooks
        """Hook called at the end of :meth:`setup` (no-op by default)."""

    # -- twin bookkeeping (used by tuners that evaluate a model) ------------------------------------
    def log_twin(self, gains, cost: float, metrics=None, **extra) -> None:
        """Record a digital-twin evaluation, shown as a ``source == "twin"`` row of the result."""
        row = {"gains": np.asarray(gains, dtype=float), "cost": float(cost), "metrics": metrics}
        row.update(extra)
        self._twin_log.append(row)

    def log_event(self, text: str) -> None:
        """Announce a change of the tuner's state (e.g. a refitted twin); :meth:`run` shows it once."""
        self._events.append(str(text))

    def drain_events(self) -> list[str]:
        """The events logged since the last call (see :meth:`log_event`), emptying the list."""
        events, self._events = self._events, []
        return events

    def drain_twin_log(self) -> list[dict]:
        """The twin evaluations logged since the last call (see :meth:`log_twin`), emptying the log."""
        rows, self._twin_log = self._twin_log, []
        return rows

    def _require_setup(self) -> None:
        if not hasattr(self, "space"):
            raise RuntimeError(f"{type(self).__name__}: call setup(space, seed) or run(env, budget) first")

    def get_params(self) -> dict[str, Any]:
        """Constructor arguments (as given), for result files and study specs."""
        return dict(getattr(self, "_params", {}))

    # -- the one tuning loop ----------------------------------------------------------------------
    def run(self, env, budget: int, seed: int | None = None, progress: bool | None = False, callback=None,
            recorder: ExperimentRecorder | None = None, max_consecutive_skips: int = 5) -> TuningResult:
        """Tune on ``env`` for ``budget`` plant experiments; with a ``recorder``, a crash-safe session.

        This is the one tuning loop: ``ask``, run the experiment with
        ``env.step``, ``tell``. A crash-safe session
        (:class:`evaluation.sessions.TuningSession`) is this loop with a
        ``recorder`` that commits every experiment before the next is proposed.

        Parameters
        ----------
        env : gymnasium.Env
            A plant env (``gym.make("gbo_envs/DCMotor-v0")`` or any env whose
            ``step`` takes gains and returns the experiment record in ``info``).
        budget : int
            Plant experiments the tuner learns from, 1 to :data:`MAX_BUDGET` (initial
            experiments included; skipped failures do not count).
        seed : int, optional
            Seeds both the env (``reset(seed=seed)``) and the tuner; 0 to :data:`MAX_SEED`.
        progress : bool or None, default False
            Show a progress bar on stderr; ``None``: only when stderr is a terminal.
        callback : callable, optional
            Called as ``callback(row)`` after every plant experiment the tuner learned from.
        recorder : agents.recorder.ExperimentRecorder, optional
            Experiment log: the loop first resumes from it (``recorder.resume``),
            then commits each experiment's intent before the plant is touched and
            its outcome before the tuner learns from it.
        max_consecutive_skips : int, default 5
            Stop after this many failed experiments in a row that the tuner was
            not told about (``>= 1``).

        Returns
        -------
        TuningResult
            The experiments run by this call (a session reads the whole log back instead).

        Raises
        ------
        TuningInterrupted
            On Ctrl-C, carrying the result of the finished experiments.
        TuningStopped
            When the failure policy stops the loop (see Notes), carrying the result so far.
        ValueError
            If ``budget`` is not an integer from 1 to :data:`MAX_BUDGET`, ``seed`` not
            None or an integer from 0 to :data:`MAX_SEED`, ``max_consecutive_skips`` not
            an integer ``>= 1``, or ``env.step`` reports a non-finite cost.

        Notes
        -----
        Failure policy, the same with and without a recorder. A failed
        experiment is recorded (``failed``, with its reason) and handled by
        what failed:

        * ``env.step`` raises :class:`gbo_envs.ExperimentFailed` (an external
          plant with ``on_failure="skip"`` or ``"stop"``): the tuner is not
          told. ``"skip"`` proposes again; the failure does not count against
          the budget, and ``max_consecutive_skips`` skips in a row raise
          :class:`TuningStopped`. ``"stop"`` raises :class:`TuningStopped`.
        * ``info["failed"]`` is true (``on_failure="penalize"``): the tuner is
          told the penalty cost without a record (a failed experiment has no
          trajectories to learn from); it counts against the budget.
        * ``env.step`` raises any other exception, or reports a non-finite
          cost: a fault of the env rather than of the experiment; the tuner is
          not told and the error propagates (``ValueError`` for the cost).

        An unstable closed loop is not a failure: the env reports its finite
        ``unstable_cost`` with ``info["unstable"] = True`` and the tuner learns
        it like any other cost. Ctrl-C during ``env.step`` abandons that
        experiment (a resumed session runs it again).
        """
        budget, seed = checked_budget(budget), checked_seed(seed)
        if not _is_integer(max_consecutive_skips) or max_consecutive_skips < 1:
            raise ValueError(f"max_consecutive_skips: must be an integer >= 1, got {max_consecutive_skips!r}")
        max_consecutive_skips = int(max_consecutive_skips)
        space = GainSpace.from_env(env)
        self._run_progress = progress  # inner loops of a tuner (e.g. RL pre-training) draw their bars alike
        self.setup(space, seed=seed, env=env)
        env.reset(seed=seed)
        recorder = InMemory() if recorder is None else recorder
        told, skips = recorder.resume(self, env)
        name = env_id(env)
        result = TuningResult(tuner=self.name, env_id=name, gain_names=space.names, seed=seed,
                              info={"params": self.get_params()}, gain_units=space.units,
                              constraints=env_constraints(env))
        start = time.perf_counter()
        best = np.inf
        bar = progress_bar(budget, f"{self.name} on {name}", progress, initial=told)
        try:
            while told < budget:
                if skips >= max_consecutive_skips:
                    raise TuningStopped(f"{skips} failed experiments in a row; fix the plant, then rerun to resume",
                                        result)
                experiment = told + 1
                gains = self.ask()
                _announce(self.drain_events(), bar, self.name)
                proposing = self.drain_twin_log()
                handle = recorder.begin(experiment, gains, proposing)
                try:
                    _, _, _, _, info = env.step(np.asarray(gains, dtype=np.float64))
                except ExperimentFailed as failure:
                    recorder.finish(handle, failure.record, failed=True, reason=failure.reason, told_cost=None)
                    if failure.policy == "stop":
                        raise TuningStopped(f"experiment {experiment} failed ({failure.reason}); the failure "
                                            "policy is 'stop'. Rerun to resume.", result) from failure
                    skips += 1
                    _log.warning("%s on %s: experiment %s failed and is skipped: %s", self.name, name, experiment,
                                 failure.reason)
                    continue
                except KeyboardInterrupt:
                    recorder.abandon(handle, "Ctrl-C during the experiment; it is run again")
                    raise
                except Exception as exc:
                    recorder.finish(handle, {"gains": gains}, failed=True, reason=f"{type(exc).__name__}: {exc}",
                                    told_cost=None)
                    raise
                cost = float(info["cost"])
                if not np.isfinite(cost):
                    reason = f"env.step reported a non-finite cost ({cost})"
                    recorder.finish(handle, info, failed=True, reason=reason, told_cost=None)
                    raise ValueError(f"experiment {experiment}: {reason}; the env must report a finite cost")
                failed = bool(info.get("failed", False))
                recorder.finish(handle, info, failed=failed, told_cost=cost,
                                reason=str(info.get("failure_reason")) if failed else None)
                self.tell(gains, cost, None if failed else info)
                _announce(self.drain_events(), bar, self.name)
                learning = self.drain_twin_log()
                recorder.add_twins(handle, learning)
                told, skips = told + 1, 0
                for twin in proposing + learning:
                    result.add(Experiment.from_mapping(twin, source="twin", index=experiment - 1), experiment,
                               np.nan, time.perf_counter() - start, twin)
                judged = constraint_columns(info, failed)
                if judged["feasible"] or not result.constraints:  # with limits: the best feasible cost so far
                    best = min(best, cost)
                record = Experiment.from_mapping(info)
                if record.cost != cost:  # a wrapper edited info["cost"]: the row shows the cost the tuner was told
                    record = record.replace(cost=cost)
                row = result.add(record, experiment, best, time.perf_counter() - start,
                                 {"true_cost": info.get("true_cost", np.nan),
                                  "unstable": bool(info.get("unstable", False)), **judged})
                if callback is not None:
                    callback(row)
                bar.update(1)
        except KeyboardInterrupt as exc:
            result.interrupted = True
            raise TuningInterrupted(result) from exc
        finally:
            bar.close()
        result.info.update(self.run_summary())
        return result

    def run_summary(self) -> dict[str, Any]:
        """Tuner-specific figures stored in ``TuningResult.info`` (e.g. twin activations)."""
        return {}

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"


def _announce(events: list[str], bar, tuner: str) -> None:
    """Print events above the progress bar, or log them at INFO without one."""
    for text in events:
        if hasattr(bar, "write"):
            bar.write(text)
        else:
            _log.info("%s: %s", tuner, text)
