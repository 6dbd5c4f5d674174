"""Bayesian optimization of controller gains (paper, subsec. BO).

GP surrogate (:class:`agents.surrogate.GPSurrogate`) + Expected Improvement
(:mod:`agents.acquisition`) maximised by exhaustive search over a dense grid of
the feasible set, after a Latin hypercube initial set of ``N0`` experiments.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np
from scipy.stats import qmc

from agents.acquisition import ExpectedImprovement, maximize_on_grid
from agents.base import Tuner
from agents.metric_surrogate import CompositeSurrogate, MetricSurrogate
from agents.result import METRIC_COLUMNS
from agents.settling import SettlingTimeModel, error_envelope
from agents.surrogate import OUTPUT_TRANSFORMS, PRIOR_MEANS, GPSurrogate
from agents.thread_limits import single_thread
from gbo_envs.gain_grid import grid_axes, grid_points

__all__ = ["BayesianOptimization", "INCUMBENTS", "MODELS", "SETTLING_MODELS"]

#: What the GP models: the cost ``J`` (one GP) or every performance metric (one GP each).
MODELS = ("cost", "metrics")

#: How ``model="metrics"`` models the settling time: by a GP of its own, or from the error envelope.
SETTLING_MODELS = ("gp", "envelope")

#: Choices of the incumbent ``J+`` of EI.
INCUMBENTS = ("observed", "posterior_mean")

#: Column of the settling time in the metric arrays.
_SETTLING = METRIC_COLUMNS.index("settling_time")

#: Candidate sets larger than this (``grid_points ** n_gains``) are replaced by a Sobol set of this size.
_MAX_GRID = 2**16


class BayesianOptimization(Tuner):
    """GP-EI Bayesian optimization (paper, subsec. BO, Algorithm 1 without the twin).

    1. ``n_initial`` (``N0``) gains from a Latin hypercube of the feasible set
       (``scipy.stats.qmc.LatinHypercube`` seeded by the tuner's rng).
    2. Then, every experiment: fit the GP (Matern 5/2 ARD, constant mean by
       standardising the costs, noise learned or given, hyperparameters by log
       marginal likelihood; inputs scaled to the unit box) on the training set
       ``D`` of eq. (D); query the maximiser of Expected Improvement (eq. (LCB))
       over a ``grid_points``-per-gain grid of the feasible set (eq. (EI)).

    Parameters
    ----------
    n_initial : int, default 1
        Size ``N0`` of the Latin hypercube initial set (the paper uses 1).
    grid_points : int, default 100
        Grid points per gain for maximising EI (100 x 100 for two gains, the
        paper's dense grid). Above 65536 candidates a scrambled Sobol set of
        65536 points is used instead.
    polish : bool, default False
        Refine the best grid point with L-BFGS-B within the bounds.
    incumbent : {"observed", "posterior_mean"}, default "observed"
        ``J+`` of EI: the lowest measured cost in the training set (the
        paper's "best-observed performance") or the lowest posterior mean at
        the training points (robust to a lucky noisy measurement). On
        DCMotor-v0 "observed" reached ratio 1.1 in fewer experiments (see
        benchmarks/data_efficiency.py), so it is the default.
    xi : float, default 0.0
        EI exploration margin, cost units.
    noise_std : float, optional
        Known cost noise ``sigma_eps`` (e.g. from :func:`agents.cost_noise.estimate_noise`);
        ``None`` learns it by marginal likelihood.
    n_restarts : int, default 2
        Random restarts of the likelihood optimiser per fit (seeded by the tuner).
    length_scale_bounds : (float, float), default (0.05, 0.5)
        ARD length-scale bounds in unit-box units. The upper bound keeps the
        GP from explaining a narrow cost valley with one smooth bowl (which
        makes EI stop exploring); 0.5 was best of 0.2-20 on DCMotor-v0.
    noise_bounds : (float, float), default (1e-6, 0.5)
        Bounds of the learned noise variance, in units of the standardised costs.
    warm_start : bool, default True
        Start each hyperparameter fit from the previous one.
    restart_every : int, default 5
        Random restarts only on every ``restart_every``-th fit (warm start in between).
    local_every : int, default 0
        Trust-region steps (TuRBO-like, Eriksson et al., 2019): when ``> 0``, every
        ``local_every``-th BO iteration maximises EI (eq. (EI)) over a ``local_points``-per-gain
        grid of the box of half-width ``trust_region`` (unit-box units) around the training
        point with the lowest cost, instead of the dense grid. ``0`` (default) is the paper's
        global grid only. On DCMotor-v0 it did not help (see Notes).
    trust_region : float, default 0.1
        Half-width of the trust region, unit-box units, in ``(0, 1]``.
    local_points : int, default 41
        Grid points per gain in the trust region.
    output_transform : {"none", "log", "rank"}, default "none"
        Monotone transform ``z = T(J)`` the GP is fitted on
        (:class:`agents.surrogate.OutputTransform`). With a transform, EI (eq. (LCB)) is
        computed in the transformed space: ``mu_n, v_n`` of ``T(J_hat)`` and incumbent
        ``T(J+_n)`` (``xi`` is scaled by ``T'(J+_n)``); since ``T`` is increasing, an improvement
        in ``z`` is an improvement in ``J``, but EI's value is in ``z`` units. The ``ei``
        returned by :meth:`propose` (and ``last_ei_``) is converted back to cost units by the
        delta method, ``a_EI / T'(J+_n)``; :meth:`posterior` returns the posterior median
        ``T^-1(mu_z)`` and a delta-method std in cost units.
    length_scale_prior : (float, float), optional
        ``(m, s)``: log-normal prior ``log l_j ~ N(m, s^2)`` on every ARD length scale
        (unit-box units); the hyperparameters are then the MAP estimate (penalised log
        marginal likelihood). ``None``: maximum likelihood (the paper).
    noise_prior : (float, float), optional
        ``(m, s)``: log-normal prior on the learned noise variance (standardised units).
    min_fit_points : int, default 5
        Below this many training points the GP keeps its prior hyperparameters
        (see :class:`agents.surrogate.GPSurrogate`).
    prior_mean : {"sample", "ml", "max"}, default "sample"
        The value of the constant prior mean ``mu`` of eq. (gpr_mio1): the sample mean of
        the (transformed) costs, the marginal-likelihood (GLS) estimate
        ``1' K^-1 y / 1' K^-1 1`` profiled out of the likelihood, or the largest training
        cost (pessimistic: unexplored regions are predicted bad, which curbs EI's corner
        and edge sampling).
    model : {"cost", "metrics"}, default "metrics"
        What is modelled. ``"metrics"``: the paper's "performance metrics modeled by Gaussian
        processes" -- one GP per metric of ``record["metrics"]`` (:data:`agents.result.METRIC_COLUMNS`),
        each on ``f_i / n_i`` with the env's normalizers, combined into the posterior of
        ``J_hat = sum_i w_i f_i / n_i`` (eq. (J_used)) as independent GPs: mean ``sum w_i mu_i``,
        variance ``sum w_i^2 sigma_i^2`` (:mod:`agents.metric_surrogate`, which documents the
        noise model). EI is computed on that mean and std by the same acquisition code; the
        ``"observed"`` incumbent is the lowest ``sum w f / n`` of the measured metrics (the
        additive cost noise is not in them). Needs ``env.unwrapped.weights`` and
        ``.normalizers`` (four metrics) at :meth:`setup`; without them, and for any fit where a
        training point has no finite metrics (no record, an unstable experiment, or extra data
        added without ``metrics=``), the cost GP is used. ``"cost"``: one GP on the measured
        costs ``J`` (what guided BO uses, since its twin points carry only costs).
    log_metrics : tuple of str, default ("settling_time", "rise_time", "itae")
        With ``model="metrics"``: metrics whose GP models ``log(f_i / n_i + 1e-3)``; the
        combination uses their log-normal mean and std. The settling time jumps where the
        response touches the 2 % band, and the log makes the jump relatively smaller than
        the valley; rise time and ITAE grow like ``1 / gain`` towards small gains, which a
        GP extrapolates better in logs. Overshoot is not logged: it is 0 on a large region,
        and its log makes that flat region dominate the fit (see Notes).
    settling_model : {"gp", "envelope"}, default "gp"
        With ``model="metrics"``: how the settling time is modelled. ``"gp"``: a GP of its own,
        like the other metrics. ``"envelope"``: from GPs on the error envelope of the response
        (:mod:`agents.settling`: the settling time as a composite of smooth functions, which
        keeps its jump where the response touches the 2 % band); needs the env's step
        (``env.unwrapped.loop.r1``, ``.r2``, ``.duration``) and the records' ``t`` and ``y``,
        else the GP is used. It needs fewer experiments but makes ``ask()`` slower (see Notes).
    settling_times : int, default 100
        With ``settling_model="envelope"``: the times, evenly spaced over the record, at which
        the envelope is modelled (the settling time's resolution is the record length over this).
    metric_optimize_every : int, default 1
        With ``model="metrics"``: the metric GPs' hyperparameters are fitted on every
        ``metric_optimize_every``-th fit only (conditioned with the previous ones in between),
        to make ``ask()`` faster (2 needed 17.4 instead of 15.7 experiments to ratio 1.1 on
        seeds 0-59, so the default is 1; ``ask()`` with 50 observations takes about 40 ms
        with 1, see benchmarks/bench_bo_ask.py).

    Attributes
    ----------
    surrogate : GPSurrogate
        The GP; :meth:`fit_surrogate` returns it fitted on the current training set.
    last_ei_, last_std_, last_mean_ : float
        EI (cost units), posterior std and mean of ``J_hat`` at the gains of the
        last :meth:`ask` (``nan`` for initial-design gains).

    Notes
    -----
    Measured on DCMotor-v0 (benchmarks/data_efficiency.py, N0 = 1, 35 experiments; mean
    experiments to optimality ratio 1.1, never-reached counted as 36; random search needs
    34.2 on seeds 0-59, as expected for a target region of 0.35 % of the box):

    * ``model="cost"`` with the options above (output transforms, MAP length-scale and noise
      priors, ML or pessimistic constant mean, trust-region steps, tighter bounds): 20.6-30.6,
      about 22 with the defaults, on seeds 0-29.
    * ``model="metrics"``, seeds 0-59: plain metrics 18.4; ``log_metrics=("settling_time",)``
      17.1; all four logged 29.6; settling time, rise time and ITAE logged (the default)
      **15.7**, confirmed on the unseen seeds 60-179 with **16.3** (to 1.05: 25.2 and 22.5,
      against 20.8 and 20.6 with only the settling time logged). Other variants on seeds
      0-59: pessimistic prior mean 16.4-18.3, GLS mean 16.9, length-scale prior 17.9,
      trust-region steps 19.0, ``metric_optimize_every=2`` 17.2-17.4.
    * With the true settling time in place of its GP (an oracle, 20 seeds) the same BO needs
      7.7: the settling-time jump is what the remaining experiments are spent on.
    * ``settling_model="envelope"`` (the settling time from GPs on the error envelope,
      100 times): **14.7** on seeds 0-59 and 15.0 on seeds 60-179 (to 1.05: 18.2 and 18.1),
      but ``ask()`` with 50 observations takes about 60 ms instead of 40 (its distribution
      is evaluated at 100 times for every grid point), over the 50 ms budget, so it is an
      option, not the default. With 30 or 50 times it needed 16.8 and 17.8 (seeds 0-59),
      with ``metric_optimize_every=2`` 15.7.

    Extension points for guided BO: :meth:`add_data` / :meth:`remove_data` /
    :meth:`extra_data` put twin evaluations in the GP's training set and take
    them out again; :meth:`propose` returns ``(gains, ei, std)`` without
    changing the tuner; :meth:`posterior` gives the GP at any gains;
    :meth:`training_set` may be overridden to change what the GP is fitted on.
    """

    name = "bo"

    def __init__(self, *, n_initial: int = 1, grid_points: int = 100, polish: bool = False,
                 incumbent: str = "observed", xi: float = 0.0, noise_std: float | None = None,
                 n_restarts: int = 2, length_scale_bounds: tuple[float, float] = (0.05, 0.5),
                 noise_bounds: tuple[float, float] = (1e-6, 0.5), warm_start: bool = True,
                 restart_every: int = 5, local_every: int = 0, trust_region: float = 0.1,
                 local_points: int = 41, output_transform: str = "none",
                 length_scale_prior: tuple[float, float] | None = None,
                 noise_prior: tuple[float, float] | None = None, min_fit_points: int = 5,
                 prior_mean: str = "sample", model: str = "metrics",
                 log_metrics: tuple[str, ...] = ("settling_time", "rise_time", "itae"),
                 metric_optimize_every: int = 1, settling_model: str = "gp",
                 settling_times: int = 100) -> None:
        if model not in MODELS:
            raise ValueError(f"model: must be one of {MODELS}, got {model!r}")
        unknown = [name for name in log_metrics if name not in METRIC_COLUMNS]
        if unknown:
            raise ValueError(f"log_metrics: unknown metrics {unknown}; choose from {METRIC_COLUMNS}")
        if settling_model not in SETTLING_MODELS:
            raise ValueError(f"settling_model: must be one of {SETTLING_MODELS}, got {settling_model!r}")
        if int(settling_times) < 2:
            raise ValueError(f"settling_times: must be >= 2, got {settling_times}")
        if int(n_initial) < 1:
            raise ValueError(f"n_initial: must be >= 1, got {n_initial}")
        if int(grid_points) < 2:
            raise ValueError(f"grid_points: must be >= 2, got {grid_points}")
        if incumbent not in INCUMBENTS:
            raise ValueError(f"incumbent: must be one of {INCUMBENTS}, got {incumbent!r}")
        if not np.isfinite(xi) or xi < 0:
            raise ValueError(f"xi: must be a finite number >= 0, got {xi}")
        if noise_std is not None and not (np.isfinite(noise_std) and noise_std > 0):
            raise ValueError(f"noise_std: must be None or a finite number > 0, got {noise_std}")
        if output_transform not in OUTPUT_TRANSFORMS:
            raise ValueError(f"output_transform: must be one of {OUTPUT_TRANSFORMS}, got {output_transform!r}")
        if prior_mean not in PRIOR_MEANS:
            raise ValueError(f"prior_mean: must be one of {PRIOR_MEANS}, got {prior_mean!r}")
        if int(local_every) < 0:
            raise ValueError(f"local_every: must be >= 0, got {local_every}")
        if not (np.isfinite(trust_region) and 0 < trust_region <= 1):
            raise ValueError(f"trust_region: must be in (0, 1], got {trust_region}")
        if int(local_points) < 2:
            raise ValueError(f"local_points: must be >= 2, got {local_points}")
        for label, prior in (("length_scale_prior", length_scale_prior), ("noise_prior", noise_prior)):
            if prior is not None and (len(prior) != 2 or not np.all(np.isfinite(prior)) or prior[1] <= 0):
                raise ValueError(f"{label}: must be None or (mean, std > 0) of a log-normal, got {prior}")
        self.n_initial = int(n_initial)
        self.grid_points = int(grid_points)
        self.polish = bool(polish)
        self.incumbent_rule = incumbent
        self.xi = float(xi)
        self.noise_std = noise_std
        self.n_restarts = int(n_restarts)
        self.length_scale_bounds = tuple(length_scale_bounds)
        self.noise_bounds = tuple(noise_bounds)
        self.warm_start = bool(warm_start)
        self.restart_every = int(restart_every)
        self.local_every = int(local_every)
        self.trust_region = float(trust_region)
        self.local_points = int(local_points)
        self.output_transform = output_transform
        self.length_scale_prior = None if length_scale_prior is None else tuple(length_scale_prior)
        self.noise_prior = None if noise_prior is None else tuple(noise_prior)
        self.min_fit_points = int(min_fit_points)
        self.prior_mean = prior_mean
        self.model = model
        self.log_metrics = tuple(log_metrics)
        self.metric_optimize_every = max(1, int(metric_optimize_every))
        self.settling_model = settling_model
        self.settling_times = int(settling_times)
        self._params = {"n_initial": self.n_initial, "grid_points": self.grid_points, "polish": self.polish,
                        "incumbent": incumbent, "xi": self.xi, "noise_std": noise_std,
                        "n_restarts": self.n_restarts, "length_scale_bounds": self.length_scale_bounds,
                        "noise_bounds": self.noise_bounds, "warm_start": self.warm_start,
                        "restart_every": self.restart_every, "local_every": self.local_every,
                        "trust_region": self.trust_region, "local_points": self.local_points,
                        "output_transform": output_transform, "length_scale_prior": self.length_scale_prior,
                        "noise_prior": self.noise_prior, "min_fit_points": self.min_fit_points,
                        "prior_mean": prior_mean, "model": model, "log_metrics": self.log_metrics,
                        "metric_optimize_every": self.metric_optimize_every,
                        "settling_model": settling_model, "settling_times": self.settling_times}

    # -- Tuner hooks ---------------------------------------------------------------------------------
    def _setup(self) -> None:
        dim = self.space.dim
        # Latin hypercube initial set Theta_init of size N0 (paper, subsec. BO), unit box.
        self._initial = qmc.LatinHypercube(d=dim, rng=self.rng).random(self.n_initial)
        self._unit_grid = _unit_candidates(dim, self.grid_points, self.rng)
        offsets = _unit_candidates(dim, self.local_points, self.rng)
        self._local_offsets = (2.0 * offsets - 1.0) * self.trust_region
        self._fit_seed = int(self.rng.integers(2**31))
        self.surrogate = GPSurrogate(n_restarts=self.n_restarts, length_scale_bounds=self.length_scale_bounds,
                                     noise_std=self.noise_std, noise_bounds=self.noise_bounds,
                                     warm_start=self.warm_start,
                                     restart_every=self.restart_every,
                                     output_transform=self.output_transform,
                                     length_scale_prior=self.length_scale_prior, noise_prior=self.noise_prior,
                                     min_fit_points=self.min_fit_points, prior_mean=self.prior_mean)
        self.metric_surrogate: MetricSurrogate | None = None
        if self.model == "metrics":
            env = getattr(self.env, "unwrapped", self.env)
            weights, normalizers = getattr(env, "weights", None), getattr(env, "normalizers", None)
            if weights is not None and normalizers is not None and np.size(weights) == len(METRIC_COLUMNS):
                # the metric GPs: same kernel and fitting options as the cost GP; the metrics are
                # modelled noise-free-ish (their own learned noise), the cost noise is added at J level
                self.metric_surrogate = MetricSurrogate(
                    weights, normalizers,
                    log_metrics=[METRIC_COLUMNS.index(name) for name in self.log_metrics],
                    n_restarts=self.n_restarts, length_scale_bounds=self.length_scale_bounds,
                    noise_bounds=self.noise_bounds, warm_start=self.warm_start,
                    restart_every=self.restart_every, length_scale_prior=self.length_scale_prior,
                    noise_prior=self.noise_prior, min_fit_points=self.min_fit_points,
                    prior_mean=self.prior_mean, optimize_every=self.metric_optimize_every,
                    settling=self._settling_model(env, normalizers[_SETTLING]), settling_index=_SETTLING)
        self._model_in_use = "cost"
        self._plant_X: list[np.ndarray] = []  # unit box
        self._plant_y: list[float] = []
        self._plant_F: list[np.ndarray | None] = []  # raw metrics f_i (None: not measured / unusable)
        self._plant_E: list[np.ndarray | None] = []  # error envelopes at the settling model's times
        self._extra_X: list[np.ndarray] = []
        self._extra_y: list[float] = []
        self._extra_F: list[np.ndarray | None] = []
        self._extra_source: list[str] = []
        self._version = 0
        self._fitted_version = -1
        self._optimize_hyperparameters = True  # guided BO holds them fixed during twin iterations
        self.last_ei_ = self.last_std_ = self.last_mean_ = float("nan")

    def _ask(self) -> np.ndarray:
        n = len(self._plant_y)
        if n < self.n_initial:
            self.last_ei_ = self.last_std_ = self.last_mean_ = float("nan")
            return self.space.from_unit(self._initial[n])
        with single_thread():  # small matrices: BLAS threads would only contend (and spin)
            gains, ei, std = self.propose()
            self.last_mean_ = float(self.posterior(gains[None, :])[0][0])
        self.last_ei_, self.last_std_ = ei, std
        return gains

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        # D <- D u {(theta+, J(theta+))}, eq. (D_training)
        self._plant_X.append(self.space.to_unit(gains))
        self._plant_y.append(cost)
        self._plant_F.append(_record_metrics(record))
        self._plant_E.append(self._record_envelope(record))
        self._version += 1

    def run_summary(self) -> dict[str, Any]:
        model = getattr(self, "_model", None)
        if isinstance(model, CompositeSurrogate):
            return {"model": "metrics", "gp_noise_std": model.noise_std_,
                    "cost_noise_std": model.cost_noise_std_,
                    "gp_length_scales": model.length_scales_.tolist()}
        if not hasattr(self.surrogate, "kernel_"):
            return {}
        return {"model": "cost", "gp_noise_std": self.surrogate.noise_std_,
                "gp_length_scales": [float(v) for v in self.surrogate.length_scales_]}

    # -- what guided BO builds on -------------------------------------------------------------------
    @property
    def n_observations(self) -> int:
        """Number of plant experiments told so far."""
        return len(self._plant_y)

    def training_set(self) -> tuple[np.ndarray, np.ndarray]:
        """The GP's training set ``D`` (eq. (D)): plant data, then extra (twin) data.

        Returns
        -------
        X : ndarray of shape (n, n_gains)
            Unit-box inputs.
        y : ndarray of shape (n,)
            Costs.
        """
        X = self._plant_X + self._extra_X
        y = self._plant_y + self._extra_y
        return np.reshape(np.asarray(X, dtype=float), (len(y), self.space.dim)), np.asarray(y, dtype=float)

    def metric_training_set(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """``(X, metrics, costs)`` of the training set if every point has metrics, else ``None``.

        The metrics model (``model="metrics"``) is used only when this is not ``None``:
        every plant experiment reported finite metrics (``record["metrics"]``, not
        unstable) and every extra point was added with ``metrics=``. Otherwise the tuner
        falls back to the cost GP for that fit (e.g. guided BO's twin costs added without
        metrics: the cost GP is used while they are in ``D``).
        """
        if self.metric_surrogate is None:
            return None
        features = self._plant_F + self._extra_F
        if not features or any(f is None for f in features):
            return None
        X, y = self.training_set()
        return X, np.vstack(features), y

    def envelope_training_set(self) -> np.ndarray | None:
        """Error envelopes (n, k) of the plant experiments for the settling-time model, or ``None``.

        ``None`` (the settling time then gets a GP like the other metrics) unless
        ``settling_model="envelope"`` applies to the env and every training point is a plant
        experiment whose record has its ``t`` and ``y`` trajectories.
        """
        if self._extra_X or not self._plant_E or any(e is None for e in self._plant_E):
            return None
        return np.vstack(self._plant_E)

    def _settling_model(self, env, normalizer: float) -> SettlingTimeModel | None:
        """The envelope model of the settling time, if asked for and the env says where the step is."""
        loop = getattr(env, "loop", None)
        if self.settling_model != "envelope" or not all(hasattr(loop, a) for a in ("r1", "r2", "duration")):
            return None
        times = np.linspace(loop.duration / self.settling_times, loop.duration, self.settling_times)
        return SettlingTimeModel(times, normalizer=normalizer, n_restarts=self.n_restarts,
                                 length_scale_bounds=self.length_scale_bounds, noise_bounds=self.noise_bounds,
                                 warm_start=self.warm_start, restart_every=self.restart_every,
                                 min_fit_points=self.min_fit_points)

    def _record_envelope(self, record: dict | None) -> np.ndarray | None:
        """:func:`agents.settling.error_envelope` of a record, or None (no settling model, no trajectories)."""
        settling = None if self.metric_surrogate is None else self.metric_surrogate.settling
        if settling is None or not record or record.get("unstable", False) or "t" not in record \
                or "y" not in record:
            return None
        loop = getattr(self.env, "unwrapped", self.env).loop  # the step r1 -> r2 (checked in _settling_model)
        envelope = error_envelope(record["t"], record["y"], loop.r1, loop.r2, settling.times)
        return envelope if np.all(np.isfinite(envelope)) else None

    @property
    def model_in_use(self) -> str:
        """``"metrics"`` or ``"cost"``: the model of the last :meth:`fit_surrogate`."""
        return self._model_in_use

    def fit_surrogate(self) -> GPSurrogate | CompositeSurrogate:
        """The surrogate fitted on :meth:`training_set` (refitted only when the data changed).

        ``model="cost"``: the GP on the costs (:attr:`surrogate`). ``model="metrics"``: the
        :class:`~agents.metric_surrogate.CompositeSurrogate` of one GP per metric, or the
        cost GP when some training point has no metrics (see :meth:`metric_training_set`).
        Both answer ``predict(X) -> (mean, std)`` of ``J_hat`` in cost units.
        """
        if self._fitted_version != self._version:
            X, y = self.training_set()
            if y.size == 0:
                raise RuntimeError(f"{type(self).__name__}: no data to fit the GP; tell() an experiment first")
            seed = int(np.random.default_rng([self._fit_seed, self._version]).integers(2**31))
            data = self.metric_training_set()
            if data is not None:
                self._model = self.metric_surrogate.fit(data[0], data[1], data[2], seed=seed,
                                                        optimize=self._optimize_hyperparameters,
                                                        envelopes=self.envelope_training_set())
                self._model_in_use = "metrics"
            else:
                self._model = self.surrogate.fit(X, y, seed=seed, optimize=self._optimize_hyperparameters)
                self._model_in_use = "cost"
            self._fitted_version = self._version
        return self._model

    def incumbent(self) -> float:
        """``J+`` of EI over the current training set (see ``incumbent`` in the class doc)."""
        model = self.fit_surrogate()
        X, y = self.training_set()
        if self.incumbent_rule == "observed":
            if self._model_in_use == "metrics":
                # J_hat of the measured metrics, sum w f / n: the best observed noise-free-ish cost
                # (the cost noise epsilon is not in the metrics the composite model is fitted on)
                return float(np.min(self.metric_surrogate.reconstruct(self.metric_training_set()[1])))
            return float(np.min(y))  # J+_n, best observed cost (paper, eq. (LCB))
        return float(np.min(model.predict(X)[0]))

    def propose(self) -> tuple[np.ndarray, float, float]:
        """Next query ``theta_{n+1} = argmax_theta a_EI(theta)`` (eq. (EI)), without side effects.

        Does not count as an ask: the initial design, the data and the rng are
        unchanged (the GP is fitted, or reused if the data did not change).

        Returns
        -------
        gains : ndarray of shape (n_gains,)
            Physical units, inside the feasible set.
        ei : float
            EI at ``gains``, cost units.
        std : float
            Posterior std of ``J_hat`` at ``gains``, cost units.
        """
        model = self.fit_surrogate()
        # EI in the transformed space z = T(J): J+ -> T(J+), xi in cost units -> xi T'(J+)
        best = self.incumbent()
        transform = model.transform_
        acquisition = ExpectedImprovement(_Latent(model), float(transform(best)),
                                          self.xi * float(transform.derivative(best)))
        unit_box = np.column_stack([np.zeros(self.space.dim), np.ones(self.space.dim)])
        x, ei = maximize_on_grid(acquisition, self.candidates(), polish=self.polish, bounds=unit_box)
        std = float(model.predict(x[None, :])[1][0])
        if transform.kind != "none":  # EI back in cost units (delta method at the incumbent)
            ei = ei / float(transform.derivative(best))
        return self.space.from_unit(x), float(ei), std

    def is_local_step(self) -> bool:
        """Whether this BO iteration searches the trust region only (see ``local_every``)."""
        k = self.n_observations - self.n_initial
        return self.local_every > 0 and k >= 0 and k % self.local_every == self.local_every - 1

    def candidates(self) -> np.ndarray:
        """Unit-box candidate set of this iteration: the dense grid, or the trust region around the best."""
        if not self.is_local_step():
            return self._unit_grid
        X, y = self.training_set()
        centre = X[int(np.argmin(y))]
        return np.clip(centre + self._local_offsets, 0.0, 1.0)

    def posterior(self, gains) -> tuple[np.ndarray, np.ndarray]:
        """GP mean and std of ``J_hat`` at gains of shape (m, n_gains) (physical units); each (m,)."""
        gains = np.atleast_2d(np.asarray(gains, dtype=float))
        return self.fit_surrogate().predict(self.space.to_unit(gains))

    def add_data(self, gains, costs, source: str = "twin", metrics=None) -> None:
        """Add extra points (e.g. twin evaluations) to the GP's training set (Algorithm 1, line D_in_DT).

        Parameters
        ----------
        gains : array_like of shape (m, n_gains) or (n_gains,)
            Inside the feasible set.
        costs : array_like of shape (m,) or float
            Finite costs.
        source : str, default "twin"
            Label used by :meth:`remove_data`; ``"plant"`` is reserved.
        metrics : array_like of shape (m, 4) or (4,), optional
            Raw metrics of the points (:data:`agents.result.METRIC_COLUMNS` order), for
            ``model="metrics"``; without them the cost GP is used while these points are in
            the training set.
        """
        if source == "plant":
            raise ValueError("source: 'plant' is reserved for tell(); use another label")
        gains = np.atleast_2d(np.asarray(gains, dtype=float))
        costs = np.atleast_1d(np.asarray(costs, dtype=float))
        if gains.shape[0] != costs.shape[0]:
            raise ValueError(f"gains, costs: {gains.shape[0]} gains but {costs.shape[0]} costs")
        if metrics is None:
            features = [None] * costs.shape[0]
        else:
            features = np.atleast_2d(np.asarray(metrics, dtype=float))
            if features.shape != (costs.shape[0], len(METRIC_COLUMNS)) or not np.all(np.isfinite(features)):
                raise ValueError(f"add_data(metrics): need finite values of shape "
                                 f"({costs.shape[0]}, {len(METRIC_COLUMNS)}), got {features.shape}")
        for row, cost, feature in zip(gains, costs, features):
            checked = self.space.check(row, name="add_data(gains)")
            if not np.isfinite(cost):
                raise ValueError(f"add_data(costs): must be finite, got {cost}")
            self._extra_X.append(self.space.to_unit(checked))
            self._extra_y.append(float(cost))
            self._extra_F.append(None if feature is None else np.array(feature, dtype=float))
            self._extra_source.append(source)
        self._version += 1

    def remove_data(self, source: str | None = "twin") -> int:
        """Remove extra points with label ``source`` (``None``: all extra points); returns how many.

        Plant experiments are never removed (Algorithm 1, line remove_DT_data).
        """
        keep = [i for i, s in enumerate(self._extra_source) if source is not None and s != source]
        removed = len(self._extra_source) - len(keep)
        self._extra_X = [self._extra_X[i] for i in keep]
        self._extra_y = [self._extra_y[i] for i in keep]
        self._extra_F = [self._extra_F[i] for i in keep]
        self._extra_source = [self._extra_source[i] for i in keep]
        if removed:
            self._version += 1
        return removed

    @contextlib.contextmanager
    def extra_data(self, gains, costs, source: str = "twin", metrics=None) -> Iterator[BayesianOptimization]:
        """``with bo.extra_data(gains, costs): bo.propose()`` -- the points are removed on exit."""
        self.add_data(gains, costs, source=source, metrics=metrics)
        try:
            yield self
        finally:
            self.remove_data(source)


class _Latent:
    """The GP's posterior in the transformed-cost space ``z = T(J)`` (what EI is computed on)."""

    def __init__(self, model: GPSurrogate) -> None:
        self.model = model

    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.model.predict_latent(X)


def _record_metrics(record: dict | None) -> np.ndarray | None:
    """The raw metrics of an experiment record in METRIC_COLUMNS order, or None if absent or unusable."""
    if not record or record.get("unstable", False):
        return None
    values = record.get("metrics")
    if not isinstance(values, dict) or any(name not in values for name in METRIC_COLUMNS):
        return None
    metrics = np.array([float(values[name]) for name in METRIC_COLUMNS])
    return metrics if np.all(np.isfinite(metrics)) else None


def _unit_candidates(dim: int, points_per_gain: int, rng: np.random.Generator) -> np.ndarray:
    """The dense grid of the unit box, shape (points_per_gain ** dim, dim), or a Sobol set if too large."""
    if points_per_gain**dim <= _MAX_GRID:
        return grid_points(grid_axes(np.zeros(dim), np.ones(dim), points_per_gain))
    return qmc.Sobol(d=dim, scramble=True, rng=rng).random(_MAX_GRID)
