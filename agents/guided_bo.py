"""Guided Bayesian optimization: BO guided by a digital twin (the paper's Algorithm 1 and a prior-mean form).

:class:`GuidedBO` composes three parts: the default BO (:class:`~agents.bo.BayesianOptimization`),
a twin keeper (:class:`~agents.twin_keeper.TwinKeeper`: the twin data set ``D~``, its fits,
refit rules and trust) and a guidance (:mod:`agents.guidance`: how the twin guides BO).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from agents.bo import BayesianOptimization
from agents.guidance import TwinIterations, TwinPrior, from_former_keywords
from agents.parameters import validate_params
from agents.twin.prior import unstable_metrics
from agents.twin_keeper import TwinKeeper
from agents.twin_safety import TwinSafeAcquisition, TwinSafetyFilter

__all__ = ["GuidedBO", "PRIOR_STARTS"]

#: L-BFGS-B starts of the multistart optimizer (three gains and more) while the twin prior is in use. Every
#: refinement step simulates the twin at ``starts * (d + 1)`` new gains; the best Sobol candidates under a twin
#: prior lie in the basin of the twin's optimum, and two starts reached the maximum of eight within 0.03 % at 5
#: of 5 asks of a DCMotorPID-v0 run (one start: 4 of 5), with a quarter of the refinement's twin simulations.
PRIOR_STARTS = 2

#: The keeper's settings that are the tuner's keywords too.
_KEEPER_PARAMS = ("eta2", "delta", "n_samples", "twin_poles", "twin")


def _keeper_attribute(name: str, doc: str) -> property:
    """A read-only attribute of the tuner that is its keeper's."""
    return property(lambda self: getattr(self.keeper_, name), doc=doc)


class GuidedBO(BayesianOptimization):
    r"""BO guided by a digital twin: the default BO, a :class:`~agents.twin_keeper.TwinKeeper` and a guidance.

    After ``N0`` Latin hypercube experiments every ``ask`` is the guidance's proposal, with
    ``theta+ = argmax_theta a_EI(theta)`` (eq. (EI)):

    * :class:`~agents.guidance.TwinPrior` (the default): while ``e_RMSE < eta2`` (eq. (DT_rmse1))
      and the twin is trusted, the metric GPs of ``J_hat = sum_i w_i f_i / n_i`` (eq. (J_used))
      have the twin's metrics ``f~_i(theta)`` as their prior mean, and the plant measures ``theta+``.
    * :class:`~agents.guidance.TwinIterations`, Algorithm 1 on one GP on the cost: if
      ``sqrt(v_n(theta+)) > eta1 sigma_eps`` (eq. (eta1)) and eq. (DT_rmse1) holds, BO runs on the
      twin, ``D <- D u {(theta+, J~(theta+))}`` (line D_in_DT), until ``a_EI,i <= eta3 max_j a_EI,j``
      for ``n_EI`` consecutive iterations (eq. (DT_stop_a)) or ``max_twin_iterations`` (eq.
      (DT_stop_b)); the plant measures the best twin point (line theta_plus) and the twin data
      leave ``D`` (line remove_DT_data).

    Every ``tell`` adds ``(theta, J)`` to ``D`` (eq. (D_training)) and the record ``(u, y)`` to
    ``D~`` (eq. (Ds)), which restarts when ``|J - J~| / J > delta`` (eq. (reinit_DTdataset)); the
    twin is refitted on ``D~`` when it mispredicts (:mod:`agents.twin_keeper` has the rules). A
    diverging experiment enters the metric GPs with the metrics of ``J = unstable_cost``.

    Parameters
    ----------
    n_initial : int, default 1
        ``N0``, the Latin hypercube initial set (count, >= 1).
    grid_points : int, default 100
        Grid points per gain for maximising EI (>= 2).
    noise_std : float, optional
        ``sigma_eps``, cost units (> 0); also the GP's fixed noise. Default: the env's
        ``cost_noise_std``, else 1 % of the mean measured cost (the GP then learns its noise).
    eta2 : float, optional
        Threshold of eq. (DT_rmse1) on the twin's normalised RMSE (> 0). Default:
        ``3 max(s, 10^-3)``, ``s`` the records' normalised noise floor; ``twin="linear"``: ``3 sigma_eps``.
    delta : float, default 2.0
        ``delta~`` of eq. (reinit_DTdataset), a relative cost error (>= 0).
    n_samples : int or None, default 100
        Samples per record kept for identification, eq. (Ds)'s ``n~`` (>= 10; ``None``: all).
    twin_poles : int, default 2
        Poles of the twin's transfer function (>= 1; no zeros).
    twin : {"auto", "linear"} or estimator, default "auto"
        The digital twin (see :class:`~agents.twin_keeper.TwinKeeper`).
    guidance : TwinPrior, TwinIterations, str or dict, default "prior"
        How the twin guides BO: an object of :mod:`agents.guidance`, a name (``"prior"``,
        ``"iterations"``: its defaults) or a one-key table, ``{"iterations": {"eta1": 2.0}}``.
    safe : bool, default False
        Safe mode with the twin as a safety filter (:mod:`agents.twin_safety`): every proposal is
        a gain the twin predicts safe by a margin from its measured error, so that the run keeps the
        env's constraints with probability ``>= 1 - safe_delta``, or the best feasible gains measured
        (while nothing is twin-safe); the first experiments are ``safe_start``. Needs an env with
        constraints, ``safe_start`` and the ``"prior"`` guidance.
    safe_start : array_like of shape (m, n_gains) or (n_gains,), optional
        Gains known to keep every constraint, in the env's units (as ``bo``'s).
    safe_delta : float, default 0.05
        Safe mode: the admitted probability that the run breaks a constraint, in ``(0, 1)``.
    **deprecated
        ``eta1``, ``eta3``, ``n_ei``, ``max_twin_iterations``, ``activation``, ``period``: the former
        spelling of :class:`~agents.guidance.TwinIterations`'s fields (a ``FutureWarning``).

    Attributes
    ----------
    keeper_ : TwinKeeper
        The twin of the run; ``twin_``, ``twin_changes_``, ``reinitializations_``, ``distrusts_``,
        ``noise_floor_``, ``sigma_eps``, ``eta2_value`` and ``trusted`` are its.
    activations_ : int
        Twin activations (with the prior: plant queries proposed with the twin prior).
    twin_evaluations_ : int
        Twin iterations made (``run_summary`` adds the prior's twin simulations).
    repeats_ : int
        Prior proposals of gains already measured, replaced by the default BO's.
    since_activation_ : float
        Proposals since the last twin activation (``inf`` before the first): the periodic rule's count.
    model : str
        The guidance's surrogate: ``"metrics"`` (the prior) or ``"cost"`` (the iterations).

    Notes
    -----
    **What the twin uses of a record, and what it identifies.** Of every plant record the keeper
    takes ``t``, ``r``, ``u`` and ``y`` (:data:`gbo_envs.experiment.SIGNALS`): ``u`` is the command the
    controller sends to the plant, ``y`` the measured output. The controller is not identified: the
    twin's loop is the plant env's, with its controller, limits, anti-windup and step. On a cascade
    (``LinearMotorCascade-v0``) ``u`` is the drive's current command in A (within its 7 A limit) and
    ``y`` the slider position in m; the speed estimate, the speed reference and the filtered setpoint
    are the controller's internal signals, functions of ``y`` and ``r``, and are not used. From these
    records the twin identifies the plant from current to position, ``b0 / (s^2 + a1 s) e^(-tau s)``
    (``twin_poles`` poles, the integrator from the env's plant): ``gain / inertia`` and ``damping /
    inertia``, not the three apart, and the delay (from two records within 1e-4 of the LinMot's
    6.2356 m/(A s^2), 11.270 1/s and 1 ms), the sensor's quantum (a record that holds still between
    its levels: the twin then rounds as the 5 um encoder does), and the effects that the records
    evidence (:mod:`agents.twin_keeper`). On the PID env (``DCMotorPID-v0``) ``u`` is the voltage and
    ``y`` the speed, as under PI.

    What a twin cannot identify is the response below one quantum. The cascade's speed estimate is a
    difference of encoder counts, so near its setpoint the loop chatters by a count, and whether the maximum
    of a response reads one count above its final value (an overshoot of 0.05 %, 0.10 in cost: the env's
    overshoot normaliser is one count, :func:`~gbo_envs.envs.base.normalizer_floors`) changes with a
    relative change of the plant's gain of 1e-5 at 43 % of the gains near the optimum (1e-6: 20 %). There
    the twin's overshoot is no forecast of the plant's: on ``LinearMotorCascade-v0`` a twin from three
    records has its optimum within 1.005 J* of the plant's (the plant's cost at the twin's optimum), yet at
    the best twin costs of 4096 Sobol gains the plant overshoots by a count.
    """

    name = "guided-bo"

    _parameter_constraints: dict[str, list] = {
        **BayesianOptimization._parameter_constraints,
        **{name: TwinKeeper._parameter_constraints[name] for name in _KEEPER_PARAMS},
        "safe_delta": BayesianOptimization._parameter_constraints["delta"],
    }

    def __init__(self, *, n_initial: int = 1, grid_points: int = 100, noise_std: float | None = None,
                 eta2: float | None = None, delta: float = 2.0, n_samples: int | None = 100, twin_poles: int = 2,
                 twin="auto", guidance: TwinPrior | TwinIterations | str | dict = "prior", safe: bool = False,
                 safe_start=None, safe_delta: float = 0.05, **deprecated) -> None:
        guidance = from_former_keywords(guidance, deprecated)
        safe_delta = validate_params(self._parameter_constraints, {"safe_delta": safe_delta})["safe_delta"]
        super().__init__(n_initial=n_initial, grid_points=grid_points, noise_std=noise_std, model=guidance.model,
                         safe=safe, safe_start=safe_start, delta=safe_delta)
        if self.safe and not isinstance(guidance, TwinPrior):
            raise ValueError(f"safe: the twin safety filter guides with the twin prior; got guidance {guidance!r}, "
                             "use guidance='prior'")
        self.safe_delta = self.delta
        params = validate_params(self._parameter_constraints, {
            "eta2": eta2, "delta": delta, "n_samples": n_samples, "twin_poles": twin_poles, "twin": twin})
        self.guidance = guidance
        self.eta2, self.delta = params["eta2"], params["delta"]
        self.n_samples = params["n_samples"]
        self.twin_poles = params["twin_poles"]
        self.twin = twin
        self._params = {"n_initial": self.n_initial, "grid_points": self.grid_points, "noise_std": self.noise_std,
                        **{name: value for name, value in params.items() if name != "twin"},
                        "twin": twin if isinstance(twin, str) else type(twin).__name__, "guidance": guidance}
        if self.safe:  # only what differs from the defaults, as bo's safe mode
            self._params.update({"safe": True, "safe_start": self.safe_start.tolist(), "safe_delta": self.safe_delta})

    # -- Tuner hooks ---------------------------------------------------------------------------------
    def _setup(self) -> None:
        super()._setup()
        plant_env = getattr(self.env, "unwrapped", None)
        if plant_env is None or not hasattr(plant_env, "loop"):
            raise ValueError("env: guided BO needs the plant env (with its closed loop) to simulate a twin; "
                             "use run(env, ...) or setup(space, seed, env=env)")
        self._plant_env = plant_env
        self.keeper_ = TwinKeeper(self.twin, twin_poles=self.twin_poles, n_samples=self.n_samples, delta=self.delta,
                                  eta2=self.eta2, noise_std=self.noise_std,
                                  refit_on_cost_miss=self.guidance.refit_on_cost_miss)
        self.keeper_.setup(self.space, plant_env, constraints=plant_env.constraints if self.safe else None)
        self.activations_ = self.twin_evaluations_ = self.repeats_ = 0
        self.since_activation_ = np.inf
        self._prior = None  # the twin's metrics while they are the metric GPs' prior mean
        self.safety_ = TwinSafetyFilter(plant_env.constraints, self.safe_delta) if self.safe else None

    def _ask(self) -> np.ndarray:
        if self.n_observations < self.n_initial and not self.safe:
            return super()._ask()
        gains = self.guidance.propose(self, self.keeper_)
        if self.safety_ is not None and self.n_observations >= 1:
            simulation = self.keeper_.twin_simulation()  # the prior's simulations of the twin: each gain once
            self.safety_.expect(simulation, gains)  # the twin's prediction, judged at tell()
            self.safety_.admitted_ += int(self.safety_.admits(simulation, gains, self.n_observations + 1)[0])
        return gains

    def _constrained_acquisition(self, model):
        """Safe mode: ``EI x PF`` on the twin-safe gains, else bo's.

        (:class:`~agents.twin_safety.TwinSafeAcquisition`)."""
        if self.safety_ is None:
            return super()._constrained_acquisition(model)
        acquisition = super()._constrained_acquisition(model)
        return TwinSafeAcquisition(acquisition.ei, self.constraint_model, self.safety_,
                                   self.keeper_.twin_simulation(), self.space, self.n_observations + 1)

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        super()._tell(gains, cost, record)
        if self.safety_ is not None:
            self.safety_.observe(gains, record)
        if record is not None and record.get("unstable", False) and self.metric_surrogate is not None:
            # a diverging experiment keeps the metric GPs (and the twin prior) in use: its metrics are
            # those of J = unstable_cost, as the twin's diverging points (agents.twin.prior.TwinMetrics)
            self._plant_F[-1] = unstable_metrics(self._plant_env)
        self.keeper_.tell(gains, cost, record)

    def drain_events(self) -> list[str]:
        """The events logged since the last call: the tuner's, then its keeper's twin changes."""
        return super().drain_events() + self.keeper_.drain_events()

    def run_summary(self) -> dict[str, Any]:
        summary = super().run_summary()
        summary.update({"activations": self.activations_,
                        "twin_evaluations": self.twin_evaluations_ + self.keeper_.metric_simulations_,
                        "repeats": self.repeats_, **self.keeper_.summary()})
        if self.safety_ is not None:
            summary.update({"twin_admitted": self.safety_.admitted_, "twin_errors": len(self.safety_.errors_)})
        return summary

    # -- what the guidance uses ----------------------------------------------------------------------
    def twin_env(self):
        """The current twin's env (:class:`agents.twin.TwinEnv`), refitted on ``D~`` if due; ``None`` without one."""
        return self.keeper_.twin_env()

    def default_ask(self) -> np.ndarray:
        """The default BO's proposal on the current surrogate (and prior, see :meth:`use_prior`)."""
        return super()._ask()

    def metric_prior(self):
        """The twin's metrics (:class:`agents.twin.prior.TwinMetrics`) while they guide BO, else ``None``."""
        return self._prior

    def use_prior(self, prior) -> None:
        """Make ``prior`` the metric GPs' prior mean (``None``: constant); the surrogate is refitted if it changed."""
        if prior is not self._prior:
            self._prior = prior
            self._data_changed()

    def multistart_plan(self) -> tuple[np.random.Generator, int]:
        """The multistart optimizer's Sobol scramble and L-BFGS-B starts (three gains and more).

        The default BO's candidates (a new scramble every fit); while the twin prior is in use the refinement runs
        from :data:`PRIOR_STARTS` starts. New candidates every ask matter on a twin whose cost is rough below the
        sensor's quantum (the class notes): the same 2048 candidates at every ask (the twin simulated on them once
        per twin) needed 53 and 61 experiments (a miss) to 1.05 J* on LinearMotorCascade-v0, seeds 4 and 8; new ones 3
        and 7.
        """
        rng, n_starts = super().multistart_plan()
        return rng, n_starts if self._prior is None else min(n_starts, PRIOR_STARTS)

    def has_measured(self, gains) -> bool:
        """Whether the plant was measured at ``gains`` (physical units) already."""
        unit = self.space.to_unit(gains)
        return any(np.allclose(unit, measured, rtol=0.0, atol=1e-9) for measured in self._plant_X)

    def plant_incumbent(self) -> np.ndarray | None:
        """``theta_I``: the gains of the plant experiment with the lowest measured cost (``None`` before any)."""
        if not self._plant_y:
            return None
        return self.space.from_unit(np.asarray(self._plant_X[int(np.argmin(self._plant_y))]))

    @property
    def optimize_hyperparameters(self) -> bool:
        """Whether the next GP fit optimises the hyperparameters (``False``: it only re-conditions the GP)."""
        return self._optimize_hyperparameters

    @optimize_hyperparameters.setter
    def optimize_hyperparameters(self, value: bool) -> None:
        self._optimize_hyperparameters = bool(value)

    twin_ = _keeper_attribute("twin_", "The current fitted twin, or ``None``.")
    twin_changes_ = _keeper_attribute("changes_", "One entry per twin fit (see :attr:`TwinKeeper.changes_`).")
    reinitializations_ = _keeper_attribute("reinitializations_", "Restarts of the twin data set ``D~``.")
    distrusts_ = _keeper_attribute("distrusts_", "Twin promises the plant broke.")
    noise_floor_ = _keeper_attribute("noise_floor_", "``s``: the records' median normalised noise floor.")
    sigma_eps = _keeper_attribute("sigma_eps", "Cost noise std ``sigma_eps`` of eqs. (eta1) and (DT_rmse1).")
    eta2_value = _keeper_attribute("eta2_", "The RMSE threshold of eq. (DT_rmse1) in use.")
    trusted = _keeper_attribute("trusted", "Whether the twin may propose plant experiments.")
