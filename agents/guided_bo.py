"""Guided Bayesian optimization: BO guided by a digital twin (the paper's Algorithm 1 and a prior-mean form).

Every plant experiment already records ``u`` and ``y``; guided BO keeps a
digital twin identified from those records (:mod:`agents.twin`). By default
the twin's performance metrics are the prior mean of the default BO's metric
GPs, which then learn only the plant's discrepancy from the twin
(:mod:`agents.twin.prior`). ``guidance="iterations"`` is the paper's
Algorithm 1: when the GP is uncertain at its next query, BO runs on the twin
until expected improvement dries up, and only the best point found goes to
the real plant.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import fields
from typing import Any

import numpy as np

from agents.bo import BayesianOptimization
from agents.guidance import ACTIVATION_RULES, GUIDANCE_RULES, TwinIterations, TwinPrior, as_guidance
from agents.parameters import HasMethods, Interval, Options, validate_params
from agents.thread_limits import single_thread
from gbo_envs import METRIC_NAMES

__all__ = ["GuidedBO", "ACTIVATION_RULES", "GUIDANCE_RULES", "MIN_TWIN_ITERATIONS", "TWIN_CHOICES",
           "TWIN_REFIT_EVERY", "TwinIterations", "TwinPrior"]

#: Twin iterations per activation before eq. (DT_stop_a) may stop them.
MIN_TWIN_ITERATIONS = 10

#: The GP hyperparameters are re-fitted (warm-started) on every this-many-th twin iteration;
#: the iterations in between only re-condition the GP on the new point.
TWIN_REFIT_EVERY = 5

#: ``twin`` by name: the workbench-diagnosed grey-box twin, or the paper's linear SRIVC twin.
TWIN_CHOICES = ("auto", "linear")

#: Effects at most in a diagnosed twin (the workbench's ladder, two rungs).
MAX_TWIN_EFFECTS = 2

#: Records in ``D~`` beyond which the effects are settled: no further diagnosis, only warm refits.
MAX_DIAGNOSED_RECORDS = 8

#: Records since the last one a twin explained, at least, that must agree on another plant before ``D~``
#: is re-initialised with them (a plant change read on the responses, see "Plant changes").
PLANT_CHANGE_RECORDS = 2

#: Noise draws ``K`` of the twin's expected cost (:class:`agents.twin.TwinEnv`).
TWIN_NOISE_DRAWS = 8

#: The twin reproduces the measurement noise when its floor exceeds this fraction of the step height.
SIMULATED_NOISE_FLOOR = 1e-4

#: Lower bound of the noise floor in eq. (DT_rmse1), as a fraction of the step height: with
#: ``eta2 = 3`` a plant quieter than this gets the paper's absolute threshold 0.003.
RMSE_FLOOR = 1e-3


class GuidedBO(BayesianOptimization):
    r"""Guided BO on top of :class:`~agents.bo.BayesianOptimization`: the twin as prior mean, or Algorithm 1.

    **guidance="prior"** (the default). The surrogate is the default BO's: one GP per
    performance metric, combined into the posterior of ``J_hat = sum_i w_i f_i / n_i``
    (eq. (J_used), :mod:`agents.metric_surrogate`). While a twin may guide (its
    ``e_RMSE < eta2``, eq. (DT_rmse1)), the prior mean of metric ``i``'s
    GP is the twin's metric ``f~_i(theta)`` (:class:`agents.twin.prior.TwinMetrics`), so
    the GP models the discrepancy ``T_i(f_i) - T_i(f~_i)`` (``T_i``: ``f / n_i``, or its
    log) and the posterior mean is ``T_i(f~_i(theta)) + mu_d(theta)``. Every ``ask``
    queries the maximiser of EI (eq. (EI)) on that posterior. A right twin makes the
    discrepancy flat, and EI goes straight to the twin's optimum; a wrong twin is
    corrected where the plant has been measured. Two rules keep a slightly wrong twin
    from holding BO at its optimum: where EI with the prior proposes gains already
    measured, the experiment is the default BO's proposal (EI without the prior); and a
    plant cost more than ``3 sigma_eps`` off the twin's prediction refits the twin once
    the records have doubled since its fit (the RMSE test below misses a twin whose
    response is close but whose thin optimal valley sits a grid cell away). The twin is
    simulated once per grid point and fitted twin (10^4 simulations, cached; a noisy twin's
    noise draws only near its expected optimum, see :class:`~agents.twin.prior.TwinMetrics`).
    Otherwise the metric GPs have their constant prior mean and guided BO is the default BO. A diverging plant
    experiment enters with the metrics of ``J = unstable_cost``.
    Which choice buys what is measured in the study guided_bo_ablation (``gbo bench guided_bo_ablation``).

    **guidance="iterations"**, Algorithm 1 of the paper, on one GP on the cost
    (the twin's points enter ``D`` as costs). Every ``ask`` after the initial design:

    1. fit the GP on the plant data ``D`` and find ``theta+ = argmax a_EI`` (eq. (EI));
    2. activate the twin if ``sqrt(v_n(theta+)) > eta1 sigma_eps`` (eq. (eta1)),
       ``e_RMSE < eta2`` (eq. (DT_rmse1)) and the twin is trusted (below);
    3. while active: evaluate the twin at ``theta+``, add ``(theta+, J^_twin(theta+))``
       to ``D`` (line D_in_DT), refit, propose again; stop when for ``n_ei`` consecutive
       twin iterations ``a_EI,i <= eta3 max_j a_EI,j`` (eq. (DT_stop_a)) or after
       ``max_twin_iterations`` (eq. (DT_stop_b));
    4. query the plant at the best point of ``D`` (line theta_plus), then remove the
       twin data from ``D`` (line remove_DT_data).

    **Which twin.** ``twin="auto"`` (the default) starts from the paper's linear
    SRIVC twin and adds what the records evidence. The twin is fitted when the first
    twin is needed after the initial design, and refitted whenever it mispredicts a
    new plant experiment: its normalised RMSE on the new record exceeds
    ``max(1.5 rmse_, 2 max(s, 10^-3))``, 1.5 times its own fit error or twice the
    noise floor ``s`` (below; ``10^-3`` of the step height on a quiet plant). A refit
    keeps the twin's structure and starts from its previous values (warm start). If
    the refitted twin's own RMSE is beyond what the noise explains,
    ``2 max(s, 10^-3)``, the records are diagnosed with the workbench's decision rule
    (:func:`agents.twin.selection.diagnosed_twin`, the error ladder of ``gbo twin
    diagnose``), and the twin becomes the linear model plus every effect they
    evidence, at most two, as a :class:`~agents.twin.GreyBoxTwin`, if that fits
    better. For a position output a grey-box twin's RMSE is that of the increments of
    its error (:func:`agents.twin.least_squares.output_error`): a replayed slider that sticks
    a moment off the plant's stays off in open loop, not in the twin's closed loop.
    A twin with effects is kept only while its closed loop predicts the costs
    measured at the recorded gains better than the linear twin's does (RMS relative
    error ``sqrt(mean_i ((J~(theta_i) - J_i) / J_i)^2)``): the fit replays the recorded
    inputs, and effects that replay them well can still mispredict the closed loop
    (on LinearMotorRig-v0 a stiction twin replayed four records within 0.4 % of the step
    and predicted three times the measured costs). The linear twin is refitted from its
    previous fit (warm start). Each diagnosis starts from the linear model, not from the current effects
    (the ladder only adds effects), so an effect that fewer records evidenced is
    dropped when more records show another. A diagnosis is repeated only when the records have doubled since the
    last one, up to :data:`MAX_DIAGNOSED_RECORDS` (1, 2, 4, 8 records); after that the
    effects are settled and the twin is only refitted.
    ``twin="linear"`` is the paper's Algorithm 1 unchanged: the SRIVC
    transfer function of ``twin_poles`` poles, noise-free, ``eta2 = 3 sigma_eps``
    by default, always trusted. A :class:`~agents.twin.LinearTwin` or
    :class:`~agents.twin.GreyBoxTwin` (or any estimator with ``fit`` and
    ``plant_``) may be passed instead: unfitted, it is fitted on the records as
    above; fitted, it is used as given until it mispredicts, then refitted.

    **Noise.** With ``"auto"`` or a given twin, the twin reproduces the plant's
    measurement noise: ``s``, the median noise floor of the plant records
    (:func:`agents.twin.noise_floor.noise_floor`, normalised by the step height
    ``|r2 - r1|``), is added as white output noise and the twin's cost is the
    expectation over :data:`TWIN_NOISE_DRAWS` fixed draws, as the plant's ground
    truth is (when ``s`` exceeds :data:`SIMULATED_NOISE_FLOOR`). The activation
    threshold is relative to it: ``eta2 = 3 max(s, 10^-3)`` by default, so a twin
    as good as the noise allows is used on any plant, and on a quiet plant the
    threshold is the paper's 0.003.

    **Trust** (``guidance="iterations"``; with the prior, the discrepancy GPs correct the
    twin instead). After a plant experiment at a twin-proposed point ``theta_T``, the
    improvement the twin promised over the plant incumbent ``theta_I`` (lowest
    measured cost), ``J^(theta_I) - J^(theta_T)``, is compared with the one measured,
    ``mu(theta_I) - J(theta_T)`` (``mu``: the GP's posterior mean on the plant data; the
    lowest measurement itself is biased low by the noise). If the plant delivers less than
    promised and less than nothing, ``delivered < min(promised, 0) - 2 sqrt(2) sigma_eps``
    (two standard deviations of a difference of two measurements): the twin's point is
    worse than the incumbent and than predicted, beyond the noise. Such a twin
    is not used again until it has been refitted and either no longer promises that
    improvement or was refitted on twice the records it had when it lost trust
    (so a wrong twin costs at most one experiment per doubling of the records);
    meanwhile guided BO is BO.

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
      with the lowest twin cost, so every plant experiment tests a new point
      the twin rates best instead of re-measuring the plant incumbent;
    * during twin iterations EI uses the posterior-mean incumbent (the plant data in
      ``D`` stay noisy) and its grid maximiser is refined by L-BFGS-B, and the GP
      hyperparameters are re-fitted by marginal likelihood (Algorithm 1, line 12,
      warm-started) on every :data:`TWIN_REFIT_EVERY`-th twin iteration; the others only
      re-condition the GP (speed).

    Every ``tell``: predict the experiment's cost with the last fitted twin, add
    the record to the twin data set ``D~`` (eq. (Ds)), and re-initialise ``D~``
    with this record alone when ``|J - J~| / J > delta`` (eq. (reinit_DTdataset)).
    With ``twin="auto"`` or a given twin, eq. (reinit_DTdataset) reads such a miss as a
    plant change only if the twin simulated its own records within the noise
    (``rmse_ <= 2 max(s, 10^-3)``) and was fitted on at least :data:`PLANT_CHANGE_RECORDS`
    of them; a twin that did not was wrong before the plant moved, so its records are
    kept and the miss calls for a refit on all of them (a reset would throw away the
    records that show the twin's error and re-diagnose from one). One record fits any
    structure: on DCMotor-v0 with a 150-unit drive limit and Coulomb friction of 20, the
    linear twin of one record missed the next cost by more than ``delta`` and reset ``D~``
    up to 7 times per run, so the twin never saw two records and never learnt the effects.
    An unstable experiment's record is not added (a diverging response identifies
    nothing). The twin is refitted on ``D~`` when an activation is due (Algorithm 1,
    "Update DT plant model").

    **Plant changes** (``twin="auto"`` or a given twin). The paper's ``delta = 2`` reads only
    a cost miss of 200 % as a change; a load that adds 25 % inertia (DCMotorStep-v0) changes
    the cost by at most 55 % and moves the optimum by 24 grid cells. Such a change shows in
    the responses: let ``m`` be the records of ``D~`` that a twin simulated within the noise
    (it was fitted on them, or predicted them without a refit, with ``rmse_ <= 2 max(s,
    10^-3)``). When the twin refitted on all of ``D~`` no longer simulates them within the
    noise, and a twin of the same structure fitted on the records after the ``m``-th alone (at least
    :data:`PLANT_CHANGE_RECORDS`) does, the records are explained by two plants and not by
    one: ``D~`` is re-initialised with the later records (counted in ``reinitializations_``)
    and that twin is used. A plant that drifts is followed the same way, one re-initialisation
    whenever its drift exceeds the noise.

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
    eta2 : float, optional
        Twin RMSE threshold of eq. (DT_rmse1) for the twin's ``rmse_`` (normalised
        by the step height, dimensionless): the twin guides only while ``rmse_ < eta2``.
        Default: ``3 max(s, 10^-3)`` with ``s`` the normalised noise floor of the records;
        with ``twin="linear"``, ``3 sigma_eps`` as in the paper. Used by both guidances
        (it gates the prior as it gates the iterations), so it is the tuner's, not the guidance's.
    delta : float, default 2.0
        Re-initialisation threshold ``delta~`` of eq. (reinit_DTdataset), a relative cost
        error (dimensionless): ``D~`` restarts when ``|J - J~| / J > delta``. Used by both
        guidances (the twin data set is the same), so it is the tuner's.
    n_samples : int, default 100
        Samples per experiment kept for identification, the paper's ``n~`` of eq. (Ds);
        ``None`` keeps every sample. Records whose command moves within the hold
        intervals (a near bang-bang move) keep more, or all
        (:func:`agents.twin.records.decimate_records`). The twin's, in both guidances.
    twin_poles : int, default 2
        Poles of the twin's transfer function, which has no zeros (the paper's
        high-fidelity twin has 2 poles, the low-fidelity one 5).
    twin : {"auto", "linear"} or estimator, default "auto"
        The digital twin, see "Which twin" above.
    guidance : TwinPrior, TwinIterations, str or dict, default "prior"
        How the twin guides BO (see above), as an object of :mod:`agents.guidance`:
        :class:`~agents.guidance.TwinPrior` (the twin as prior mean of the metric GPs)
        or :class:`~agents.guidance.TwinIterations` (the paper's twin iterations on the
        cost GP, Algorithm 1, with ``eta1``, ``eta3``, ``n_ei``, ``max_twin_iterations``,
        ``activation`` and ``period``). A name, ``"prior"`` or ``"iterations"``, stands
        for its defaults; ``{"iterations": {"eta1": 2.0}}`` for its parameters (the
        form of a study file, ``guidance = {iterations = {eta1 = 2.0}}``).
    **deprecated
        ``eta1``, ``eta3``, ``n_ei``, ``max_twin_iterations``, ``activation``, ``period``:
        the former spelling of :class:`~agents.guidance.TwinIterations`'s parameters,
        accepted for one release with a ``FutureWarning`` (beside ``guidance="prior"``
        they had, and have, no effect).

    Attributes
    ----------
    activations_ : int
        How often the twin was switched on (``guidance="prior"``: plant queries proposed with the twin prior).
    twin_evaluations_ : int
        Twin experiments made (with ``guidance="prior"``, by twins replaced so far; ``run_summary``
        counts the current twin's too).
    reinitializations_ : int
        How often the twin data set was re-initialised: by eq. (reinit_DTdataset), or on a plant
        change read on the responses (see "Plant changes").
    distrusts_ : int
        How often a twin-proposed experiment disappointed and the twin lost trust.
    repeats_ : int
        ``guidance="prior"``: how often the twin prior proposed gains already measured and the
        default BO's proposal was taken instead.
    twin_ : LinearTwin, GreyBoxTwin or None
        The current fitted twin.
    twin_changes_ : list of dict
        One entry per twin fit: ``experiment`` (plant experiments told), ``effects``,
        ``params``, ``rmse`` (normalised, on ``D~``), ``previous_rmse`` (the former twin on
        the new records, ``None`` for the first) and ``text`` (one line, as ``gbo tune`` prints it).
    noise_floor_ : float
        ``s``: the median normalised noise floor of the plant records.
    model : str
        ``"metrics"`` with ``guidance="prior"``; ``"cost"`` with ``"iterations"``: one GP on the
        cost, as in the paper's Algorithm 1 (the twin's points enter ``D`` as costs, line D_in_DT).
    """

    name = "guided-bo"

    _parameter_constraints: dict[str, list] = {
        **BayesianOptimization._parameter_constraints,
        "eta2": [None, Interval(float, 0.0, None, closed="neither")],
        "delta": [Interval(float, 0.0, None)],
        "n_samples": [None, Interval(int, 10, None)],
        "twin_poles": [Interval(int, 1, None)],
        "twin": [Options(TWIN_CHOICES), HasMethods(("fit", "get_params"))],
    }

    def __init__(self, *, n_initial: int = 1, grid_points: int = 100, noise_std: float | None = None,
                 eta2: float | None = None, delta: float = 2.0, n_samples: int | None = 100, twin_poles: int = 2,
                 twin="auto", guidance: TwinPrior | TwinIterations | str | dict = "prior", **deprecated) -> None:
        guidance = _guidance(guidance, deprecated)
        # iterations: one GP on the cost, the twin's points enter D as costs (Algorithm 1, line D_in_DT);
        # prior: the default BO's metric GPs, with the twin's metrics as their prior mean
        super().__init__(n_initial=n_initial, grid_points=grid_points, noise_std=noise_std, model=guidance.model)
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

    # -- Tuner hooks ---------------------------------------------------------------------------------
    def _setup(self) -> None:
        super()._setup()
        plant_env = getattr(self.env, "unwrapped", None)
        if plant_env is None or not hasattr(plant_env, "loop"):
            raise ValueError("env: guided BO needs the plant env (with its closed loop) to simulate a twin; "
                             "use run(env, ...) or setup(space, seed, env=env)")
        self._plant_env = plant_env
        self._step_height = abs(float(plant_env.loop.r2) - float(plant_env.loop.r1)) or 1.0
        self._twin_records: list[dict] = []
        self._twin_costs: list[tuple[np.ndarray, float]] = []  # (gains, measured cost) of each record in D~
        self._twin_fitted_on = 0  # records in D~ when the twin was last fitted
        self._twin_dirty = False
        self._cost_missed = False  # a plant cost since the last fit was off the twin's by > 3 sigma_eps
        self._diagnosed_on = 0  # records in D~ at the last diagnosis (twin="auto")
        self._explained_upto = 0  # the first records of D~ that a twin simulated within the noise
        self._noise_floors: list[float] = []
        self._promise = None  # (theta_T, theta_I, mu(theta_I), promised improvement) of the last twin proposal
        self._broken = None  # (theta_T, theta_I, delivered improvement, records) of the promise that failed
        self.twin_ = None
        self._linear = None  # the SRIVC twin of twin="auto", refitted in place (warm start)
        self._twin_env = None
        if not isinstance(self.twin, str) and hasattr(self.twin, "plant_"):
            self.twin_ = self.twin  # a fitted twin: used as given until it mispredicts
        self.activations_ = 0
        self.twin_evaluations_ = 0
        self.reinitializations_ = 0
        self.distrusts_ = 0
        self.repeats_ = 0
        self.twin_changes_: list[dict] = []
        if self.twin_ is not None:
            self._record_twin_change(None)
        # periodic rule (Sec. V-A): the twin is used right after the initial data, then every N_G experiments
        self._since_activation = getattr(self.guidance, "period", 1)
        self._prior = None  # the twin's metrics while they are the metric GPs' prior mean (guidance="prior")
        self._twin_metrics = None  # the current twin's metrics (simulated gains cached)

    def _ask(self) -> np.ndarray:
        if self.n_observations < self.n_initial:
            return super()._ask()
        if isinstance(self.guidance, TwinPrior):
            return self._ask_with_twin_prior()
        with single_thread():  # small matrices, as in BayesianOptimization._ask
            gains, ei, std = self.propose()
            self.last_ei_, self.last_std_ = ei, std
            if self._activate(std):
                gains = self._explore_on_twin(gains, ei)
            self._since_activation += 1
            self.last_mean_ = float(self.posterior(gains[None, :])[0][0])
        return gains

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        super()._tell(gains, cost, record)
        if isinstance(self.guidance, TwinPrior) and record is not None and record.get("unstable", False):
            # a diverging experiment keeps the metric GPs (and the twin prior) in use: its metrics are
            # those of J = unstable_cost, as the twin's diverging points (agents.twin.prior.TwinMetrics)
            from agents.twin.prior import unstable_metrics

            self._plant_F[-1] = unstable_metrics(self._plant_env)
        self._check_promise(gains, cost)
        if record is None or record.get("unstable", False) or not all(key in record for key in ("t", "r", "u", "y")):
            return  # nothing to identify from (or a diverging response)
        new = {key: np.asarray(record[key], dtype=float) for key in ("t", "r", "u", "y")}
        if not all(np.all(np.isfinite(v)) for v in new.values()):
            return
        if self.twin != "linear":
            from agents.twin.selection import measurement_noise

            self._noise_floors.append(measurement_noise(new) / self._step_height)
        if self._twin_env is not None:
            # eq. (reinit_DTdataset): the last fitted twin's estimate of this experiment against the
            # measurement (Algorithm 1 refits the twin only when it is activated)
            predicted = float(self._twin_env.evaluate(gains[None, :])[1][0])
            missed = not np.isfinite(predicted) or abs(cost - predicted) / max(abs(cost), 1e-12) > self.delta
            if missed and not self._twin_explained_its_records():
                self._cost_missed = True  # the twin was wrong, not the plant changed: refit on every record
            elif missed:
                self._reinitialise(len(self._twin_records))
            elif isinstance(self.guidance, TwinPrior) and abs(cost - predicted) > 3.0 * self.sigma_eps:
                self._cost_missed = True  # the twin's cost is off by more than the cost noise explains
        self._twin_records.append(new)  # eq. (Ds): D~ <- D~ u {(u_i, y_i)}
        self._twin_costs.append((np.asarray(gains, dtype=float), float(cost)))
        self._twin_dirty = True

    def run_summary(self) -> dict[str, Any]:
        summary = super().run_summary()
        twin = self.twin_
        simulated = 0 if self._twin_metrics is None else self._twin_metrics.simulations_
        summary.update({"activations": self.activations_, "twin_evaluations": self.twin_evaluations_ + simulated,
                        "repeats": self.repeats_,
                        "reinitializations": self.reinitializations_, "distrusts": self.distrusts_,
                        "twin_rmse": twin.rmse_ if twin is not None else None,
                        "twin_params": None if twin is None else [float(p) for p in twin.params_],
                        "twin_effects": None if twin is None else _effect_values(twin),
                        "twin_changes": [{k: v for k, v in c.items() if k != "text"} for c in self.twin_changes_],
                        "noise_floor": self.noise_floor_})
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
    def noise_floor_(self) -> float:
        """``s``: median noise floor of the plant records over the step height (0 before any record)."""
        return float(np.median(self._noise_floors)) if self._noise_floors else 0.0

    @property
    def eta2_value(self) -> float:
        """RMSE threshold of eq. (DT_rmse1): ``eta2``, else ``3 max(s, 10^-3)`` (linear twin: ``3 sigma_eps``)."""
        if self.eta2 is not None:
            return float(self.eta2)
        if self.twin == "linear":
            return 3.0 * self.sigma_eps
        return 3.0 * max(self.noise_floor_, RMSE_FLOOR)

    @property
    def _difference_noise(self) -> float:
        """Two standard deviations of a difference of two cost measurements, ``2 sqrt(2) sigma_eps``."""
        return 2.0 * np.sqrt(2.0) * self.sigma_eps

    @property
    def trusted(self) -> bool:
        """Whether the twin may propose plant experiments (see "Trust" in the class doc)."""
        return self._broken is None

    def _ask_with_twin_prior(self) -> np.ndarray:
        """EI on the metric GPs with the twin prior; the default BO's proposal where the twin repeats itself.

        If EI with the twin prior proposes gains already measured, the twin has nothing
        new to say (plain EI would measure its optimum over and over, also where that
        optimum is slightly off the plant's): the experiment is then the default BO's
        proposal, EI on the same metric GPs without the prior.
        """
        prior = self._twin_prior()
        if prior is not self._prior:
            self._prior = prior
            self._data_changed()
        gains = super()._ask()
        if prior is None:
            return gains
        self.activations_ += 1
        unit = self.space.to_unit(gains)
        if any(np.allclose(unit, measured, rtol=0.0, atol=1e-9) for measured in self._plant_X):
            self._prior = None
            self._data_changed()
            try:
                gains = super()._ask()
            finally:
                self._prior = prior
                self._data_changed()
            self.repeats_ += 1
        return gains

    def twin_env(self):
        """The env of the current twin (:class:`agents.twin.TwinEnv`), fitted or refitted on ``D~`` if due.

        ``None`` before the first plant record, or while the records identify no twin. The
        same twin and refit rules as guided BO's own use (see "Which twin" in the class doc);
        multi-fidelity BO (:mod:`agents.mf_bo`) takes its low fidelity from here.
        """
        self._current_twin()  # a refit if the records added since the last fit call for one
        return self._current_twin_env()

    def metric_prior(self):
        """The twin's metrics (:class:`agents.twin.prior.TwinMetrics`) while they guide BO, else ``None``."""
        return self._prior

    def _twin_prior(self):
        """The current twin's metrics if the twin may guide (eq. (DT_rmse1) and trust), else ``None``."""
        twin = self._current_twin()
        if twin is None or not np.isfinite(twin.rmse_) or twin.rmse_ >= self.eta2_value or not self.trusted:
            return None
        twin_env = self._current_twin_env()
        if self._twin_metrics is None or self._twin_metrics.twin_env is not twin_env:
            from agents.twin.prior import TwinMetrics

            if self._twin_metrics is not None:
                self.twin_evaluations_ += self._twin_metrics.simulations_
            self._twin_metrics = TwinMetrics(twin_env, self.space)
        return self._twin_metrics

    def _activate(self, std: float) -> bool:
        """Twin activation test, eq. (DT_activation) (or the periodic rule), and trust."""
        iterations = self.guidance
        if iterations.activation == "periodic":
            due = self._since_activation >= iterations.period
        else:
            due = std > iterations.eta1 * self.sigma_eps  # eq. (eta1)
        if not due:
            return False
        twin = self._current_twin()
        if twin is None or not np.isfinite(twin.rmse_) or twin.rmse_ >= self.eta2_value:  # eq. (DT_rmse1)
            return False
        return self.trusted

    def _explore_on_twin(self, gains: np.ndarray, ei: float) -> np.ndarray:
        """BO iterations on the twin until eq. (DT_stop) holds; returns the best point of ``D``."""
        self.activations_ += 1
        self._since_activation = 0
        twin_env = self._current_twin_env()
        periodic = self.guidance.activation == "periodic"
        cap = self.guidance.n_ei if periodic else self.guidance.max_twin_iterations
        saved = self.incumbent_rule, self.polish
        # twin iterations: posterior-mean incumbent (the plant data in D are noisy), polished EI maximiser
        self.incumbent_rule, self.polish = "posterior_mean", True
        try:
            best, best_cost = self._twin_iterations(twin_env, gains, ei, cap, periodic)
        finally:
            self._optimize_hyperparameters = True
            self.incumbent_rule, self.polish = saved
        self.remove_data("twin")  # line remove_DT_data
        if self.twin != "linear":
            incumbent = self._plant_incumbent()
            if incumbent is not None:
                promised = self._twin_cost(twin_env, incumbent) - best_cost
                # the GP's mean at the incumbent, not its lowest measurement (biased low by the noise)
                reference = float(self.posterior(incumbent[None, :])[0][0])
                self._promise = (best.copy(), incumbent, reference, promised)
        return best

    def _twin_iterations(self, twin_env, gains: np.ndarray, ei: float, cap: int,
                         periodic: bool) -> tuple[np.ndarray, float]:
        """Lines 9-16 of Algorithm 1; returns the best point of ``D`` (line theta_plus) and its twin cost."""
        eis, calm = [ei], 0
        twin_X, twin_J = [], []
        described = self._twin_description()
        for iteration in range(1, cap + 1):
            metrics, clean = twin_env.evaluate(gains[None, :])
            cost = float(clean[0]) if np.isfinite(clean[0]) else float(twin_env.unstable_cost)
            twin_X.append(gains.copy())
            twin_J.append(cost)
            self.add_data(gains, cost, source="twin")  # line D_in_DT, without the paper's eps
            self.log_twin(gains, cost, dict(zip(METRIC_NAMES, metrics[0])), activation=self.activations_,
                          twin_iteration=iteration, twin_true_cost=cost, **described)
            self.twin_evaluations_ += 1
            # Algorithm 1, line 12: hyperparameters re-fitted on every TWIN_REFIT_EVERY-th twin iteration
            self._optimize_hyperparameters = (iteration - 1) % TWIN_REFIT_EVERY == 0
            gains, ei, _ = self.propose()
            if not periodic:
                # eq. (DT_stop_a), against the largest EI realised since the activation
                calm = calm + 1 if ei <= self.guidance.eta3 * max(eis) else 0
                eis.append(ei)
                if calm >= self.guidance.n_ei and iteration >= MIN_TWIN_ITERATIONS:
                    break
        # line theta_plus: the twin point of this activation with the lowest twin cost
        best = int(np.argmin(twin_J))
        return twin_X[best], twin_J[best]

    # -- trust -------------------------------------------------------------------------------------
    def _plant_incumbent(self) -> np.ndarray | None:
        """``theta_I``: the gains of the plant experiment with the lowest measured cost."""
        if not self._plant_y:
            return None
        return self.space.from_unit(np.asarray(self._plant_X[int(np.argmin(self._plant_y))]))

    @staticmethod
    def _twin_cost(twin_env, gains: np.ndarray) -> float:
        cost = float(twin_env.evaluate(np.asarray(gains, dtype=float)[None, :])[1][0])
        return cost if np.isfinite(cost) else float(twin_env.unstable_cost)

    def _check_promise(self, gains: np.ndarray, cost: float) -> None:
        """Compare the improvement the twin promised at ``gains`` with the one measured (see "Trust")."""
        promise, self._promise = self._promise, None
        if promise is None or not np.allclose(gains, promise[0]):
            return
        _, inc_gains, inc_cost, promised = promise
        delivered = inc_cost - float(cost)
        # worse than promised and worse than the incumbent, each beyond the noise of a difference
        if delivered < min(promised, 0.0) - self._difference_noise:
            self._broken = (promise[0], inc_gains, delivered, max(len(self._twin_records), 1))
            self.distrusts_ += 1

    def _restore_trust(self) -> None:
        """After a refit: trusted again if the new twin no longer promises the improvement that failed,
        or if it was refitted on at least twice the records it had when it lost trust."""
        if self._broken is None or self._twin_env is None:
            return
        failed, inc_gains, delivered, records = self._broken
        if len(self._twin_records) >= 2 * records:
            self._broken = None
            return
        promised = self._twin_cost(self._twin_env, inc_gains) - self._twin_cost(self._twin_env, failed)
        if promised <= delivered + self._difference_noise:
            self._broken = None

    # -- the twin ----------------------------------------------------------------------------------
    def _error_on(self, new: list[dict]) -> float | None:
        """The current twin's normalised RMSE on new records; ``None`` if it cannot simulate them."""
        try:
            return float(-self.twin_.score(new))
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            return None

    def _mispredicts(self, error: float | None) -> bool:
        """Whether the twin's RMSE on new records exceeds what noise and its own fit error explain."""
        if error is None:
            return True
        if self.twin == "linear":
            return not error <= max(1.5 * self.twin_.rmse_, 0.25 * self.eta2_value)
        return not error <= max(1.5 * self.twin_.rmse_, self._explained_rmse())

    def _twin_explained_its_records(self) -> bool:
        """Whether the current twin simulated the records it was fitted on, at least :data:`PLANT_CHANGE_RECORDS`,
        within the noise (the paper's linear twin always counts as having done so: eq. (reinit_DTdataset)
        unchanged)."""
        if self.twin == "linear" or self.twin_ is None:
            return True
        return self._twin_fitted_on >= PLANT_CHANGE_RECORDS and self.twin_.rmse_ <= self._explained_rmse()

    def _explained_rmse(self) -> float:
        """The normalised RMSE that measurement noise explains: ``2 max(s, 10^-3)``."""
        return 2.0 * max(self.noise_floor_, RMSE_FLOOR)

    def _current_twin(self):
        """The twin fitted on ``D~``, refitted only when it mispredicts records added since its last fit.

        Refitting costs far more than a BO iteration; a twin that already
        simulates the new records within the noise (see "Which twin" in the class
        doc) has nothing to learn from them, so it is kept (Algorithm 1 refits at
        every activation; the result is the same up to that tolerance).
        """
        new = self._twin_records[self._twin_fitted_on:]
        previous_rmse = None  # the current twin's error on the records added since its fit
        scored = False
        if self._twin_dirty and self.twin_ is not None:
            if not new:
                self._twin_dirty = False
            elif self.trusted:
                previous_rmse, scored = self._error_on(new), True
                # with the twin as prior, also when its cost missed and the records have doubled since its fit
                doubled = len(self._twin_records) >= 2 * self._twin_fitted_on
                self._twin_dirty = self._mispredicts(previous_rmse) or (self._cost_missed and doubled)
                if not self._twin_dirty:
                    self._note_explained()
            else:  # a distrusted twin is refitted when the records have doubled since its fit (more excitation)
                self._twin_dirty = len(self._twin_records) >= 2 * self._twin_fitted_on
        if self._twin_dirty and self._twin_records:
            previous = self.twin_
            if previous is not None and new and not scored:
                previous_rmse = self._error_on(new)
            try:
                twin = self._fit_twin(previous)
                twin = self._twin_of_a_changed_plant(twin) or twin
                self.twin_ = twin if np.isfinite(twin.rmse_) else None
            except (ValueError, FloatingPointError, np.linalg.LinAlgError):
                self.twin_ = None  # too little excitation to identify: no twin this time
            self._note_explained()
            self._twin_env = None
            self._twin_dirty = self._cost_missed = False
            self._twin_fitted_on = len(self._twin_records)
            if self.twin_ is not None:
                self._record_twin_change(previous_rmse)
                self._twin_env = self._twin_env_for(self.twin_)
                self._restore_trust()
        return self.twin_

    def _twin_of_a_changed_plant(self, twin):
        """If the records show a plant change, ``D~`` re-initialised with the records since and their twin.

        ``twin`` is fitted on all of ``D~``. See "Plant changes" in the class doc: when it no longer
        simulates them within the noise but a twin of its structure fitted on the records after the
        first ``m`` explained ones (at least :data:`PLANT_CHANGE_RECORDS`) does, those records are
        kept alone in ``D~`` and their twin is returned; otherwise ``None``.
        """
        from sklearn.base import clone

        start = self._explained_upto
        later = self._twin_records[start:]
        explained = self._explained_rmse()
        if self.twin == "linear" or start == 0 or len(later) < PLANT_CHANGE_RECORDS or twin.rmse_ <= explained:
            return None
        try:
            candidate = clone(twin).fit(later)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            return None  # the later records identify no twin: keep the one of all records
        if not candidate.rmse_ <= explained:
            return None  # no single plant explains the later records either: a missing effect, not a change
        self._reinitialise(start)
        return candidate

    def _reinitialise(self, start: int) -> None:
        """``D~`` restarts from its records after the first ``start`` (eq. (reinit_DTdataset), or a plant change)."""
        self._twin_records, self._twin_costs = self._twin_records[start:], self._twin_costs[start:]
        self._twin_fitted_on = 0
        self._diagnosed_on = 0
        self._explained_upto = 0
        self.reinitializations_ += 1

    def _note_explained(self) -> None:
        """Record that the current twin simulates every record of ``D~`` within the noise, if it does."""
        if self.twin != "linear" and self.twin_ is not None and self.twin_.rmse_ <= self._explained_rmse():
            self._explained_upto = len(self._twin_records)

    def _fit_twin(self, previous):
        """A twin fitted on ``D~``: diagnosed (``"auto"``), the paper's linear one, or the given estimator."""
        from sklearn.base import clone

        if self.twin == "auto":
            effects = getattr(previous, "effect_params_", None) or {}
            # the current structure first: the paper's SRIVC twin, or the diagnosed effects from their last values
            twin = clone(previous).fit(self._twin_records) if effects else self._linear_twin()
            n = len(self._twin_records)
            doubled = n >= 2 * self._diagnosed_on and self._diagnosed_on < MAX_DIAGNOSED_RECORDS
            due = self._diagnosed_on == 0 or doubled
            if due and not twin.rmse_ <= self._explained_rmse():  # an error the noise does not explain
                from agents.twin.model import ModelSpec
                from agents.twin.selection import diagnosed_twin

                spec = ModelSpec(n_poles=self.twin_poles, n_integrators=self._integrators(),
                                 output=self._plant_env.loop.plant.output)
                self._diagnosed_on = n
                # from the linear model, not from the current effects: the ladder only adds effects, and one that
                # fewer records evidenced (a wrong one, when the true effect showed in only one of them) is dropped
                diagnosed = diagnosed_twin(self._twin_records, spec, max_effects=MAX_TWIN_EFFECTS,
                                           n_samples=self.n_samples)[0]
                if diagnosed.rmse_ < twin.rmse_:
                    twin = diagnosed
            if getattr(twin, "effect_params_", None):
                linear = self._linear_twin()
                if self._cost_error(linear) < self._cost_error(twin):
                    twin = linear  # the effects replay the records but mispredict the experiments' costs
            return twin
        if self.twin == "linear":
            template = self._default_twin()
        else:
            template = self.twin
        twin = previous if previous is not None and previous is not self.twin else clone(template)
        return twin.fit(self._twin_records)  # warm start from the last fit

    def _linear_twin(self):
        """The paper's SRIVC twin fitted on ``D~``, warm-started from its previous fit in this run."""
        if self._linear is None:
            self._linear = self._default_twin()
        return self._linear.fit(self._twin_records)

    def _cost_error(self, twin) -> float:
        r"""RMS relative error of ``twin``'s expected cost at the gains of ``D~`` against their measured costs.

        ``sqrt(mean_i ((J~(theta_i) - J_i) / J_i)^2)``: the twin closes the loop at each recorded
        experiment's gains, as it will when it guides BO (a replay of the recorded input, which the
        fit minimises, does not test that); ``inf`` if the twin diverges where the plant did not.
        """
        gains = np.array([g for g, _ in self._twin_costs])
        measured = np.array([c for _, c in self._twin_costs])
        try:
            predicted = self._twin_env_for(twin).evaluate(gains)[1]
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            return np.inf
        error = float(np.sqrt(np.mean(((predicted - measured) / np.maximum(np.abs(measured), 1e-12)) ** 2)))
        return error if np.isfinite(error) else np.inf

    def _current_twin_env(self):
        """The twin env of the current twin (fitting it first if none is fitted yet)."""
        if self._twin_env is None:
            twin = self._current_twin()  # a refit builds the env itself
            if twin is not None and self._twin_env is None:
                self._twin_env = self._twin_env_for(twin)
        return self._twin_env

    def _twin_env_for(self, twin):
        """The plant env's loop around ``twin``, with the records' noise floor unless the twin is the paper's."""
        from agents.twin import make_twin_env

        floor = self.noise_floor_
        noise = floor * self._step_height if self.twin != "linear" and floor > SIMULATED_NOISE_FLOOR else 0.0
        return make_twin_env(self._plant_env, twin, measurement_noise_std=noise, draws=TWIN_NOISE_DRAWS)

    def _integrators(self) -> int:
        plant = self._plant_env.loop.plant
        integrators = len(plant.den) - len(np.trim_zeros(np.asarray(plant.den), "b"))
        return min(integrators, self.twin_poles - 1)

    def _default_twin(self):
        from agents.twin import LinearTwin

        return LinearTwin(n_poles=self.twin_poles, n_zeros=0, n_integrators=self._integrators(),
                          n_samples=self.n_samples, output=self._plant_env.loop.plant.output, warm_start=True)

    # -- what the run shows ------------------------------------------------------------------------
    def _twin_description(self) -> dict[str, Any]:
        """Which twin drives the twin iterations: its effects, parameters and RMSE (logged per twin row)."""
        twin = self.twin_
        return {"twin_effects": ",".join(_effect_values(twin)) or "linear",
                "twin_params": _json_params(twin), "twin_rmse": float(twin.rmse_)}

    def _record_twin_change(self, previous_rmse: float | None) -> None:
        twin = self.twin_
        effects = _effect_values(twin)
        model = _model_label(twin)
        change = {"experiment": self.n_observations, "model": model, "effects": effects,
                  "params": [float(p) for p in twin.params_], "rmse": float(twin.rmse_), "previous_rmse": previous_rmse}
        named = ", ".join(f"+ {name} ({_format_values(values)})" for name, values in effects.items()) or "linear"
        spec = getattr(getattr(twin, "greybox_", None), "spec", None)
        if spec is not None and (spec.n_poles > self.twin_poles or spec.n_zeros > 0):  # the linear part grew
            named = f"{spec.n_poles} poles, {spec.n_zeros} zero{'s' if spec.n_zeros != 1 else ''}" + \
                (f", {named}" if effects else "")
        before = f"{previous_rmse:.3g} -> " if previous_rmse is not None else ""
        after = f"{self.n_observations} experiment" + ("" if self.n_observations == 1 else "s")
        change["text"] = f"twin: {named}, RMSE {before}{twin.rmse_:.3g} (after {after})"
        self.twin_changes_.append(change)
        self.log_event(change["text"])


def _model_label(twin) -> str:
    """The twin's structure, e.g. ``"linear(4p0z)+compliance"`` (a linear twin: its orders)."""
    fit = getattr(twin, "greybox_", None)
    if fit is not None:
        return fit.spec.label
    den, num = np.asarray(twin.den_), np.asarray(twin.num_)
    return f"linear({den.size - 1}p{num.size - 1}z)"


def _effect_values(twin) -> dict[str, dict[str, float]]:
    """``{effect: {parameter: value}}`` of a twin (empty for a linear one), finite values only."""
    params = getattr(twin, "effect_params_", None) or {}
    return {name: {k: float(v) for k, v in values.items() if isinstance(v, (int, float)) and np.isfinite(v)}
            for name, values in params.items()}


def _format_values(values: dict[str, float]) -> str:
    return ", ".join(f"{k} {v:.4g}" for k, v in values.items())


def _json_params(twin) -> str:
    """The twin's linear parameters and effect values as one compact JSON string (one per twin row)."""
    return json.dumps({"linear": [float(p) for p in twin.params_], **_effect_values(twin)})


#: ``GuidedBO``'s former keywords of the twin iterations, now :class:`~agents.guidance.TwinIterations`'s.
_DEPRECATED = tuple(f.name for f in fields(TwinIterations))


def _guidance(guidance, deprecated: dict) -> TwinPrior | TwinIterations:
    """The guidance object of ``GuidedBO(guidance=..., **deprecated)``, with a ``FutureWarning`` for the old keywords.

    ``GuidedBO(guidance="iterations", eta1=2)`` is ``guidance=TwinIterations(eta1=2)``. Beside
    ``guidance="prior"`` the old keywords are checked and, as before, have no effect.
    """
    unknown = [name for name in deprecated if name not in _DEPRECATED]
    if unknown:
        raise TypeError(f"GuidedBO.__init__() got an unexpected keyword argument {unknown[0]!r}")
    named = as_guidance(guidance)
    if not deprecated:
        return named
    iterations = TwinIterations(**deprecated)  # checked in either case, as the keywords were
    given = ", ".join(f"{name}={value!r}" for name, value in deprecated.items())
    if not isinstance(guidance, str):
        raise ValueError(f"{', '.join(deprecated)}: give them in the guidance, TwinIterations({given}, ...), not "
                         f"beside guidance={guidance!r}")
    if isinstance(named, TwinPrior):
        warnings.warn(f"GuidedBO({given}) is deprecated: these keywords belong to the twin iterations and have no "
                      f"effect with guidance='prior'; for twin iterations write guidance=TwinIterations({given})",
                      FutureWarning, stacklevel=3)
        return named
    table = ", ".join(f"{name} = {_toml(value)}" for name, value in deprecated.items())
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
