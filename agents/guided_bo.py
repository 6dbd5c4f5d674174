"""Guided Bayesian optimization: the paper's Algorithm 1, BO guided by a digital twin.

Every plant experiment already records ``u`` and ``y``; guided BO keeps a
digital twin identified from those records (:mod:`agents.twin`) and, when the
GP is uncertain at its next query, lets the twin do the exploring: BO runs on
the twin until expected improvement dries up, and only the best point found
goes to the real plant.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from agents.bo import BayesianOptimization
from agents.parameters import HasMethods, Interval, Options, validate_params
from gbo_envs import METRIC_NAMES

__all__ = ["GuidedBO", "ACTIVATION_RULES", "MIN_TWIN_ITERATIONS", "TWIN_REFIT_EVERY"]

#: How the twin is switched on: the paper's uncertainty test eq. (DT_activation), or every
#: ``period`` plant experiments for ``n_ei`` twin iterations (the twin-fidelity study, Sec. V-A).
ACTIVATION_RULES = ("uncertainty", "periodic")

#: Twin iterations per activation before eq. (DT_stop_a) may stop them.
MIN_TWIN_ITERATIONS = 10

#: The GP hyperparameters are re-fitted (warm-started) on every this-many-th twin iteration;
#: the iterations in between only re-condition the GP on the new point.
TWIN_REFIT_EVERY = 5


class GuidedBO(BayesianOptimization):
    r"""Guided BO, Algorithm 1 of the paper, on top of :class:`~agents.bo.BayesianOptimization`.

    Every ``ask`` after the initial design:

    1. fit the GP on the plant data ``D`` and find ``theta+ = argmax a_EI`` (eq. (EI));
    2. activate the twin if ``sqrt(v_n(theta+)) > eta1 sigma_eps`` (eq. (eta1)) and
       ``e_RMSE < eta2`` (eq. (DT_rmse1));
    3. while active: evaluate the twin at ``theta+``, add ``(theta+, J^_twin(theta+))``
       to ``D`` (line D_in_DT), refit, propose again; stop when for ``n_ei`` consecutive
       twin iterations ``a_EI,i <= eta3 max_j a_EI,j`` (eq. (DT_stop_a)) or after
       ``max_twin_iterations`` (eq. (DT_stop_b));
    4. query the plant at the best point of ``D`` (line theta_plus), then remove the
       twin data from ``D`` (line remove_DT_data).

    Choices where the paper leaves room (their measured effect on DCMotor-v0 is in
    benchmarks/README.md):

    * the maximum in eq. (DT_stop_a) runs over every EI realised since the
      activation (the paper's text: "the maximal expected improvement realized so
      far");
    * at least :data:`MIN_TWIN_ITERATIONS` (10) twin iterations per activation and at
      most ``max_twin_iterations`` (20): with the bare stopping rule the twin search
      stopped early, its best point was often worse than the plant incumbent and
      guided BO stalled;
    * the twin's costs enter ``D`` without the artificial noise ``eps ~ N(0, sigma_eps^2)``
      the paper adds (``J~ = J^ + eps``): the twin is a deterministic simulation and,
      with ``sigma_eps`` comparable to the gap to the optimum, noisy twin costs hide the
      thin optimal strip from the GP;
    * "the best point of ``D``" (line theta_plus) is the twin point of this activation
      with the lowest noise-free twin cost, so every plant experiment tests a new point
      the twin rates best instead of re-measuring the plant incumbent;
    * during twin iterations EI uses the posterior-mean incumbent (the plant data in
      ``D`` stay noisy) and its grid maximiser is refined by L-BFGS-B, and the GP
      hyperparameters are re-fitted by marginal likelihood (Algorithm 1, line 12,
      warm-started) on every :data:`TWIN_REFIT_EVERY`-th twin iteration; the others only
      re-condition the GP (speed).

    Every ``tell``: predict the experiment's cost with the last fitted twin, add
    the record to the twin data set ``D~`` (eq. (Ds)), and re-initialise ``D~``
    with this record alone when ``|J - J~| / J > delta`` (eq. (reinit_DTdataset)).
    The twin is refitted on ``D~`` when an activation is due (Algorithm 1,
    "Update DT plant model"), warm-started from its previous fit.

    Parameters
    ----------
    n_initial : int, default 1
        Size ``N0`` of the Latin hypercube initial set (see :class:`~agents.bo.BayesianOptimization`).
    grid_points : int, default 100
        Grid points per gain for maximising EI (see :class:`~agents.bo.BayesianOptimization`).
    noise_std : float, optional
        ``sigma_eps``, cost units; also the GP's fixed noise. Default: the plant env's
        declared cost noise (``cost_noise_std``), which stands for the paper's prior
        measurement of five repeated experiments (:func:`agents.cost_noise.estimate_noise`
        measures it on a real plant); if the env declares none (or zero), 1 % of the mean
        measured cost. (The GP then learns its noise.)
    eta1 : float, default 3.0
        Activation threshold of eq. (eta1), in units of ``sigma_eps``: the twin is
        used when the GP's posterior std at the next query exceeds
        ``eta1 * sigma_eps``. (The paper states ``eta1 = 3`` without a unit; tying
        it to the noise level makes the same value work on every plant.)
    eta2 : float, optional
        Twin RMSE threshold of eq. (DT_rmse1) for the twin's ``rmse_`` (normalised
        by the step height); default ``3 sigma_eps`` as in the paper.
    eta3 : float, default 0.2
        Stopping threshold of eq. (DT_stop_a); ``inf`` runs exactly ``n_ei`` iterations.
    n_ei : int, default 3
        ``n~_EI`` of eq. (DT_stop_a).
    delta : float, default 2.0
        Re-initialisation threshold ``delta~`` of eq. (reinit_DTdataset).
    max_twin_iterations : int, default 20
        Cap of eq. (DT_stop_b) on twin iterations per activation.
    n_samples : int, default 100
        Samples per experiment kept for identification, the paper's ``n~`` of eq. (Ds);
        ``None`` keeps every sample.
    activation : {"uncertainty", "periodic"}, default "uncertainty"
        ``"periodic"`` activates the twin every ``period`` plant experiments for
        exactly ``n_ei`` iterations, subject only to ``eta2`` (Sec. V-A).
    period : int, default 1
        ``N_G`` of the periodic rule.
    twin_poles : int, default 2
        Poles of the identified transfer function, which has no zeros (the paper's
        high-fidelity twin has 2 poles, the low-fidelity one 5).
    twin : LinearTwin or GreyBoxTwin, optional
        A configured (unfitted) estimator to clone instead of the default
        SRIVC twin, e.g. one with physical effects.

    Attributes
    ----------
    activations_ : int
        How often the twin was switched on.
    twin_evaluations_ : int
        Twin experiments made.
    reinitializations_ : int
        How often eq. (reinit_DTdataset) emptied the twin data set.
    twin_ : LinearTwin, GreyBoxTwin or None
        The current fitted twin.
    model : str
        Always ``"cost"``: one GP on the cost, as in the paper's Algorithm 1 (the twin's
        points enter ``D`` as costs, line D_in_DT).
    """

    name = "guided-bo"

    _parameter_constraints: dict[str, list] = {
        **BayesianOptimization._parameter_constraints,
        "eta1": [Interval(float, 0.0, None)],
        "eta2": [None, Interval(float, 0.0, None, closed="neither")],
        "eta3": [Interval(float, 0.0, None)],
        "n_ei": [Interval(int, 1, None)],
        "delta": [Interval(float, 0.0, None)],
        "max_twin_iterations": [Interval(int, 1, None)],
        "n_samples": [None, Interval(int, 10, None)],
        "activation": [Options(ACTIVATION_RULES)],
        "period": [Interval(int, 1, None)],
        "twin_poles": [Interval(int, 1, None)],
        "twin": [None, HasMethods(("fit", "get_params"))],
    }

    def __init__(self, *, n_initial: int = 1, grid_points: int = 100, noise_std: float | None = None,
                 eta1: float = 3.0, eta2: float | None = None, eta3: float = 0.2, n_ei: int = 3,
                 delta: float = 2.0, max_twin_iterations: int = 20, n_samples: int | None = 100,
                 activation: str = "uncertainty", period: int = 1, twin_poles: int = 2, twin=None) -> None:
        # one GP on the cost: the twin's points enter D as costs (Algorithm 1, line D_in_DT)
        super().__init__(n_initial=n_initial, grid_points=grid_points, noise_std=noise_std, model="cost")
        params = validate_params(self._parameter_constraints, {
            "eta1": eta1, "eta2": eta2, "eta3": eta3, "n_ei": n_ei, "delta": delta,
            "max_twin_iterations": max_twin_iterations, "n_samples": n_samples, "activation": activation,
            "period": period, "twin_poles": twin_poles, "twin": twin})
        self.eta1, self.eta2, self.eta3 = params["eta1"], params["eta2"], params["eta3"]
        self.n_ei, self.delta = params["n_ei"], params["delta"]
        self.max_twin_iterations = params["max_twin_iterations"]
        self.n_samples = params["n_samples"]
        self.activation, self.period = params["activation"], params["period"]
        self.twin_poles = params["twin_poles"]
        self.twin_template = twin
        self._params = {"n_initial": self.n_initial, "grid_points": self.grid_points, "noise_std": self.noise_std,
                        **{name: value for name, value in params.items() if name != "twin"}}

    # -- Tuner hooks ---------------------------------------------------------------------------------
    def _setup(self) -> None:
        super()._setup()
        plant_env = getattr(self.env, "unwrapped", None)
        if plant_env is None or not hasattr(plant_env, "loop"):
            raise ValueError("env: guided BO needs the plant env (with its closed loop) to simulate a twin; "
                             "use run(env, ...) or setup(space, seed, env=env)")
        self._plant_env = plant_env
        self._twin_records: list[dict] = []
        self._twin_fitted_on = 0  # records in D~ when the twin was last fitted
        self._twin_dirty = False
        self.twin_ = None
        self._twin_env = None
        self.activations_ = 0
        self.twin_evaluations_ = 0
        self.reinitializations_ = 0
        # periodic rule (Sec. V-A): the twin is used right after the initial data, then every N_G experiments
        self._since_activation = self.period

    def _ask(self) -> np.ndarray:
        if self.n_observations < self.n_initial:
            return super()._ask()
        gains, ei, std = self.propose()
        self.last_ei_, self.last_std_ = ei, std
        if self._activate(std):
            gains = self._explore_on_twin(gains, ei)
        self._since_activation += 1
        self.last_mean_ = float(self.posterior(gains[None, :])[0][0])
        return gains

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        super()._tell(gains, cost, record)
        if record is None or not all(key in record for key in ("t", "r", "u", "y")):
            return
        new = {key: np.asarray(record[key], dtype=float) for key in ("t", "r", "u", "y")}
        if self._twin_env is not None:
            # eq. (reinit_DTdataset): the last fitted twin's estimate of this experiment against the
            # measurement (Algorithm 1 refits the twin only when it is activated)
            predicted = float(self._twin_env.evaluate(gains[None, :])[1][0])
            if abs(cost - predicted) / max(abs(cost), 1e-12) > self.delta:
                self._twin_records = []
                self._twin_fitted_on = 0
                self.reinitializations_ += 1
        self._twin_records.append(new)  # eq. (Ds): D~ <- D~ u {(u_i, y_i)}
        self._twin_dirty = True

    def run_summary(self) -> dict[str, Any]:
        summary = super().run_summary()
        summary.update({"activations": self.activations_, "twin_evaluations": self.twin_evaluations_,
                        "reinitializations": self.reinitializations_,
                        "twin_rmse": self.twin_.rmse_ if self.twin_ is not None else None,
                        "twin_params": None if self.twin_ is None else [float(p) for p in self.twin_.params_]})
        return summary

    # -- Algorithm 1 ---------------------------------------------------------------------------------
    @property
    def sigma_eps(self) -> float:
        """Cost noise std ``sigma_eps`` used by eqs. (eta1) and (DT_rmse1)."""
        if self.noise_std is not None:
            return float(self.noise_std)
        declared = float(getattr(self._plant_env, "cost_noise_std", 0.0) or 0.0)
        if declared > 0.0:
            return declared
        _, y = self.training_set()
        return 0.01 * float(np.mean(np.abs(y))) if y.size else 0.01

    @property
    def eta2_value(self) -> float:
        """RMSE threshold of eq. (DT_rmse1): ``eta2`` or ``3 sigma_eps``."""
        return float(self.eta2) if self.eta2 is not None else 3.0 * self.sigma_eps

    def _activate(self, std: float) -> bool:
        """Twin activation test, eq. (DT_activation) (or the periodic rule)."""
        if self.activation == "periodic":
            due = self._since_activation >= self.period
        else:
            due = std > self.eta1 * self.sigma_eps  # eq. (eta1)
        if not due:
            return False
        twin = self._current_twin()
        return twin is not None and twin.rmse_ < self.eta2_value  # eq. (DT_rmse1)

    def _explore_on_twin(self, gains: np.ndarray, ei: float) -> np.ndarray:
        """BO iterations on the twin until eq. (DT_stop) holds; returns the best point of ``D``."""
        self.activations_ += 1
        self._since_activation = 0
        twin_env = self._current_twin_env()
        periodic = self.activation == "periodic"
        cap = self.n_ei if periodic else self.max_twin_iterations
        saved = self.incumbent_rule, self.polish
        # twin iterations: posterior-mean incumbent (the plant data in D are noisy), polished EI maximiser
        self.incumbent_rule, self.polish = "posterior_mean", True
        try:
            best = self._twin_iterations(twin_env, gains, ei, cap, periodic)
        finally:
            self._optimize_hyperparameters = True
            self.incumbent_rule, self.polish = saved
        self.remove_data("twin")  # line remove_DT_data
        return best

    def _twin_iterations(self, twin_env, gains: np.ndarray, ei: float, cap: int, periodic: bool) -> np.ndarray:
        """Lines 9-16 of Algorithm 1; returns the best point of ``D`` (line theta_plus)."""
        eis, calm = [ei], 0
        twin_X, twin_J = [], []
        for iteration in range(1, cap + 1):
            metrics, clean = twin_env.evaluate(gains[None, :])
            twin_X.append(gains.copy())
            twin_J.append(float(clean[0]))
            self.add_data(gains, float(clean[0]), source="twin")  # line D_in_DT, without the paper's eps
            self.log_twin(gains, float(clean[0]), dict(zip(METRIC_NAMES, metrics[0])), activation=self.activations_,
                          twin_iteration=iteration, twin_true_cost=float(clean[0]))
            self.twin_evaluations_ += 1
            # Algorithm 1, line 12: hyperparameters re-fitted on every TWIN_REFIT_EVERY-th twin iteration
            self._optimize_hyperparameters = (iteration - 1) % TWIN_REFIT_EVERY == 0
            gains, ei, _ = self.propose()
            if not periodic:
                # eq. (DT_stop_a), against the largest EI realised since the activation
                calm = calm + 1 if ei <= self.eta3 * max(eis) else 0
                eis.append(ei)
                if calm >= self.n_ei and iteration >= MIN_TWIN_ITERATIONS:
                    break
        # line theta_plus: the twin point of this activation with the lowest noise-free twin cost
        return twin_X[int(np.argmin(twin_J))]

    def _current_twin(self):
        """The twin fitted on ``D~``, refitted only when it mispredicts records added since its last fit.

        Refitting SRIVC costs far more than a BO iteration; a twin that already
        simulates the new records within ``max(1.5 rmse_, eta2 / 4)`` (normalised
        RMSE) has nothing to learn from them, so it is kept (Algorithm 1 refits at
        every activation; the result is the same up to that tolerance).
        """
        if self._twin_dirty and self.twin_ is not None and self._twin_fitted_on <= len(self._twin_records):
            new = self._twin_records[self._twin_fitted_on:]
            if not new or -self.twin_.score(new) <= max(1.5 * self.twin_.rmse_, 0.25 * self.eta2_value):
                self._twin_dirty = False
        if self._twin_dirty and self._twin_records:
            from sklearn.base import clone

            template = self.twin_template if self.twin_template is not None else self._default_twin()
            twin = self.twin_ if self.twin_ is not None else clone(template)  # warm start from the last fit
            try:
                self.twin_ = twin.fit(self._twin_records)
            except (ValueError, np.linalg.LinAlgError):
                self.twin_ = None  # too little excitation to identify: no twin this time
            self._twin_env = None
            self._twin_dirty = False
            self._twin_fitted_on = len(self._twin_records)
        return self.twin_

    def _current_twin_env(self):
        twin = self._current_twin()
        if twin is None:
            return None
        if self._twin_env is None:
            from agents.twin import make_twin_env

            self._twin_env = make_twin_env(self._plant_env, twin)
        return self._twin_env

    def _default_twin(self):
        from agents.twin import LinearTwin

        plant = self._plant_env.loop.plant
        integrators = len(plant.den) - len(np.trim_zeros(np.asarray(plant.den), "b"))
        return LinearTwin(n_poles=self.twin_poles, n_zeros=0,
                          n_integrators=min(integrators, self.twin_poles - 1), n_samples=self.n_samples,
                          output=plant.output, warm_start=True)



