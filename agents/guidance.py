"""How the digital twin guides BO: the objects ``GuidedBO(guidance=...)`` is composed with.

As BoTorch composes a model with an acquisition function instead of switching
one optimiser by flags, guided BO takes its guidance as an object that carries
only the parameters of that guidance:

* :class:`TwinPrior` (the default): the twin's metrics are the prior mean of the
  default BO's metric GPs; it has no parameters of its own.
* :class:`TwinIterations`: the paper's Algorithm 1, BO iterations on the twin
  while the GP is uncertain; it holds the parameters of eqs. (eta1),
  (DT_stop_a) and (DT_stop_b) and the periodic rule of Sec. V-A.

Each guidance has behaviour: ``propose(bo, keeper)`` is the plant proposal of guided BO
``bo`` (:class:`~agents.guided_bo.GuidedBO`) after its initial design, with the twin of
``keeper`` (:class:`~agents.twin_keeper.TwinKeeper`); ``refit_on_cost_miss`` tells the keeper
whether a cost ``3 sigma_eps`` off the twin's calls for a refit. What both guidances use stays
on the tuner and its keeper: ``eta2`` (eq. (DT_rmse1): whether the twin may guide at all),
``delta`` (eq. (reinit_DTdataset): when the twin data set restarts), ``n_samples`` (the twin
data's decimation, eq. (Ds)) and ``twin_poles``.

A study file (``evaluation/studies/*.toml``), or any caller of
``agents.make``, may name a guidance instead: ``guidance = "iterations"`` (its
defaults, the paper's table) or ``guidance = {iterations = {eta1 = 3.0}}`` (a
table of its parameters); :func:`as_guidance` turns either into the object.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np

from agents.bo import BayesianOptimization
from agents.parameters import Interval, Options, validate_params
from agents.thread_limits import single_thread
from agents.twin_keeper import TwinKeeper
from gbo_envs import METRIC_NAMES

__all__ = ["ACTIVATION_RULES", "GUIDANCE_RULES", "Guidance", "MIN_TWIN_ITERATIONS", "TWIN_REFIT_EVERY",
           "TwinIterations", "TwinPrior", "as_guidance", "from_former_keywords"]

#: Twin iterations per activation before eq. (DT_stop_a) may stop them.
MIN_TWIN_ITERATIONS = 10

#: The GP hyperparameters are re-fitted (warm-started) on every this-many-th twin iteration;
#: the iterations in between only re-condition the GP on the new point.
TWIN_REFIT_EVERY = 5

#: How the twin is switched on: the paper's uncertainty test eq. (DT_activation), or every
#: ``period`` plant experiments for ``n_ei`` twin iterations (the twin-fidelity study, Sec. V-A).
ACTIVATION_RULES = ("uncertainty", "periodic")


@dataclass(frozen=True)
class TwinPrior:
    r"""The twin's metrics as the prior mean of the default BO's metric GPs (``GuidedBO``'s default).

    While the twin may guide (eq. (DT_rmse1) and trust), the prior mean of metric ``i``'s GP is
    the twin's metric ``f~_i(theta)`` (:meth:`~agents.twin_keeper.TwinKeeper.twin_metrics`), so the
    GP models the discrepancy ``T_i(f_i) - T_i(f~_i)`` (``T_i``: ``f / n_i``, or its log), unless the
    measured ``T_i(f_i)`` are likelier under a constant mean
    (:class:`~agents.metric_surrogate.MetricSurrogate`): the
    posterior of ``J_hat = sum_i w_i f_i / n_i`` (eq. (J_used)) follows the twin, corrected where
    the plant was measured. Every ``ask`` queries the maximiser of EI (eq. (EI)) on that
    posterior; where it proposes gains already measured, the experiment is the default BO's
    proposal (EI without the prior). A plant cost more than ``3 sigma_eps`` off the twin's refits
    the twin once the records have doubled since its fit (``refit_on_cost_miss``). The guidance
    has no parameters.

    Examples
    --------
    >>> from agents.guidance import TwinPrior
    >>> TwinPrior()
    TwinPrior()
    """

    #: The name a study file or ``agents.make`` gives this guidance.
    name: ClassVar[str] = "prior"
    #: ``GuidedBO``'s surrogate under this guidance: one GP per performance metric.
    model: ClassVar[str] = "metrics"
    #: The twin is refitted when a plant cost misses its cost by more than the cost noise: the refit rule on
    #: the responses misses a twin whose response is close but whose thin optimal valley sits a grid cell away.
    refit_on_cost_miss: ClassVar[bool] = True

    def propose(self, bo: BayesianOptimization, keeper: TwinKeeper) -> np.ndarray:
        """The next plant gains (physical units): EI's maximiser with the twin prior, else without.

        Parameters
        ----------
        bo : agents.guided_bo.GuidedBO
            The tuner, past its initial design.
        keeper : agents.twin_keeper.TwinKeeper
            Its twin.
        """
        prior = keeper.twin_metrics() if keeper.can_guide() else None
        bo.use_prior(prior)
        gains = bo.default_ask()
        if prior is None:
            return gains
        bo.activations_ += 1
        if bo.has_measured(gains):  # the twin has nothing new to say: the default BO's proposal
            bo.use_prior(None)
            try:
                gains = bo.default_ask()
            finally:
                bo.use_prior(prior)
            bo.repeats_ += 1
        return gains


@dataclass(frozen=True)
class TwinIterations:
    r"""The paper's Algorithm 1: BO iterations on the twin while the GP is uncertain, on one GP on the cost.

    The defaults are the paper's parameter table. Every ``ask`` after the initial design
    activates the twin when ``sqrt(v_n(theta+)) > eta1 sigma_eps`` (eq. (eta1)) and the
    twin fits (``GuidedBO``'s ``eta2``, eq. (DT_rmse1)); BO then runs on the twin until
    for ``n_ei`` consecutive iterations ``a_EI,i <= eta3 max_j a_EI,j`` (eq. (DT_stop_a)),
    or for ``max_twin_iterations`` (eq. (DT_stop_b)); each twin point enters ``D`` as a cost
    (line D_in_DT), the plant measures the best of them (line theta_plus), and they leave
    ``D`` (line remove_DT_data). A twin point the plant measures worse than promised costs
    the twin its trust (:meth:`~agents.twin_keeper.TwinKeeper.promise`).

    Parameters
    ----------
    eta1 : float, default 3.0
        Activation threshold of eq. (eta1), in units of the cost noise ``sigma_eps``
        (dimensionless, >= 0): the twin is used when the GP's posterior std at the next
        query exceeds ``eta1 * sigma_eps``. (The paper states ``eta1 = 3`` without a
        unit; tying it to the noise level makes the same value work on every plant.)
    eta3 : float, default 0.2
        Stopping threshold of eq. (DT_stop_a), a fraction (dimensionless, >= 0) of the
        largest EI realised since the activation; ``inf`` runs exactly ``n_ei`` iterations.
    n_ei : int, default 3
        ``n~_EI`` of eq. (DT_stop_a): consecutive twin iterations (count, >= 1) below
        ``eta3`` that stop the activation.
    max_twin_iterations : int, default 20
        Cap of eq. (DT_stop_b): twin iterations per activation (count, >= 1).
    activation : {"uncertainty", "periodic"}, default "uncertainty"
        ``"uncertainty"``: the test of eq. (eta1). ``"periodic"``: every ``period``
        plant experiments, for exactly ``n_ei`` iterations, subject only to ``eta2``
        (the twin-fidelity study, Sec. V-A).
    period : int, default 1
        ``N_G`` of the periodic rule, in plant experiments (>= 1).

    Raises
    ------
    ValueError
        A parameter outside its range, naming it, e.g. ``eta1: must be a float in [0, inf), got -1.0``.

    Notes
    -----
    Where the paper leaves room (the measured effects: benchmarks/README.md): the maximum of
    eq. (DT_stop_a) runs over every EI realised since the activation; at least
    :data:`MIN_TWIN_ITERATIONS` twin iterations per activation; the twin's costs enter ``D``
    without the paper's artificial noise ``eps``; "the best point of ``D``" is the twin point of
    this activation with the lowest twin cost; during twin iterations EI's incumbent is the
    posterior-mean one, its grid maximiser is polished by L-BFGS-B, and the GP hyperparameters
    are re-fitted (Algorithm 1, line 12, warm-started) on every :data:`TWIN_REFIT_EVERY`-th one.

    Examples
    --------
    >>> from agents.guidance import TwinIterations
    >>> TwinIterations(eta1=2)
    TwinIterations(eta1=2.0, eta3=0.2, n_ei=3, max_twin_iterations=20, activation='uncertainty', period=1)
    """

    eta1: float = 3.0
    eta3: float = 0.2
    n_ei: int = 3
    max_twin_iterations: int = 20
    activation: str = "uncertainty"
    period: int = 1

    #: The name a study file or ``agents.make`` gives this guidance.
    name: ClassVar[str] = "iterations"
    #: ``GuidedBO``'s surrogate under this guidance: one GP on the cost (the twin's points enter ``D``
    #: as costs, Algorithm 1, line D_in_DT).
    model: ClassVar[str] = "cost"
    #: Trust guards the twin's proposals instead (see :meth:`~agents.twin_keeper.TwinKeeper.promise`).
    refit_on_cost_miss: ClassVar[bool] = False
    _parameter_constraints: ClassVar[dict[str, list]] = {
        "eta1": [Interval(float, 0.0, None)],
        "eta3": [Interval(float, 0.0, None)],
        "n_ei": [Interval(int, 1, None)],
        "max_twin_iterations": [Interval(int, 1, None)],
        "activation": [Options(ACTIVATION_RULES)],
        "period": [Interval(int, 1, None)],
    }

    def __post_init__(self) -> None:
        checked = validate_params(self._parameter_constraints, {f.name: getattr(self, f.name) for f in fields(self)})
        for name, value in checked.items():  # ints to int, reals to float: equal objects for equal values
            object.__setattr__(self, name, value)

    def propose(self, bo: BayesianOptimization, keeper: TwinKeeper) -> np.ndarray:
        """The next plant gains (physical units): EI's maximiser, or the best twin point of an activation.

        Parameters
        ----------
        bo : agents.guided_bo.GuidedBO
            The tuner, past its initial design.
        keeper : agents.twin_keeper.TwinKeeper
            Its twin.
        """
        with single_thread():  # small matrices, as in BayesianOptimization._ask
            gains, ei, std = bo.propose()
            bo.last_ei_, bo.last_std_ = ei, std
            if self._due(bo, std) and keeper.can_guide():  # eq. (DT_activation): also eq. (DT_rmse1) and trust
                gains = self._explore_on_twin(bo, keeper, gains, ei)
            bo.since_activation_ += 1
            bo.last_mean_ = float(bo.posterior(gains[None, :])[0][0])
        return gains

    def _due(self, bo: BayesianOptimization, std: float) -> bool:
        """The periodic rule, or eq. (eta1): the GP's std at the next query beyond ``eta1 sigma_eps``."""
        if self.activation == "periodic":
            return bo.since_activation_ >= self.period
        return std > self.eta1 * bo.sigma_eps

    def _explore_on_twin(self, bo: BayesianOptimization, keeper: TwinKeeper, gains: np.ndarray,
                         ei: float) -> np.ndarray:
        """BO iterations on the twin until eq. (DT_stop) holds; returns the best point of ``D``."""
        bo.activations_ += 1
        bo.since_activation_ = 0
        twin_env = keeper.twin_env()
        periodic = self.activation == "periodic"
        cap = self.n_ei if periodic else self.max_twin_iterations
        saved = bo.incumbent_rule, bo.polish
        # twin iterations: posterior-mean incumbent (the plant data in D are noisy), polished EI maximiser
        bo.incumbent_rule, bo.polish = "posterior_mean", True
        try:
            best, best_cost = self._twin_iterations(bo, keeper, twin_env, gains, ei, cap, periodic)
        finally:
            bo.optimize_hyperparameters = True
            bo.incumbent_rule, bo.polish = saved
        bo.remove_data("twin")  # line remove_DT_data
        incumbent = bo.plant_incumbent()
        if keeper.judges_trust and incumbent is not None:
            # the GP's mean at the incumbent, not its lowest measurement (biased low by the noise)
            keeper.promise(best, best_cost, incumbent, float(bo.posterior(incumbent[None, :])[0][0]))
        return best

    def _twin_iterations(self, bo: BayesianOptimization, keeper: TwinKeeper, twin_env, gains: np.ndarray,
                         ei: float, cap: int, periodic: bool) -> tuple[np.ndarray, float]:
        """Lines 9-16 of Algorithm 1; returns the best point of ``D`` (line theta_plus) and its twin cost."""
        eis, calm = [ei], 0
        twin_X, twin_J = [], []
        described = keeper.describe()
        for iteration in range(1, cap + 1):
            metrics, clean = twin_env.evaluate(gains[None, :])
            cost = float(clean[0]) if np.isfinite(clean[0]) else float(twin_env.unstable_cost)
            twin_X.append(gains.copy())
            twin_J.append(cost)
            bo.add_data(gains, cost, source="twin")  # line D_in_DT, without the paper's eps
            bo.log_twin(gains, cost, dict(zip(METRIC_NAMES, metrics[0])), activation=bo.activations_,
                        twin_iteration=iteration, twin_true_cost=cost, **described)
            bo.twin_evaluations_ += 1
            # Algorithm 1, line 12: hyperparameters re-fitted on every TWIN_REFIT_EVERY-th twin iteration
            bo.optimize_hyperparameters = (iteration - 1) % TWIN_REFIT_EVERY == 0
            gains, ei, _ = bo.propose()
            if not periodic:
                # eq. (DT_stop_a), against the largest EI realised since the activation
                calm = calm + 1 if ei <= self.eta3 * max(eis) else 0
                eis.append(ei)
                if calm >= self.n_ei and iteration >= MIN_TWIN_ITERATIONS:
                    break
        # line theta_plus: the twin point of this activation with the lowest twin cost
        best = int(np.argmin(twin_J))
        return twin_X[best], twin_J[best]


#: A guidance object.
Guidance = TwinPrior | TwinIterations

#: Guidance by name (``guidance = "iterations"`` in a study file).
_BY_NAME: dict[str, type] = {TwinPrior.name: TwinPrior, TwinIterations.name: TwinIterations}

#: The guidance names: the twin as prior mean of the metric GPs, or the paper's twin iterations.
GUIDANCE_RULES = tuple(_BY_NAME)


def as_guidance(value: Any) -> TwinPrior | TwinIterations:
    """The guidance object that ``value`` names.

    Parameters
    ----------
    value : TwinPrior, TwinIterations, str or mapping
        A guidance object (returned as it is); a name, ``"prior"`` or ``"iterations"``
        (its defaults); or a mapping of one name to the guidance's parameters,
        ``{"iterations": {"eta1": 3.0}}`` (a study file's ``{iterations = {eta1 = 3.0}}``).

    Raises
    ------
    ValueError
        Anything else, or a parameter the guidance rejects.
    """
    if isinstance(value, (TwinPrior, TwinIterations)):
        return value
    if isinstance(value, str) and value in _BY_NAME:
        return _BY_NAME[value]()
    if isinstance(value, Mapping) and len(value) == 1:
        (name, params), = value.items()
        if name in _BY_NAME and isinstance(params, Mapping):
            cls = _BY_NAME[name]
            known = {f.name for f in fields(cls)}
            unknown = sorted(set(params) - known)
            if unknown:
                raise ValueError(f"guidance: {name!r} takes {sorted(known) or 'no parameters'}, got {unknown}")
            return cls(**params)
    raise ValueError(f"guidance: must be one of {GUIDANCE_RULES}, TwinPrior(), TwinIterations(...) or a "
                     f"table of one of them, e.g. {{'iterations': {{'eta1': 3.0}}}}, got {value!r}")


#: ``GuidedBO``'s former keywords of the twin iterations, now :class:`TwinIterations`'s.
_FORMER_KEYWORDS = tuple(f.name for f in fields(TwinIterations))


def from_former_keywords(guidance, keywords: dict) -> TwinPrior | TwinIterations:
    """The guidance of ``GuidedBO(guidance=..., **keywords)``, with a ``FutureWarning`` for the former keywords.

    ``GuidedBO(guidance="iterations", eta1=2)`` is ``guidance=TwinIterations(eta1=2)``. Beside
    ``guidance="prior"`` the former keywords are checked and, as before, have no effect.

    Raises
    ------
    TypeError
        A keyword that is none of :class:`TwinIterations`'s fields.
    ValueError
        The keywords beside a guidance object, or a value :class:`TwinIterations` rejects.
    """
    unknown = [name for name in keywords if name not in _FORMER_KEYWORDS]
    if unknown:
        raise TypeError(f"GuidedBO.__init__() got an unexpected keyword argument {unknown[0]!r}")
    named = as_guidance(guidance)
    if not keywords:
        return named
    iterations = TwinIterations(**keywords)  # checked in either case, as the keywords were
    given = ", ".join(f"{name}={value!r}" for name, value in keywords.items())
    if not isinstance(guidance, str):
        raise ValueError(f"{', '.join(keywords)}: give them in the guidance, TwinIterations({given}, ...), not "
                         f"beside guidance={guidance!r}")
    if isinstance(named, TwinPrior):
        warnings.warn(f"GuidedBO({given}) is deprecated: these keywords belong to the twin iterations and have no "
                      f"effect with guidance='prior'; for twin iterations write guidance=TwinIterations({given})",
                      FutureWarning, stacklevel=3)
        return named
    table = ", ".join(f"{name} = {_toml(value)}" for name, value in keywords.items())
    warnings.warn(f"GuidedBO(guidance='iterations', {given}) is deprecated: write guidance=TwinIterations({given}) "
                  f"(in a study file: guidance = {{iterations = {{{table}}}}})", FutureWarning, stacklevel=3)
    return iterations


def _toml(value) -> str:
    """``value`` as a TOML value (for the deprecation message)."""
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, float) and not np.isfinite(value):
        return "inf" if value > 0 else "-inf"
    return repr(value)
