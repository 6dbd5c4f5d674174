"""Any Optuna sampler as a tuner, through Optuna's ask-and-tell interface."""

from __future__ import annotations

import inspect
from typing import Any

import numpy as np

from agents.base import Tuner
from agents.feasibility import constraint_set, reported_slacks
from agents.parameters import HasMethods, Interval, Options, validate_params
from agents.peers.base import latin_hypercube

__all__ = ["OptunaTuner", "OptunaGP", "OptunaTPE", "SAMPLERS"]

#: Sampler short names -> ``optuna.samplers`` class names.
SAMPLERS = {"gp": "GPSampler", "tpe": "TPESampler", "random": "RandomSampler", "qmc": "QMCSampler",
            "cmaes": "CmaEsSampler"}


class OptunaTuner(Tuner):
    """Adapter: an Optuna sampler proposes the gains, one ``suggest_float`` per gain.

    Each :meth:`ask` is ``study.ask()`` followed by ``trial.suggest_float(name,
    low, high)`` for every gain of the feasible set; each :meth:`tell` is
    ``study.tell(trial, cost)`` (minimisation). Gains told without a matching
    ask are added as finished trials. Optuna's logging is set to WARNING.

    Parameters
    ----------
    sampler : str, optuna sampler class, callable or sampler instance, default "tpe"
        ``"gp"``, ``"tpe"``, ``"random"``, ``"qmc"``, ``"cmaes"`` or a sampler
        class: built as ``cls(seed=seed, **sampler_kwargs)`` at every setup
        with the run's seed. A callable ``seed -> sampler`` likewise. A
        sampler *instance* is used as given (its own seed decides
        reproducibility, and it is shared between runs).
    sampler_kwargs : dict, optional
        Extra constructor arguments of the sampler.
    n_initial : int, optional
        ``None``: the sampler's own start (GPSampler and TPESampler: 10 independent random
        trials). An int ``N0 >= 1``: the first ``N0`` trials are ``agents.make("bo")``'s Latin
        hypercube initial design for the same seed (enqueued with ``study.enqueue_trial``), and a
        sampler built here that takes ``n_startup_trials`` gets ``n_startup_trials=N0`` (unless
        ``sampler_kwargs`` sets it), so its model takes over right after the design.

    Notes
    -----
    On an env with constraints (``gym.make(id, constraints=...)``, ``env.unwrapped.constraints``),
    every told trial carries them as Optuna constraints (``trial.set_constraint(name, value -
    limit)``, Optuna's convention: ``<= 0`` feasible; a failed or unstable experiment counts as
    broken by its limit, :func:`agents.feasibility.reported_slacks`). The samplers that model
    constraints use them: ``GPSampler``'s constrained LogEI (EI x probability of feasibility,
    Optuna >= 4.2) and ``TPESampler``'s feasibility-weighted TPE; Optuna's best trial is then the
    best feasible one.
    """

    name = "optuna"

    _parameter_constraints = {
        "sampler": [Options(tuple(SAMPLERS)), HasMethods(("__call__",)), HasMethods(("sample_relative",))],
        "sampler_kwargs": [None, HasMethods(("keys",))],
        "n_initial": [None, Interval(int, 1, None)],
    }

    def __init__(self, *, sampler: Any = "tpe", sampler_kwargs: dict | None = None,
                 n_initial: int | None = None) -> None:
        checked = validate_params(self._parameter_constraints,
                                  {"sampler": sampler, "sampler_kwargs": sampler_kwargs, "n_initial": n_initial})
        self.sampler = sampler
        self.sampler_kwargs = dict(sampler_kwargs or {})
        self.n_initial = checked["n_initial"]
        self._params = {"sampler": sampler if isinstance(sampler, str) else repr(sampler),
                        "sampler_kwargs": self.sampler_kwargs}
        if self.n_initial is not None:
            self._params["n_initial"] = self.n_initial

    def _make_sampler(self, seed: int | None):
        import optuna

        if isinstance(self.sampler, str):
            return self._build(getattr(optuna.samplers, SAMPLERS[self.sampler]), seed)
        if isinstance(self.sampler, type):
            return self._build(self.sampler, seed)
        if callable(self.sampler) and not isinstance(self.sampler, optuna.samplers.BaseSampler):
            return self.sampler(seed)
        return self.sampler

    def _build(self, cls: type, seed: int | None):
        """``cls(seed=seed, **sampler_kwargs)``, with ``n_startup_trials = n_initial`` where it applies."""
        kwargs = dict(self.sampler_kwargs)
        if self.n_initial is not None and "n_startup_trials" in inspect.signature(cls).parameters:
            kwargs.setdefault("n_startup_trials", self.n_initial)
        return cls(seed=seed, **kwargs)

    def _setup(self) -> None:
        import optuna

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        # BO's initial design is the first draw from the tuner rng, as in agents.bo
        initial = None if self.n_initial is None else latin_hypercube(self.rng, self.space.dim, self.n_initial)
        # the run's seed, or a draw from the tuner rng when setup got no seed
        seed = self.seed if self.seed is not None else int(self.rng.integers(2**31))
        self._distributions = {name: optuna.distributions.FloatDistribution(float(lo), float(hi))
                               for name, lo, hi in zip(self.space.names, self.space.low, self.space.high)}
        self.study = optuna.create_study(direction="minimize", sampler=self._make_sampler(seed))
        for point in () if initial is None else self.space.from_unit(initial):
            self.study.enqueue_trial({name: float(g) for name, g in zip(self.space.names, point)})
        self._pending: tuple[Any, np.ndarray] | None = None
        self._constraints = constraint_set(self.env)

    def _ask(self) -> np.ndarray:
        if self._pending is not None:  # ask twice without tell: same proposal
            return self._pending[1].copy()
        trial = self.study.ask()
        gains = np.array([trial.suggest_float(name, float(lo), float(hi))
                          for name, lo, hi in zip(self.space.names, self.space.low, self.space.high)])
        self._pending = (trial, gains)
        return gains.copy()

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        import optuna

        slacks = None if self._constraints is None else \
            dict(zip(self._constraints[0], reported_slacks(record, *self._constraints)))
        if self._pending is not None and np.allclose(self._pending[1], gains, rtol=0.0, atol=1e-12):
            for name, value in (slacks or {}).items():
                self._pending[0].set_constraint(name, value)
            self.study.tell(self._pending[0], cost)
        else:
            if self._pending is not None:  # the asked gains were not run
                self.study.tell(self._pending[0], state=optuna.trial.TrialState.FAIL)
            params = {name: float(g) for name, g in zip(self.space.names, gains)}
            self.study.add_trial(optuna.trial.create_trial(params=params, distributions=self._distributions,
                                                           value=cost, **({} if slacks is None else
                                                                          {"constraints": slacks})))
        self._pending = None


class OptunaGP(OptunaTuner):
    """:class:`OptunaTuner` with ``optuna.samplers.GPSampler(seed=...)`` (registry name ``optuna-gp``).

    ``n_initial=N0`` starts it from ``agents.make("bo")``'s initial design (see :class:`OptunaTuner`).
    """

    name = "optuna-gp"

    def __init__(self, *, sampler_kwargs: dict | None = None, n_initial: int | None = None) -> None:
        super().__init__(sampler="gp", sampler_kwargs=sampler_kwargs, n_initial=n_initial)


class OptunaTPE(OptunaTuner):
    """:class:`OptunaTuner` with ``optuna.samplers.TPESampler(seed=...)`` (registry name ``optuna-tpe``)."""

    name = "optuna-tpe"

    def __init__(self, *, sampler_kwargs: dict | None = None) -> None:
        super().__init__(sampler="tpe", sampler_kwargs=sampler_kwargs)

