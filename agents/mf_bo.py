"""Multi-fidelity BO with the digital twin as the low fidelity (after GMFBO, Nobar et al., arXiv 2509.17952).

One Gaussian process models the cost at every fidelity: the plant at ``s = 1``,
the twin at ``s = s_twin < 1``, with ``s_twin`` re-estimated from the twin's
error on the plant records (:mod:`agents.mf_correction`). A cost-aware
acquisition decides, before every real experiment, whether a cheap twin
evaluation is worth more per unit cost than the real experiment. A twin the
records show to be useless is switched off, and the tuner is then the default BO.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import minimize

from agents.base import Tuner
from agents.bo import BayesianOptimization
from agents.mf_correction import TwinCorrection
from agents.parameters import HasMethods, Interval, Options, validate_params
from agents.peers.base import latin_hypercube, require
from agents.twin_keeper import RMSE_FLOOR, TWIN_CHOICES, TwinKeeper

__all__ = ["MultiFidelityBO", "NUM_RESTARTS", "RAW_SAMPLES", "robust_minimum"]

#: ``optimize_acqf_mixed``: L-BFGS-B starts per fidelity, and the random points they are picked from.
NUM_RESTARTS, RAW_SAMPLES = 2, 32

#: Multi-fidelity MES: max-value samples, fantasies, and the random candidate set of the max values.
NUM_MV_SAMPLES, NUM_FANTASIES, CANDIDATES = 8, 8, 256

#: The learned fidelity ``s_twin`` never exceeds this: a twin is never the plant.
MAX_FIDELITY = 0.95

#: Nelder-Mead's search for a twin's robust optimum: at most this many steps, to this tolerance of the unit box.
OPTIMUM_STEPS, OPTIMUM_TOLERANCE = 200, 1e-3

#: Radius of the robust optimum's neighbourhood, a fraction of each gain's range (guided BO's grid spacing).
ROBUST_RADIUS = 0.01

#: Noise std of ``log J`` on a twin row (a deterministic simulation), and the least on a plant row.
TWIN_LOG_NOISE = 1e-3


class MultiFidelityBO(Tuner):
    r"""Multi-fidelity BO: the twin at fidelity ``s_twin``, the plant at ``s = 1``, in one BoTorch GP.

    **The twin.** Guided BO's twin (with ``twin="auto"`` the diagnosed grey-box twin,
    refitted when it mispredicts a new record): every plant experiment is told to a
    :class:`~agents.twin_keeper.TwinKeeper` (with the cost rule of guided BO's default
    guidance, ``refit_on_cost_miss``) that keeps the twin records ``D~`` and fits the twin;
    its :class:`~agents.twin.TwinEnv` gives the twin's expected cost at any gains.

    **The correction and the fidelity** (:class:`~agents.mf_correction.TwinCorrection`).
    Before every proposal the current twin is simulated at the gains of every plant
    experiment. ``s_twin`` (in ``[0, 0.95]``) is estimated from the twin's error on the
    plant records, in two stages:

    * from the first record, by the twin's *response* error: with ``e_RMSE`` the twin's
      normalised simulation error on its records (eq. (RMSE), guided BO's ``rmse_``) and
      ``s_n`` their normalised noise floor (at least ``10^-3``),
      ``s_twin = min(0.95, s_n^2 / e_RMSE^2)``, the share of the response error the
      measurement noise explains (``e_RMSE^2 ~ s_n^2 + e_model^2``): a twin as right as
      the noise allows gets 0.95, one twice the noise floor off 0.25. It is 0 if the
      twin's cost at a record's gains is more than ``3 sigma_eps`` off the measured cost
      (a twin whose response fits but whose cost does not, such as a pure-noise cost,
      is not used). The correction is the identity ``a = 0, b = 1`` at this stage;
    * from ``min_records`` (4) records on, by the twin's *cost* error: the line
      ``log J = a + b log J_twin`` is fitted through the pairs (twin cost, measured
      cost), and ``s_twin`` is its leave-one-out explained variance on the measured
      log costs, ``Q^2 = 1 - sum_i (log J_i - a_{-i} - b_{-i} log J_twin,i)^2 /
      sum_i (log J_i - mean log J)^2`` (``a_{-i}, b_{-i}``: the line fitted without
      record ``i``), 0 unless the twin's and the plant's log costs are significantly
      positively correlated (one-sided Pearson test, ``p < 0.01``).

    Over a run: ``s_twin`` is 0 until a twin is fitted (the first record), jumps to the
    response estimate (DCMotor-v0: 0.95 from the second or third experiment), may step
    at the fourth record when the cost pairs take over (a chance near-tie of four
    costs can give ``Q^2 = 0`` for an experiment or two), then rises as a good twin's
    predictions are confirmed, falls when a new record contradicts the twin, and jumps
    when the twin is refitted (the twin rows are re-simulated on the new twin). A
    pure-noise twin stays at 0 throughout. ``result.info["fidelity_trace"]`` records,
    per real experiment, ``s_twin``, what it was estimated from (``estimate``:
    ``"none"``, ``"response"`` or ``"costs"``), ``a``, ``b`` and whether the twin was used.

    **The twin design and the twin's optimum.** When the twin is first used
    (``s_twin >= min_fidelity``), it is evaluated at ``twin_design`` Latin hypercube
    points of the gain box (twin rows with ``design=True``): the twin is cheap, and the
    GP then knows its shape over the whole box. Each new twin's robust optimum
    (:func:`robust_minimum`: Nelder-Mead on the worst twin cost within 1 % of each gain's
    range) and its neighbours ``+- 1 %`` along each gain are twin rows too
    (``twin_optimum=True``): the cost's optimum can sit in a thin valley or on the edge
    of a cliff (DCMotor-v0's cost jumps from 1.0 to 1.4 times the optimum across a line
    through it), which design points 0.1 apart do not resolve.

    **The model** (while ``s_twin >= min_fidelity``). BoTorch's
    ``SingleTaskMultiFidelityGP`` with the fidelity as the last input column
    (``data_fidelities=[d]``, the downsampling kernel) on the gains scaled to
    ``[0, 1]``, trained on the plant experiments at ``s = 1`` and every twin evaluation
    of this run at ``s = s_twin``, outcomes ``-log J`` (twin rows: the corrected
    ``-(a + b log J_twin)``) standardised. The log makes the cost's orders of magnitude
    (an unstable loop's cost is large) comparable. The noise is fixed, not learned: a
    plant row's ``log J`` has the std ``sigma_eps / J`` (the cost noise, to first
    order), a twin row (a deterministic simulation) ``10^-3``. (With a learned noise the
    GP took the twin's cliff for noise, std 0.16 of the standardised outcome, and its
    mean at ``s = 1`` stayed 0.2 below the twin's optimum in ``log J``, so the real
    experiments went elsewhere.) Hyperparameters by ``fit_gpytorch_mll``, warm-started
    from the last fit.

    **The acquisition.** ``qMultiFidelityMaxValueEntropy`` (information about the
    plant's optimum, with the fantasies projected to ``s = 1``) divided by the cost of
    an evaluation, ``InverseCostWeightedUtility`` with an ``AffineFidelityCostModel``
    through ``c(1) = 1`` and ``c(s_twin) = twin_cost``. It is maximised by
    ``optimize_acqf_mixed`` over the gain box with the fidelity fixed to ``s_twin``
    and to 1. While the twin wins, it is evaluated there (a twin row) and the GP
    refitted; otherwise, and at the latest after ``max_twin_evaluations`` twin
    evaluations, the real experiment is run at the maximiser of the posterior mean at
    ``s = 1`` (``PosteriorMean`` with the fidelity fixed, ``optimize_acqf``): the
    fused model's best gains. Where these repeat a measured experiment (within
    ``10^-3`` of the unit box), the real experiment goes to the maximiser of
    ``LogExpectedImprovement`` at ``s = 1`` (incumbent: the lowest measured cost)
    instead. Multi-fidelity knowledge gradient is the other cost-aware acquisition
    BoTorch has; it is many times slower per optimisation (``python benchmarks/bench_mf_bo.py``),
    beyond the 2 s per real experiment this tuner keeps to.
    Why the real experiment is not the MES or log-EI maximiser: benchmarks/README.md.

    **A useless twin** (``s_twin < min_fidelity``) is not evaluated, and the real
    experiment is the default BO's proposal (:class:`~agents.bo.BayesianOptimization`,
    seeded as ``agents.make("bo")`` and told every plant experiment): with a twin
    of no use, multi-fidelity BO is the default BO.

    Parameters
    ----------
    n_initial : int, default 1
        Size ``N0`` of the Latin hypercube initial set (the same points as ``agents.make("bo")``).
    twin : {"auto", "linear"} or estimator, default "auto"
        The digital twin, as for :class:`~agents.guided_bo.GuidedBO`.
    twin_cost : float, default 0.1
        Cost of a twin evaluation relative to a real experiment, in ``(0, 1)``.
    max_twin_evaluations : int, default 2
        Twin evaluations the acquisition may choose per real experiment (``>= 0``; with
        0 the twin is never used).
    twin_design : int, default 32
        Twin evaluations of the design made when the twin is first used (``>= 0``).
    min_fidelity : float, default 0.5
        ``s_twin`` below which the twin is not used, in ``[0, 1]``.
    min_records : int, default 4
        Plant records before ``s_twin`` is estimated from the cost pairs (``>= 3``); before,
        from the twin's response error.

    Attributes
    ----------
    keeper_ : TwinKeeper
        The twin of the run: its records ``D~``, fits and changes.
    fidelity_ : float
        The current ``s_twin``.
    correction_ : TwinCorrection or None
        The last fitted correction.
    twin_evaluations_ : int
        Twin evaluations of the design and chosen by the acquisition (the result's twin rows).
    twin_simulations_ : int
        Twin simulations in all (those plus the correction's, at the plant gains).

    Raises
    ------
    ImportError
        If BoTorch is not installed (``pip install "gbo-envs[mf]"``).
    """

    name = "mf-bo"

    _parameter_constraints: dict[str, list] = {
        "n_initial": [Interval(int, 1, None)],
        "twin": [Options(TWIN_CHOICES), HasMethods(("fit", "get_params"))],
        "twin_cost": [Interval(float, 0.0, 1.0, closed="neither")],
        "max_twin_evaluations": [Interval(int, 0, None)],
        "twin_design": [Interval(int, 0, None)],
        "min_fidelity": [Interval(float, 0.0, 1.0)],
        "min_records": [Interval(int, 3, None)],
    }

    def __init__(self, *, n_initial: int = 1, twin="auto", twin_cost: float = 0.1, max_twin_evaluations: int = 2,
                 twin_design: int = 32, min_fidelity: float = 0.5, min_records: int = 4) -> None:
        params = validate_params(self._parameter_constraints, {
            "n_initial": n_initial, "twin": twin, "twin_cost": twin_cost,
            "max_twin_evaluations": max_twin_evaluations, "twin_design": twin_design, "min_fidelity": min_fidelity,
            "min_records": min_records})
        require("botorch", "botorch", extra="mf")
        self.n_initial, self.twin = params["n_initial"], twin
        self.twin_cost, self.max_twin_evaluations = params["twin_cost"], params["max_twin_evaluations"]
        self.twin_design = params["twin_design"]
        self.min_fidelity, self.min_records = params["min_fidelity"], params["min_records"]
        self._params = {**{k: v for k, v in params.items() if k != "twin"},
                        "twin": twin if isinstance(twin, str) else type(twin).__name__}

    # -- Tuner hooks ---------------------------------------------------------------------------------
    def _setup(self) -> None:
        if not hasattr(getattr(self.env, "unwrapped", None), "loop"):
            raise ValueError("env: mf-bo needs the plant env (with its closed loop) to simulate its twin; "
                             "use run(env, ...) or setup(space, seed, env=env)")
        # the default BO, seeded as agents.make("bo"): the initial design, and every proposal without a twin
        self._bo = BayesianOptimization(n_initial=self.n_initial)
        self._bo.setup(self.space, seed=self.seed, env=self.env)
        self.keeper_ = TwinKeeper(self.twin, refit_on_cost_miss=True)  # keeps D~ and fits the twin
        self.keeper_.setup(self.space, self.env.unwrapped)
        self._torch_seeds = np.random.default_rng(self.rng.integers(2**31))
        self._design = latin_hypercube(np.random.default_rng(self.rng.integers(2**31)), self.space.dim,
                                       self.twin_design) if self.twin_design else np.empty((0, self.space.dim))
        self._designed = False
        self._plant_X: list[np.ndarray] = []  # unit box
        self._plant_y: list[float] = []
        self._twin_X: list[np.ndarray] = []  # unit box, the twin evaluations of this run
        self._twin_cache: tuple[object, dict[tuple, float]] = (None, {})  # (twin env, unit gains -> twin cost)
        self._optimum_of = None  # the twin env whose optimum is a twin row
        self._gp_state = None
        self.fidelity_ = 0.0
        self.correction_: TwinCorrection | None = None
        self.fidelity_trace_: list[dict] = []
        self.twin_evaluations_ = 0
        self.twin_simulations_ = 0

    def _ask(self) -> np.ndarray:
        if len(self._plant_y) < self.n_initial:
            return self._bo.ask()
        twin_env = self._estimate_fidelity()
        used = twin_env is not None and self.fidelity_ >= self.min_fidelity and self.max_twin_evaluations > 0
        self.fidelity_trace_.append({
            "experiment": len(self._plant_y) + 1, "fidelity": self.fidelity_, "twin_used": used,
            "estimate": "none" if self.correction_ is None else self.correction_.estimate_,
            "intercept": None if self.correction_ is None else self.correction_.intercept_,
            "slope": None if self.correction_ is None else self.correction_.slope_})
        if not used:
            return np.asarray(self._bo.ask(), dtype=float)
        if not self._designed:
            self._designed = True
            for unit in self._design:
                self._evaluate_twin(twin_env, unit, design=True)
        if self._optimum_of is not twin_env:
            self._optimum_of = twin_env
            for unit in _neighbourhood(self._twin_optimum(twin_env)):
                self._evaluate_twin(twin_env, unit, optimum=True)
        return self._ask_multi_fidelity(twin_env)

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        self._plant_X.append(self.space.to_unit(gains))
        self._plant_y.append(cost)
        self._bo.tell(gains, cost, record)
        self.keeper_.tell(gains, cost, record)
        for text in self.keeper_.drain_events():
            self.log_event(text)

    def run_summary(self) -> dict[str, Any]:
        twin = self.keeper_.twin_
        return {"fidelity": self.fidelity_, "fidelity_trace": list(self.fidelity_trace_),
                "twin_evaluations": self.twin_evaluations_, "twin_simulations": self.twin_simulations_,
                "twin_rmse": None if twin is None else float(twin.rmse_),
                "twin_changes": [{k: v for k, v in c.items() if k != "text"} for c in self.keeper_.changes_]}

    # -- the twin, its correction and fidelity -------------------------------------------------------
    def _twin_costs(self, twin_env, unit: np.ndarray) -> np.ndarray:
        """The current twin's expected cost at unit-box gains of shape (m, n_gains), simulated once per twin."""
        cached_env, cache = self._twin_cache
        if cached_env is not twin_env:
            cache = {}
            self._twin_cache = (twin_env, cache)
        missing = [x for x in unit if tuple(x) not in cache]
        if missing:
            costs = twin_env.evaluate(self.space.from_unit(np.asarray(missing)))[1]
            self.twin_simulations_ += len(missing)
            for x, cost in zip(missing, costs):
                cache[tuple(x)] = float(cost) if np.isfinite(cost) else float(twin_env.unstable_cost)
        return np.array([cache[tuple(x)] for x in unit])

    def _estimate_fidelity(self):
        """Refit the correction on the plant records; returns the twin env (``None`` without a twin)."""
        twin_env = self.keeper_.twin_env()
        for text in self.keeper_.drain_events():
            self.log_event(text)
        if twin_env is None:
            self.fidelity_, self.correction_ = 0.0, None
            return None
        twin = self._twin_costs(twin_env, np.asarray(self._plant_X))
        keeper = self.keeper_
        self.correction_ = TwinCorrection(min_records=self.min_records, max_fidelity=MAX_FIDELITY).fit(
            twin, self._plant_y, response_rmse=float(keeper.twin_.rmse_),
            noise_floor=max(keeper.noise_floor_, RMSE_FLOOR), cost_noise=keeper.sigma_eps)
        self.fidelity_ = self.correction_.fidelity_
        return twin_env

    def _twin_optimum(self, twin_env) -> np.ndarray:
        """The twin's robust minimiser (unit box), searched from the lowest twin row or experiment.

        A simulation costs well under a millisecond, a GP fit tens, so each new twin's optimum is
        searched directly (:func:`robust_minimum`); it enters the GP with its neighbourhood as twin
        rows, where a thin optimal valley between the design points would otherwise stay unseen.
        """
        known = np.vstack([np.asarray(self._twin_X).reshape(-1, self.space.dim), np.asarray(self._plant_X)])
        start = known[int(np.argmin(self._twin_costs(twin_env, known)))]
        return robust_minimum(lambda unit: self._twin_costs(twin_env, unit), start)

    # -- multi-fidelity proposals --------------------------------------------------------------------
    def _ask_multi_fidelity(self, twin_env) -> np.ndarray:
        """Twin evaluations while the cost-weighted acquisition prefers them, then the real experiment."""
        # heavy optional dependency: torch, botorch (the mf extra)
        import torch

        threads = torch.get_num_threads()
        torch.set_num_threads(1)  # small matrices: threads only contend
        try:
            with torch.random.fork_rng():
                torch.manual_seed(int(self._torch_seeds.integers(2**31)))
                for evaluation in range(self.max_twin_evaluations + 1):
                    unit, fidelity = self._propose(last=evaluation == self.max_twin_evaluations)
                    if fidelity == 1.0:
                        return self.space.from_unit(unit)
                    self._evaluate_twin(twin_env, unit)
        finally:
            torch.set_num_threads(threads)
        raise AssertionError("unreachable: the last proposal is at the plant's fidelity")

    def _evaluate_twin(self, twin_env, unit: np.ndarray, design: bool = False, optimum: bool = False) -> None:
        gains = self.space.from_unit(unit)
        cost = float(self._twin_costs(twin_env, unit[None, :])[0])
        self._twin_X.append(unit)
        self.twin_evaluations_ += 1
        corrected = float(np.exp(self.correction_.predict_log([cost])[0]))
        self.log_twin(gains, cost, None, fidelity=self.fidelity_, corrected_cost=corrected,
                      twin_iteration=self.twin_evaluations_, design=design, twin_optimum=optimum)

    def _training_data(self):
        """Inputs ``[unit gains, s]``, outcomes ``-log J`` and their noise variances, plant and (corrected) twin rows.

        A measured cost's noise ``sigma_eps`` is ``sigma_eps / J`` on ``log J`` (to first
        order); a twin row is a deterministic simulation, noise-free but for the jitter
        ``TWIN_LOG_NOISE``.
        """
        # heavy optional dependency: torch, botorch (the mf extra)
        import torch

        twin_env = self._twin_cache[0]
        costs = np.maximum(self._plant_y, 1e-300)
        X = [np.column_stack([np.asarray(self._plant_X), np.ones(len(self._plant_X))])]
        y = [-np.log(costs)]
        variance = [np.maximum(self.keeper_.sigma_eps / costs, TWIN_LOG_NOISE) ** 2]
        if self._twin_X:
            unit = np.asarray(self._twin_X)
            X.append(np.column_stack([unit, np.full(len(unit), self.fidelity_)]))
            y.append(-self.correction_.predict_log(self._twin_costs(twin_env, unit)))
            variance.append(np.full(len(unit), TWIN_LOG_NOISE**2))
        return tuple(torch.as_tensor(a, dtype=torch.float64).reshape(len(a), -1)
                     for a in (np.vstack(X), np.concatenate(y), np.concatenate(variance)))

    def _propose(self, last: bool) -> tuple[np.ndarray, float]:
        """The next evaluation: unit-box gains and fidelity (``s_twin``, or 1 for the real experiment).

        The cost-weighted MF-MES maximiser over the gain box and ``s in {s_twin, 1}``
        decides the fidelity (only 1 if ``last``); a real experiment goes to the maximiser
        of log EI at ``s = 1`` (see "The acquisition" in the class doc).
        """
        # heavy optional dependency: torch, botorch (the mf extra)
        from botorch.optim import optimize_acqf_mixed

        dim = self.space.dim
        model = self._fit_model()
        bounds = _unit_box(dim + 1)
        if not last:
            candidate, _ = optimize_acqf_mixed(self._information_per_cost(model), bounds=bounds, q=1,
                                               num_restarts=NUM_RESTARTS, raw_samples=RAW_SAMPLES,
                                               fixed_features_list=[{dim: self.fidelity_}, {dim: 1.0}])
            point = candidate.detach().numpy().reshape(dim + 1)
            if point[dim] != 1.0:
                return np.clip(point[:dim], 0.0, 1.0), self.fidelity_
        return self._plant_point(model), 1.0

    def _fit_model(self):
        """The ``SingleTaskMultiFidelityGP`` on the plant and twin rows, warm-started from the last fit."""
        # heavy optional dependency: torch, botorch (the mf extra)
        from botorch.fit import fit_gpytorch_mll
        from botorch.models import SingleTaskMultiFidelityGP
        from botorch.models.transforms.outcome import Standardize
        from gpytorch.mlls import ExactMarginalLogLikelihood

        train_x, train_y, train_yvar = self._training_data()
        model = SingleTaskMultiFidelityGP(train_x, train_y, train_Yvar=train_yvar, data_fidelities=[self.space.dim],
                                          outcome_transform=Standardize(m=1))
        if self._gp_state is not None:
            model.load_state_dict(self._gp_state, strict=False)
        try:
            fit_gpytorch_mll(ExactMarginalLogLikelihood(model.likelihood, model))
        except Exception:  # noqa: BLE001 - botorch's fit raises its own types; the warm-started values stay
            pass
        self._gp_state = {k: v for k, v in model.state_dict().items() if "train" not in k and "outcome" not in k}
        return model

    def _information_per_cost(self, model):
        """``qMultiFidelityMaxValueEntropy`` weighted by the inverse affine cost through ``c(s_twin)``, ``c(1)``."""
        # heavy optional dependency: torch, botorch (the mf extra)
        import torch
        from botorch.acquisition.cost_aware import InverseCostWeightedUtility
        from botorch.acquisition.max_value_entropy_search import qMultiFidelityMaxValueEntropy
        from botorch.acquisition.utils import project_to_target_fidelity
        from botorch.models.cost import AffineFidelityCostModel

        dim = self.space.dim
        weight = (1.0 - self.twin_cost) / (1.0 - self.fidelity_)
        cost = AffineFidelityCostModel(fidelity_weights={dim: weight}, fixed_cost=1.0 - weight)
        return qMultiFidelityMaxValueEntropy(
            model, candidate_set=torch.rand(CANDIDATES, dim, dtype=torch.float64), num_fantasies=NUM_FANTASIES,
            num_mv_samples=NUM_MV_SAMPLES, cost_aware_utility=InverseCostWeightedUtility(cost_model=cost),
            project=lambda X: project_to_target_fidelity(X, target_fidelities={dim: 1.0}, d=dim + 1))

    def _plant_point(self, model) -> np.ndarray:
        """The real experiment: the posterior mean's maximiser at ``s = 1``, or log EI's where that repeats."""
        # heavy optional dependency: torch, botorch (the mf extra)
        from botorch.acquisition import FixedFeatureAcquisitionFunction, LogExpectedImprovement, PosteriorMean
        from botorch.optim import optimize_acqf

        dim = self.space.dim
        bounds = _unit_box(dim)
        mean = FixedFeatureAcquisitionFunction(PosteriorMean(model), d=dim + 1, columns=[dim], values=[1.0])
        candidate, _ = optimize_acqf(mean, bounds=bounds, q=1, num_restarts=NUM_RESTARTS, raw_samples=RAW_SAMPLES)
        point = np.clip(candidate.detach().numpy().reshape(dim), 0.0, 1.0)
        if not any(np.allclose(point, x, atol=1e-3, rtol=0.0) for x in self._plant_X):
            return point
        best = -float(np.log(max(min(self._plant_y), 1e-300)))
        acquisition = FixedFeatureAcquisitionFunction(LogExpectedImprovement(model, best_f=best), d=dim + 1,
                                                      columns=[dim], values=[1.0])
        candidate, _ = optimize_acqf(acquisition, bounds=bounds, q=1, num_restarts=NUM_RESTARTS,
                                     raw_samples=RAW_SAMPLES)
        return np.clip(candidate.detach().numpy().reshape(dim), 0.0, 1.0)


def robust_minimum(cost, start) -> np.ndarray:
    """The gains (unit box) whose worst cost within :data:`ROBUST_RADIUS` of each gain's range is lowest.

    Nelder-Mead on ``max_{v in N(u)} log J(v)`` (``N(u)``: ``u`` and ``u +- r e_i``,
    :func:`_neighbourhood`) from ``start``, at most :data:`OPTIMUM_STEPS` steps to
    :data:`OPTIMUM_TOLERANCE`. Robust, because an optimum can sit on a cliff of the cost
    (DCMotor-v0's jumps from ratio 1.0 to 1.4 across a line through its optimum): the plain
    minimiser lies on the edge, and the plant's edge, a little off the twin's, puts it on the high side.

    Parameters
    ----------
    cost : callable
        ``cost(unit)``: positive costs (m,) at unit-box gains (m, n_gains).
    start : array_like of shape (n_gains,)
        Unit-box gains the search starts from.

    Returns
    -------
    ndarray of shape (n_gains,)
        In the unit box.
    """
    start = np.asarray(start, dtype=float)

    def worst_log_cost(unit: np.ndarray) -> float:
        return float(np.log(np.max(cost(_neighbourhood(unit)))))

    found = minimize(worst_log_cost, start, method="Nelder-Mead", bounds=[(0.0, 1.0)] * start.size,
                     options={"maxfev": OPTIMUM_STEPS, "xatol": OPTIMUM_TOLERANCE, "fatol": 1e-6})
    return np.clip(found.x, 0.0, 1.0)


def _neighbourhood(unit: np.ndarray) -> np.ndarray:
    """``u`` and ``u +- ROBUST_RADIUS e_i`` in the unit box, shape (2 n_gains + 1, n_gains)."""
    unit = np.clip(np.asarray(unit, dtype=float), 0.0, 1.0)
    steps = ROBUST_RADIUS * np.vstack([np.zeros(unit.size), np.eye(unit.size), -np.eye(unit.size)])
    return np.clip(unit + steps, 0.0, 1.0)


def _unit_box(dim: int):
    """The bounds ``[0, 1]^dim`` of ``optimize_acqf``, a float64 tensor of shape (2, dim)."""
    # heavy optional dependency: torch, botorch (the mf extra)
    import torch

    bounds = torch.zeros(2, dim, dtype=torch.float64)
    bounds[1] = 1.0
    return bounds
