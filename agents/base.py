"""The tuner interface every tuner implements, and the one ``run`` loop they share.

Modelled on Optuna's ``BaseSampler``: a tuner proposes gains with ``ask`` and
learns from a finished experiment with ``tell``. The public methods validate
and call the private ``_ask`` / ``_tell`` that a tuner implements. A third
party writes a tuner by subclassing :class:`Tuner` and implementing those two.
"""

from __future__ import annotations

import abc
import time
from typing import Any

import numpy as np

from agents.result import TuningResult
from agents.space import GainSpace
from agents.utils import env_id, progress_bar
from gbo_envs.experiment import Experiment

__all__ = ["Tuner", "TuningInterrupted"]


class TuningInterrupted(KeyboardInterrupt):
    """Raised by :meth:`Tuner.run` on Ctrl-C; ``.result`` holds every finished experiment."""

    def __init__(self, result: TuningResult) -> None:
        super().__init__(f"tuning interrupted after {result.n_experiments} plant experiments")
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

    # -- the interface -----------------------------------------------------------------------------
    def setup(self, space: GainSpace, seed: int | None = None, env=None) -> None:
        """Prepare a fresh tuning session on ``space`` (forgets all data).

        Parameters
        ----------
        space : GainSpace
        seed : int, optional
            Seeds :attr:`rng`; the same seed gives the same proposals for the same costs.
        env : gymnasium.Env, optional
            The plant env, for tuners that use more than the cost (e.g. a twin).
        """
        self.space = space
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self.env = env
        self._twin_log: list[dict] = []
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

    def _drain_twin_log(self) -> list[dict]:
        rows, self._twin_log = self._twin_log, []
        return rows

    def _require_setup(self) -> None:
        if not hasattr(self, "space"):
            raise RuntimeError(f"{type(self).__name__}: call setup(space, seed) or run(env, budget) first")

    def get_params(self) -> dict[str, Any]:
        """Constructor arguments (as given), for result files and study specs."""
        return dict(getattr(self, "_params", {}))

    # -- the shared loop ---------------------------------------------------------------------------
    def run(self, env, budget: int, seed: int | None = None, progress: bool = False,
            callback=None) -> TuningResult:
        """Tune on ``env`` for ``budget`` plant experiments.

        Parameters
        ----------
        env : gymnasium.Env
            A plant env (``gym.make("gbo_envs/DCMotor-v0")`` or any env whose
            ``step`` takes gains and returns the experiment record in ``info``).
        budget : int
            Number of plant experiments, ``>= 1`` (initial experiments included).
        seed : int, optional
            Seeds both the env (``reset(seed=seed)``) and the tuner.
        progress : bool, default False
            Show a progress bar.
        callback : callable, optional
            Called as ``callback(row)`` after every plant experiment (e.g. to save it).

        Returns
        -------
        TuningResult

        Raises
        ------
        TuningInterrupted
            On Ctrl-C, carrying the result of the finished experiments.
        """
        if int(budget) < 1:
            raise ValueError(f"budget: must be an integer >= 1, got {budget}")
        budget = int(budget)
        space = GainSpace.from_env(env)
        self.setup(space, seed=seed, env=env)
        env.reset(seed=seed)
        name = env_id(env)
        result = TuningResult(tuner=self.name, env_id=name, gain_names=space.names, seed=seed,
                              info={"params": self.get_params()}, gain_units=space.units)
        start = time.perf_counter()
        best = np.inf
        bar = progress_bar(budget, f"{self.name} on {name}", progress)
        try:
            for experiment in range(1, budget + 1):
                gains = self.ask()
                _, _, _, _, info = env.step(np.asarray(gains, dtype=np.float64))
                cost = float(info["cost"])
                self.tell(gains, cost, info)
                for twin in self._drain_twin_log():
                    result.add(Experiment.from_mapping(twin, source="twin", index=experiment - 1), experiment,
                               np.nan, time.perf_counter() - start, twin)
                best = min(best, cost)
                row = result.add(Experiment.from_mapping(info), experiment, best, time.perf_counter() - start,
                                 {"true_cost": info.get("true_cost", np.nan),
                                  "unstable": bool(info.get("unstable", False))})
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

