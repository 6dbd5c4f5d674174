"""Bayesian optimization of controller gains (paper, subsec. BO).

GP surrogate (:class:`agents.surrogate.GPSurrogate`) + Expected Improvement
(:mod:`agents.acquisition`) maximised by exhaustive search over a dense grid of
the feasible set (two gains) or by Sobol candidates and multistart L-BFGS-B
(three gains and more), after a Latin hypercube initial set of ``N0`` experiments.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np
from scipy.stats import qmc

from agents.acquisition import ExpectedImprovement, maximize_multistart, maximize_on_grid
from agents.base import Tuner
from agents.feasibility import ConstrainedAcquisition, ConstraintModel, constraint_set, run_risk, validated_safe_start
from agents.metric_surrogate import CompositeSurrogate, MetricSurrogate
from agents.parameters import Interval, Options, validate_params
from agents.result import METRIC_COLUMNS
from agents.settling import SettlingTimeModel, error_envelope
from agents.surrogate import GPSurrogate
from agents.thread_limits import single_thread
from gbo_envs.gain_grid import grid_axes, grid_points

__all__ = ["BayesianOptimization", "GRID_MAX_GAINS", "LOG_METRICS", "MODELS", "OPTIMIZERS", "SETTLING_MODELS",
           "SETTLING_TIMES"]

#: What the GP models: the cost ``J`` (one GP) or every performance metric (one GP each).
MODELS = ("cost", "metrics")

#: How EI is maximised: ``"grid"`` (the dense grid), ``"multistart"`` (Sobol candidates, then L-BFGS-B from
#: the best of them) or ``"auto"`` (the grid up to :data:`GRID_MAX_GAINS` gains, multistart above).
OPTIMIZERS = ("auto", "grid", "multistart")

#: With ``optimizer="auto"``: the most gains whose EI is maximised on the grid.
GRID_MAX_GAINS = 2

#: How ``model="metrics"`` models the settling time: by a GP of its own, or from the error envelope.
SETTLING_MODELS = ("gp", "envelope")

#: With ``model="metrics"``: the metrics whose GP models ``log(f_i / n_i + 1e-3)``. The settling time
#: jumps where the response touches the 2 % band, and the log makes the jump relatively smaller than
#: the valley; rise time and ITAE grow like ``1 / gain`` towards small gains, which a GP extrapolates
#: better in logs. Overshoot is not logged: it is 0 on a large region, and its log makes that flat
#: region dominate the fit (benchmarks/README.md, the study data_efficiency, has the comparison).
LOG_METRICS = ("settling_time", "rise_time", "itae")

#: With ``settling_model="envelope"``: the times, evenly spaced over the record, at which the error
#: envelope is modelled (the settling time's resolution is the record length over this).
SETTLING_TIMES = 100

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
       marginal likelihood with :class:`~agents.surrogate.GPSurrogate`'s defaults:
       2 random restarts on the first and every 5th fit, warm starts from the previous
       fit, length scales in ``[0.05, 0.5] sqrt(d / 2)`` of the unit box for ``d`` gains, prior hyperparameters
       below 5 points; inputs scaled to the unit box) on the training set ``D`` of eq. (D); query the
       maximiser of Expected Improvement (eq. (LCB), no exploration margin, eq. (EI)):
       by default (``optimizer="auto"``) over a ``grid_points``-per-gain grid of the
       feasible set for one or two gains, and for three gains and more by
       :func:`~agents.acquisition.maximize_multistart` on the unit box (``n_candidates``
       scrambled Sobol points, then L-BFGS-B from the best ``n_starts``). The incumbent
       ``J+`` of EI is the lowest measured cost in ``D`` (the paper's "best-observed
       performance").

    Parameters
    ----------
    n_initial : int, default 1
        Size ``N0`` of the Latin hypercube initial set (the paper uses 1).
    grid_points : int, default 100
        Grid points per gain for maximising EI on the grid (100 x 100 for two gains, the
        paper's dense grid). Above 65536 candidates a scrambled Sobol set of
        65536 points is used instead.
    optimizer : {"auto", "grid", "multistart"}, default "auto"
        How EI is maximised. ``"auto"``: ``"grid"`` for up to :data:`GRID_MAX_GAINS` gains,
        ``"multistart"`` above. ``"grid"``: the grid of ``grid_points`` per gain.
        ``"multistart"``: Sobol candidates and L-BFGS-B in any dimension (seeded per fit,
        so :meth:`propose` stays free of side effects).
    n_candidates : int, default 2048
        With the multistart optimizer: Sobol candidates per maximisation, ``>= 1``.
    n_starts : int, default 8
        With the multistart optimizer: L-BFGS-B starts (the best candidates), ``>= 1``.
    noise_std : float, optional
        Known cost noise ``sigma_eps``, cost units (e.g. from :func:`agents.cost_noise.estimate_noise`);
        ``None`` learns it by marginal likelihood.
    model : {"cost", "metrics"}, default "metrics"
        What is modelled. ``"metrics"``: the paper's "performance metrics modeled by Gaussian
        processes" -- one GP per metric of ``record["metrics"]`` (:data:`agents.result.METRIC_COLUMNS`),
        each on ``f_i / n_i`` with the env's normalizers (in logs for :data:`LOG_METRICS`, combined
        by their log-normal mean and std), combined into the posterior of
        ``J_hat = sum_i w_i f_i / n_i`` (eq. (J_used)) as independent GPs: mean ``sum w_i mu_i``,
        variance ``sum w_i^2 sigma_i^2`` (:mod:`agents.metric_surrogate`, which documents the
        noise model). EI is computed on that mean and std by the same acquisition code; the
        ``"observed"`` incumbent is the lowest ``sum w f / n`` of the measured metrics (the
        additive cost noise is not in them; with ``settling_model="envelope"`` the settling
        time there is the envelope model's own, :meth:`MetricSurrogate.observed_cost
        <agents.metric_surrogate.MetricSurrogate.observed_cost>`). Needs ``env.unwrapped.weights`` and
        ``.normalizers`` (four metrics) at :meth:`setup`; without them, and for any fit where a
        training point has no finite metrics (no record, an unstable experiment, or extra data
        added without ``metrics=``), the cost GP is used. ``"cost"``: one GP on the measured
        costs ``J`` (what guided BO uses, since its twin points carry only costs).
    settling_model : {"gp", "envelope"}, default "gp"
        With ``model="metrics"``: how the settling time is modelled. ``"gp"``: a GP of its own,
        like the other metrics. ``"envelope"``: from GPs on the error envelope of the response
        at :data:`SETTLING_TIMES` times (:mod:`agents.settling`: the settling time as a composite
        of smooth functions, which keeps its jump where the response touches the 2 % band); needs
        the env's step (``env.unwrapped.loop.r1``, ``.r2``, ``.duration``) and the records' ``t``
        and ``y``, else the GP is used. It needs fewer experiments but makes ``ask()`` slower
        (benchmarks/README.md has the figures).
    safe : bool, default False
        Safe mode: every proposal keeps the env's constraints with probability ``PF >= 1 - delta``
        under the constraint GPs (the *lower-confidence-bound safe set*: the gains whose
        ``PF(theta) = prod_j Phi(-mu_j / sigma_j)`` is at least ``1 - delta``, with the acquisition
        ``EI x PF`` maximised inside it; not SafeOpt's expanders and maximisers, which
        ``agents.make("safeopt")`` implements). The first experiments are ``safe_start``; the
        safe set grows from them as the constraint GPs learn. If no candidate is safe, the best
        feasible gains measured are run again. Needs an env with constraints and ``safe_start``.
    safe_start : array_like of shape (m, n_gains) or (n_gains,), optional
        Gains known to keep every constraint, in the env's units (the first ``m`` experiments of
        safe mode, in place of the Latin hypercube).
    delta : float, default 0.05
        Safe mode: the admitted probability that a proposal breaks a constraint, in ``(0, 1)``.

    Attributes
    ----------
    surrogate : GPSurrogate
        The GP; :meth:`fit_surrogate` returns it fitted on the current training set.
    incumbent_rule : {"observed", "posterior_mean"}
        ``J+`` of EI: ``"observed"`` (above), or the lowest posterior mean at the training
        points; guided BO uses ``"posterior_mean"`` during its twin iterations.
    polish : bool
        Whether the best grid point of EI is refined by L-BFGS-B (``False``; guided BO
        polishes during its twin iterations). The multistart optimizer always refines.
    last_ei_, last_std_, last_mean_ : float
        EI (cost units), posterior std and mean of ``J_hat`` at the gains of the
        last :meth:`ask` (``nan`` for initial-design gains).

    Notes
    -----
    On an env with constraints (``gym.make(id, constraints=...)``, read from
    ``env.unwrapped.constraints`` at :meth:`setup`, or from the first record carrying
    ``record["constraints"]`` when driven by ``ask``/``tell``), one GP per constraint models
    its scaled slack (:class:`agents.feasibility.ConstraintModel`; the cost's metric GPs are not
    reused, since an unstable experiment must enter the constraint GPs as a violation while the
    metric GPs leave it out), and the next gains maximise Gardner et al.'s (2014) constrained EI::

        a(theta) = EI(theta; J+_feasible) x PF(theta),   PF(theta) = prod_j Phi(-mu_j(theta) / sigma_j(theta))

    with ``J+_feasible`` the best cost among the experiments that kept every limit; before the
    first feasible experiment, ``PF`` alone is maximised. Without constraints nothing changes.

    The measured data efficiency of these choices (and of the variants that were
    tried and removed: output transforms, hyperparameter priors, other constant
    means, trust-region steps) is in benchmarks/README.md.

    Extension points for guided BO: :meth:`add_data` / :meth:`remove_data` /
    :meth:`extra_data` put twin evaluations in the GP's training set and take
    them out again; :meth:`propose` returns ``(gains, ei, std)`` without
    changing the tuner; :meth:`posterior` gives the GP at any gains;
    :meth:`training_set` may be overridden to change what the GP is fitted on.
    """

    name = "bo"

    _parameter_constraints: dict[str, list] = {
        "n_initial": [Interval(int, 1, None)],
        "grid_points": [Interval(int, 2, None)],
        "noise_std": [None, Interval(float, 0.0, None, closed="neither")],
        "model": [Options(MODELS)],
        "settling_model": [Options(SETTLING_MODELS)],
        "optimizer": [Options(OPTIMIZERS)],
        "n_candidates": [Interval(int, 1, None)],
        "n_starts": [Interval(int, 1, None)],
        "delta": [Interval(float, 0.0, 1.0, closed="neither")],
    }

    def __init__(self, *, n_initial: int = 1, grid_points: int = 100, noise_std: float | None = None,
                 model: str = "metrics", settling_model: str = "gp", optimizer: str = "auto",
                 n_candidates: int = 2048, n_starts: int = 8, safe: bool = False, safe_start=None,
                 delta: float = 0.05) -> None:
        self._params = validate_params(self._parameter_constraints, {
            "n_initial": n_initial, "grid_points": grid_points, "noise_std": noise_std, "model": model,
            "settling_model": settling_model, "optimizer": optimizer, "n_candidates": n_candidates,
            "n_starts": n_starts})
        if not isinstance(safe, bool | np.bool_):
            raise ValueError(f"safe: must be True or False, got {safe!r}")
        self.safe, self.delta = bool(safe), validate_params(self._parameter_constraints, {"delta": delta})["delta"]
        self._run_risk = self.delta  # the safe mode's delta (a subclass may give ``delta`` another meaning)
        self.safe_start = validated_safe_start(safe_start) if safe_start is not None else None
        if self.safe and self.safe_start is None:
            raise ValueError("safe_start: safe=True needs gains known to keep every constraint, e.g. "
                             "safe_start=[[0.3, 1.0]]; without them no experiment is known to be safe")
        if self.safe:  # only what differs from the defaults: unconstrained specs keep their parameters
            self._params.update({"safe": True, "safe_start": self.safe_start.tolist(), "delta": self.delta})
        self.n_initial = self._params["n_initial"]
        self.grid_points = self._params["grid_points"]
        self.noise_std = self._params["noise_std"]
        self.model = self._params["model"]
        self.settling_model = self._params["settling_model"]
        self.optimizer = self._params["optimizer"]
        self.n_candidates = self._params["n_candidates"]
        self.n_starts = self._params["n_starts"]
        self.incumbent_rule = "observed"
        self.polish = False

    # -- Tuner hooks ---------------------------------------------------------------------------------
    def _setup(self) -> None:
        dim = self.space.dim
        # Latin hypercube initial set Theta_init of size N0 (paper, subsec. BO), unit box.
        self._initial = qmc.LatinHypercube(d=dim, rng=self.rng).random(self.n_initial)
        self._optimizer_in_use = self.optimizer if self.optimizer != "auto" else \
            ("grid" if dim <= GRID_MAX_GAINS else "multistart")
        # the grid (or its Sobol stand-in) only where EI is maximised on it
        self._unit_grid = _unit_candidates(dim, self.grid_points, self.rng) \
            if self._optimizer_in_use == "grid" else None
        self._fit_seed = int(self.rng.integers(2**31))
        self.surrogate = GPSurrogate(noise_std=self.noise_std)
        self.metric_surrogate: MetricSurrogate | None = None
        if self.model == "metrics":
            env = getattr(self.env, "unwrapped", self.env)
            weights, normalizers = getattr(env, "weights", None), getattr(env, "normalizers", None)
            if weights is not None and normalizers is not None and np.size(weights) == len(METRIC_COLUMNS):
                # the metric GPs: same kernel and fitting options as the cost GP; the metrics are
                # modelled noise-free-ish (their own learned noise), the cost noise is added at J level
                self.metric_surrogate = MetricSurrogate(
                    weights, normalizers, log_metrics=[METRIC_COLUMNS.index(name) for name in LOG_METRICS],
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
        self._plant_feasible: list[bool | None] = []
        known = constraint_set(self.env)
        self.constraint_model = None if known is None else ConstraintModel(*known)
        if self.safe:
            if self.constraint_model is None and self.env is not None:
                raise ValueError("safe: safe=True needs an env with constraints, e.g. "
                                 "gym.make(id, constraints={'overshoot_pct': 2.0})")
            if self.safe_start.shape[1] != dim:
                raise ValueError(f"safe_start: need gains of {dim} values each, got shape {self.safe_start.shape}")
            for row in self.safe_start:
                self.space.check(row, name="safe_start")

    def _ask(self) -> np.ndarray:
        n = len(self._plant_y)
        if self.safe and n < self.safe_start.shape[0]:
            self.last_ei_ = self.last_std_ = self.last_mean_ = float("nan")
            return self.safe_start[n].copy()
        if n < self.n_initial and not self.safe:
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
        if self.constraint_model is None and record and record.get("constraints"):  # ask/tell without an env
            names = tuple(record["constraints"])
            self.constraint_model = ConstraintModel(names, np.zeros(len(names)))
        feasible = None if self.constraint_model is None else \
            self.constraint_model.add(self.space.to_unit(gains), record)
        self._plant_feasible.append(feasible)
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
        times = np.linspace(loop.duration / SETTLING_TIMES, loop.duration, SETTLING_TIMES)
        return SettlingTimeModel(times, normalizer=normalizer)

    def _record_envelope(self, record: dict | None) -> np.ndarray | None:
        """:func:`agents.settling.error_envelope` of a record, or None (no settling model, no trajectories)."""
        settling = None if self.metric_surrogate is None else self.metric_surrogate.settling
        if settling is None or not record or record.get("unstable", False) or "t" not in record \
                or "y" not in record:
            return None
        loop = getattr(self.env, "unwrapped", self.env).loop  # the step r1 -> r2 (checked in _settling_model)
        envelope = error_envelope(record["t"], record["y"], loop.r1, loop.r2, settling.times)
        return envelope if np.all(np.isfinite(envelope)) else None

    def metric_prior(self):
        """Prior mean of the metric GPs (:class:`agents.metric_surrogate.MetricPrior`), ``None`` here.

        ``None`` gives every metric GP a constant prior mean. Guided BO returns its twin's metrics
        (:class:`agents.twin.prior.TwinMetrics`); a subclass that changes its prior must call
        :meth:`_data_changed` so that the surrogate is refitted.
        """
        return None

    def _data_changed(self) -> None:
        """Mark the surrogate stale: the next :meth:`fit_surrogate` refits it."""
        self._version += 1

    @property
    def optimizer_in_use(self) -> str:
        """``"grid"`` or ``"multistart"``: how EI is maximised (``optimizer`` resolved at :meth:`setup`)."""
        return self._optimizer_in_use

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
                                                        envelopes=self.envelope_training_set(),
                                                        prior=self.metric_prior())
                self._model_in_use = "metrics"
            else:
                self._model = self.surrogate.fit(X, y, seed=seed, optimize=self._optimize_hyperparameters)
                self._model_in_use = "cost"
            self._fitted_version = self._version
        return self._model

    def incumbent(self) -> float:
        """``J+`` of EI over the current training set, by :attr:`incumbent_rule` (see the class doc)."""
        model = self.fit_surrogate()
        X, y = self.training_set()
        kept = self._kept_mask(y.size)
        if self.incumbent_rule == "observed":
            if self._model_in_use == "metrics":
                # J_hat of the measured metrics, sum w f / n: the best observed noise-free-ish cost
                # (the cost noise epsilon is not in the metrics the composite model is fitted on),
                # with the envelope model's own settling time where it models it
                X_metrics, metrics, _ = self.metric_training_set()
                return float(np.min(self.metric_surrogate.observed_cost(model, X_metrics, metrics)[kept]))
            return float(np.min(y[kept]))  # J+_n, best observed cost (paper, eq. (LCB))
        return float(np.min(model.predict(X)[0][kept]))

    def _kept_mask(self, n: int) -> np.ndarray:
        """Training points that count for the incumbent: with constraints, the feasible plant experiments
        (extra points count as kept); all points without constraints."""
        mask = np.ones(n, dtype=bool)
        if self.constraint_model is not None:
            mask[: len(self._plant_feasible)] = [bool(f) for f in self._plant_feasible]
        return mask

    @property
    def constrained(self) -> bool:
        """Whether the proposals model constraints (the env has them and an experiment reported them)."""
        return self.constraint_model is not None and self.constraint_model.n_observations > 0

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
        if self.safe and not self.constrained:
            raise ValueError("safe: safe=True needs experiments that report their constraints "
                             "(record['constraints']); none did")
        if self.constrained:
            acquisition = self._constrained_acquisition(model)
        else:
            acquisition = ExpectedImprovement(model, self.incumbent())
        unit_box = np.column_stack([np.zeros(self.space.dim), np.ones(self.space.dim)])
        if self._optimizer_in_use == "grid":
            x, ei = maximize_on_grid(acquisition, self._unit_grid, polish=self.polish, bounds=unit_box)
        else:
            rng, n_starts = self.multistart_plan()
            x, ei = maximize_multistart(acquisition, unit_box, rng, n_candidates=self.n_candidates, n_starts=n_starts)
        if self.safe and ei < 0.0:  # no candidate in the safe set: repeat the best feasible experiment
            x = self._best_kept_point()
            ei = float(acquisition(x[None, :])[0])
        std = float(model.predict(x[None, :])[1][0])
        return self.space.from_unit(x), float(ei), std

    def multistart_plan(self) -> tuple[np.random.Generator, int]:
        """The multistart optimizer's Sobol scramble and its number of L-BFGS-B starts for the next maximisation.

        Here: seeded by the fit's data version (the same data give the same proposal; every fit draws new
        candidates) and ``n_starts``. Guided BO's twin prior replaces both (:meth:`GuidedBO.multistart_plan
        <agents.guided_bo.GuidedBO.multistart_plan>`).
        """
        return np.random.default_rng([self._fit_seed, self._version, 1]), self.n_starts

    def _constrained_acquisition(self, model) -> ConstrainedAcquisition:
        """``EI x PF`` over the best feasible cost, ``PF`` alone before a feasible experiment (class doc)."""
        self.constraint_model.fit(seed=int(np.random.default_rng([self._fit_seed, self._version, 2]).integers(2**31)))
        any_kept = bool(np.any(self._kept_mask(self.training_set()[1].size)))
        ei = ExpectedImprovement(model, self.incumbent()) if any_kept else None
        return ConstrainedAcquisition(ei, self.constraint_model, self.safe_level() if self.safe else None)

    def safe_level(self) -> float:
        """Safe mode: the least ``PF`` of the next proposal, ``1 - delta_t`` with ``delta_t`` the run's risk
        split over its experiments (:func:`agents.feasibility.run_risk`, ``t`` the next experiment's number)."""
        return 1.0 - run_risk(self._run_risk, self.n_observations + 1)

    def _best_kept_point(self) -> np.ndarray:
        """Unit-box gains of the lowest-cost feasible plant experiment."""
        kept = [i for i, f in enumerate(self._plant_feasible) if f]
        if not kept:
            raise RuntimeError(f"{self.name}: no experiment kept the constraints, so none is known to be safe; "
                               "check that safe_start keeps every limit")
        return self._plant_X[min(kept, key=lambda i: self._plant_y[i])].copy()

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
