r"""The digital twin's life cycle in a tuning run: its data set, noise floor, fits, refit rules and trust.

A tuner that uses a twin (:class:`agents.guided_bo.GuidedBO`, :class:`agents.mf_bo.MultiFidelityBO`)
tells every plant experiment to one :class:`TwinKeeper` and asks it for the twin
(:meth:`TwinKeeper.twin_env`: the plant's closed loop around the twin, evaluated at any
gains). The keeper's rules, with ``s`` the median noise floor of the records over the step
height ``|r2 - r1|`` and ``e = 2 max(s, 10^-3)`` the RMSE the noise explains:

* **Data set** (eq. (Ds)). Every stable, finite record ``(u, y)`` enters ``D~``; ``D~``
  restarts from the new record when ``|J - J~| / J > delta`` (eq. (reinit_DTdataset)). With
  ``twin="auto"`` or a given twin the miss reads as a plant change only if the twin simulated
  at least :data:`PLANT_CHANGE_RECORDS` records within ``e``; otherwise it calls for a refit on
  every record. With ``refit_on_cost_miss``, a cost ``> 3 sigma_eps`` off the twin's calls for
  a refit once the records have doubled since the fit.
* **Fits.** The twin is fitted when first asked for, and refitted when its RMSE on the records
  added since the fit exceeds ``max(1.5 rmse_, e)`` (the linear twin:
  ``max(1.5 rmse_, eta2 / 4)``), warm-started. ``twin="auto"`` starts from the paper's SRIVC
  twin; a refitted twin whose ``rmse_ > e`` is diagnosed
  (:func:`agents.twin.selection.diagnosed_twins`, at most :data:`MAX_TWIN_EFFECTS` effects) at
  1, 2, 4 and 8 records (:data:`MAX_DIAGNOSED_RECORDS`), each time from the linear model; from
  :data:`COST_SELECTION_RECORDS` records on, so is a twin with effects that missed a cost, and a
  diagnosis keeps, of the ladder's twin and the single-effect twins that also replay ``D~`` within
  ``e``, the one whose closed loop predicts the measured costs best. A twin with effects is kept
  only while it predicts them better than the linear twin (RMS relative error
  ``sqrt(mean_i ((J~(theta_i) - J_i) / J_i)^2)``).
* **Plant changes.** Let ``m`` be the records of ``D~`` a twin simulated within ``e``. When the
  twin refitted on all of ``D~`` no longer does, but one of its structure fitted on the records
  after the ``m``-th (at least :data:`PLANT_CHANGE_RECORDS`) does, ``D~`` keeps those records only.
* **Noise.** Beyond the paper's linear twin the twin env adds white output noise of std
  ``s |r2 - r1|`` (above :data:`SIMULATED_NOISE_FLOOR`), its cost the mean over
  :data:`TWIN_NOISE_DRAWS` fixed draws; eq. (DT_rmse1)'s threshold is ``eta2 = 3 max(s, 10^-3)``
  (the linear twin: ``3 sigma_eps``).
* **Trust.** A twin-proposed ``theta_T`` that promised ``J~(theta_I) - J~(theta_T)`` over the
  incumbent ``theta_I`` loses trust when the plant delivers ``mu(theta_I) - J(theta_T) <
  min(promised, 0) - 2 sqrt(2) sigma_eps``; a refit restores it when the refitted twin no longer
  promises that much, or was fitted on twice the records it had when it lost trust.

docs/design.md ("Which twin drives guided BO") gives the reasons and the measured cases.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping
from typing import Any

import numpy as np
from sklearn.base import clone

from agents.parameters import HasMethods, Interval, Options, validate_params
from agents.twin import make_twin_env
from agents.twin.greybox_twin import GreyBoxTwin
from agents.twin.identify import IdentifyOptions, SrivcOptions
from agents.twin.linear_twin import LinearTwin
from agents.twin.model import ModelSpec
from agents.twin.noise_floor import noiseless_quantum
from agents.twin.prior import TwinMetrics, TwinSimulation
from agents.twin.records import Batch, as_records
from agents.twin.selection import diagnosed_twins, measurement_noise
from gbo_envs.experiment import SIGNALS, Experiment
from gbo_envs.physics.sensor import Quantization

__all__ = ["COST_SELECTION_RECORDS", "MAX_DIAGNOSED_RECORDS", "MAX_TWIN_EFFECTS", "PLANT_CHANGE_RECORDS",
           "RMSE_FLOOR", "SIMULATED_NOISE_FLOOR", "TWIN_CHOICES", "TWIN_NOISE_DRAWS", "TwinKeeper"]

#: ``twin`` by name: the workbench-diagnosed grey-box twin, or the paper's linear SRIVC twin.
TWIN_CHOICES = ("auto", "linear")

#: Effects at most in a diagnosed twin (the workbench's ladder, two rungs).
MAX_TWIN_EFFECTS = 2

#: Records in ``D~`` beyond which the effects are settled: no further diagnosis, only warm refits.
MAX_DIAGNOSED_RECORDS = 8

#: Records in ``D~`` from which a diagnosis chooses among twins that replay them within the noise by their costs.
COST_SELECTION_RECORDS = 4

#: Records a twin must have simulated within the noise before a cost miss, or a later twin, reads as a plant change.
PLANT_CHANGE_RECORDS = 2

#: Noise draws ``K`` of the twin's expected cost (:class:`agents.twin.TwinEnv`).
TWIN_NOISE_DRAWS = 8

#: The twin reproduces the measurement noise when its floor exceeds this fraction of the step height.
SIMULATED_NOISE_FLOOR = 1e-4

#: Lower bound of the noise floor in eq. (DT_rmse1), a fraction of the step height: with ``eta2 = 3``
#: a plant quieter than this gets the paper's absolute threshold 0.003.
RMSE_FLOOR = 1e-3

#: What a failed identification or simulation raises: no twin this time.
_FIT_ERRORS = (ValueError, FloatingPointError, np.linalg.LinAlgError)


class TwinKeeper:
    r"""The twin of a tuning run: ``tell`` it every plant experiment, ask it for :meth:`twin_env`.

    Parameters
    ----------
    twin : {"auto", "linear"} or estimator, default "auto"
        ``"auto"``: the SRIVC twin plus the effects the records evidence; ``"linear"``: the
        paper's SRIVC twin, noise-free, always trusted; or an estimator with ``fit`` and
        ``get_params`` (:class:`~agents.twin.LinearTwin`, :class:`~agents.twin.GreyBoxTwin`),
        fitted on the records, or, if fitted (it has ``plant_``), used as given until it mispredicts.
    twin_poles : int, default 2
        Poles of the twin's transfer function (>= 1; no zeros).
    n_samples : int or None, default 100
        Samples per record kept for identification, eq. (Ds)'s ``n~`` (>= 10; ``None``: all).
    delta : float, default 2.0
        Relative cost miss of eq. (reinit_DTdataset) that restarts ``D~`` (dimensionless, >= 0).
    eta2 : float, optional
        Threshold of eq. (DT_rmse1) on the twin's normalised ``rmse_`` (> 0). Default: see :attr:`eta2_`.
    noise_std : float, optional
        ``sigma_eps``, cost units (> 0). Default: see :attr:`sigma_eps`.
    refit_on_cost_miss : bool, default False
        Whether a cost ``> 3 sigma_eps`` off the twin's calls for a refit once the records have doubled.

    Attributes
    ----------
    twin_ : estimator or None
        The current fitted twin.
    changes_ : list of dict
        One entry per twin fit: ``experiment`` (plant experiments told), ``model``, ``effects``,
        ``params``, ``rmse`` (on ``D~``), ``previous_rmse`` (the former twin on the new records,
        ``None`` for the first) and ``text`` (one line, as ``gbo tune`` prints it).
    reinitializations_ : int
        Restarts of ``D~``: by eq. (reinit_DTdataset), or on a plant change read on the responses.
    distrusts_ : int
        Twin promises the plant broke.

    Examples
    --------
    >>> import gymnasium as gym, numpy as np, gbo_envs, agents
    >>> from agents.twin_keeper import TwinKeeper
    >>> env = gym.make("gbo_envs/DCMotor-v0")
    >>> keeper = TwinKeeper(twin="linear")
    >>> keeper.setup(agents.GainSpace.from_env(env), env.unwrapped)
    >>> _ = env.reset(seed=0)
    >>> info = env.step(np.array([0.5, 1.2]))[4]
    >>> keeper.tell(info["gains"], info["cost"], info)
    >>> keeper.twin_env().evaluate(np.array([[0.5, 1.2], [0.9, 1.6]]))[1].shape
    (2,)
    """

    _parameter_constraints: dict[str, list] = {
        "twin": [Options(TWIN_CHOICES), HasMethods(("fit", "get_params"))],
        "twin_poles": [Interval(int, 1, None)],
        "n_samples": [None, Interval(int, 10, None)],
        "delta": [Interval(float, 0.0, None)],
        "eta2": [None, Interval(float, 0.0, None, closed="neither")],
        "noise_std": [None, Interval(float, 0.0, None, closed="neither")],
    }

    def __init__(self, twin="auto", *, twin_poles: int = 2, n_samples: int | None = 100, delta: float = 2.0,
                 eta2: float | None = None, noise_std: float | None = None, refit_on_cost_miss: bool = False) -> None:
        params = validate_params(self._parameter_constraints, {
            "twin": twin, "twin_poles": twin_poles, "n_samples": n_samples, "delta": delta, "eta2": eta2,
            "noise_std": noise_std})
        if not isinstance(refit_on_cost_miss, bool):
            raise ValueError(f"refit_on_cost_miss: must be a bool, got {refit_on_cost_miss!r}")
        self.twin = twin
        self.twin_poles, self.n_samples, self.delta = params["twin_poles"], params["n_samples"], params["delta"]
        self.eta2, self.noise_std = params["eta2"], params["noise_std"]
        self.refit_on_cost_miss = refit_on_cost_miss

    def setup(self, space, env, constraints=None) -> None:
        """Start a run (forgets every record) on the feasible set ``space`` of the plant env ``env``.

        Parameters
        ----------
        space : agents.GainSpace
        env : gbo_envs.ControllerTuningEnv
            The unwrapped plant env: its closed loop is the twin's (``env.loop``).
        constraints : gbo_envs.constraints.Constraints, optional
            Limits that :meth:`twin_simulation` judges on the twin's simulated records too
            (guided BO's safety filter); ``None``: the metrics alone.
        """
        if not hasattr(env, "loop"):
            raise ValueError("env: the twin keeper needs the unwrapped plant env, with its closed loop (env.loop)")
        self.space, self._env, self._constraints = space, env, constraints
        self._step_height = abs(float(env.loop.r2) - float(env.loop.r1)) or 1.0
        self._records: list[Experiment] = []  # D~ with the gains and costs told, each record's index its place in it
        self._stacked: dict[int | None, Batch] = {}  # D~ as one Batch per n_samples, stacked when first fitted on
        self._costs: list[float] = []  # every cost told
        self._noise_floors: list[float] = []
        self._quanta: list[float | None] = []  # each record's resolution if quantized without visible noise
        self._fitted_on = 0  # records in D~ when the twin was last fitted
        self._diagnosed_on = 0  # records in D~ at the last diagnosis (twin="auto")
        self._explained_upto = 0  # the first records of D~ that a twin simulated within the noise
        self._dirty = self._cost_missed = False
        self._promise = None  # (theta_T, theta_I, mu(theta_I), promised improvement) of the last twin proposal
        self._broken = None  # (theta_T, theta_I, delivered improvement, records) of the promise that failed
        self._linear = None  # the SRIVC twin of twin="auto", refitted in place (warm start)
        self._twin_env = None
        self._simulation = None  # the current twin's TwinSimulation
        self._metrics = None  # the current twin's TwinMetrics (reading self._simulation)
        self._retired_simulations = 0  # simulations of former twins (their TwinSimulation and TwinMetrics)
        self._events: list[str] = []
        self.twin_ = None
        self.changes_: list[dict] = []
        self.reinitializations_ = 0
        self.distrusts_ = 0
        if not isinstance(self.twin, str) and hasattr(self.twin, "plant_"):
            self.twin_ = self.twin  # a fitted twin: used as given until it mispredicts
            self._record_change(None)

    # -- what the tuner tells and asks ---------------------------------------------------------------
    def tell(self, gains, cost: float, record: Experiment | Mapping | None) -> None:
        """A plant experiment: its gains (physical units), measured cost and record.

        Checks the last promise (see "Trust" in the module doc), then adds the record to ``D~``
        (eq. (Ds)) unless it diverged or has no signals.

        Parameters
        ----------
        gains : array_like of shape (n_gains,)
        cost : float
            The measured cost ``J``, dimensionless.
        record : Experiment, mapping or None
            The experiment (:class:`~gbo_envs.Experiment`), or an env ``info`` (its ``"experiment"``,
            not kept if ``info["unstable"]``); ``None``: a cost without a record.
        """
        gains = np.asarray(gains, dtype=float)
        self._costs.append(float(cost))
        self._check_promise(gains, cost)
        new = _identifiable(record)
        if new is None:
            return  # nothing to identify from (or a diverging response)
        # eq. (Ds): D~ <- D~ u {(u_i, y_i)}, with the gains and cost as told (a wrapper may edit the cost), the
        # record numbered by its place in D~; validated here once (as_records), stacked unchecked (Batch.stack)
        new = as_records(new, min_steps=3)[0].replace(gains=gains, cost=float(cost), index=len(self._records))
        if self.twin != "linear":
            single = Batch.stack([new])
            self._noise_floors.append(measurement_noise(single) / self._step_height)
            self._quanta.append(noiseless_quantum(single))
        if self._twin_env is not None:
            # eq. (reinit_DTdataset): the last fitted twin's estimate of this experiment against the measurement
            predicted = float(self._twin_env.evaluate(gains[None, :])[1][0])
            missed = not np.isfinite(predicted) or abs(cost - predicted) / max(abs(cost), 1e-12) > self.delta
            if missed and not self._explained_its_records():
                self._cost_missed = True  # the twin was wrong, not the plant changed: refit on every record
            elif missed:
                self._reinitialise(len(self._records))
            elif self.refit_on_cost_miss and abs(cost - predicted) > 3.0 * self.sigma_eps:
                self._cost_missed = True  # the twin's cost is off by more than the cost noise explains
        self._records.append(new)
        self._stacked = {}
        self._dirty = True

    def twin_env(self):
        """The plant's closed loop around the current twin (:class:`agents.twin.TwinEnv`), refitted on ``D~`` if due.

        ``evaluate(gains)`` gives the twin's expected metrics and cost at any gains of shape
        (m, n_gains). ``None`` before the first record, or while the records identify no twin.
        """
        self._current_twin()
        if self._twin_env is None and self.twin_ is not None:
            self._twin_env = self._env_for(self.twin_)
        return self._twin_env

    def can_guide(self) -> bool:
        """Whether the twin may guide: fitted (refitted if due), ``rmse_ < eta2`` (eq. (DT_rmse1)) and trusted."""
        twin = self._current_twin()
        if twin is None or not np.isfinite(twin.rmse_) or twin.rmse_ >= self.eta2_:
            return False
        return self.trusted

    def twin_simulation(self) -> TwinSimulation | None:
        """The current twin's noise-free simulations (metrics, cost and the setup's constraint slacks), cached per twin.

        A :class:`~agents.twin.prior.TwinSimulation`: each gain simulated once per twin, read by
        :meth:`twin_metrics` and by guided BO's safety filter; ``None`` without a twin.
        """
        twin_env = self.twin_env()
        if twin_env is None:
            return None
        if self._simulation is None or self._simulation.twin_env is not twin_env:
            self._retired_simulations += self._current_simulations()
            self._simulation, self._metrics = TwinSimulation(twin_env, self._constraints), None
        return self._simulation

    def twin_metrics(self) -> TwinMetrics | None:
        """The current twin's raw metrics ``f~(X)`` at unit-box gains ``X`` of shape (m, n_gains), cached per twin.

        A :class:`~agents.twin.prior.TwinMetrics` reading :meth:`twin_simulation`: any ``X`` (the
        acquisition grid or any other points), each row simulated once per twin; ``None`` without a twin.
        """
        simulation = self.twin_simulation()
        if simulation is None:
            return None
        if self._metrics is None:
            self._metrics = TwinMetrics(simulation, self.space)
        return self._metrics

    def _current_simulations(self) -> int:
        """Simulations of the current twin: its noise-free ones, and its prior's expected ones."""
        if self._metrics is not None:
            return self._metrics.simulations_
        return 0 if self._simulation is None else self._simulation.simulations_

    def twin_cost(self, gains) -> float:
        """The last fitted twin's expected cost at one gain vector (physical units), ``unstable_cost`` if it diverges.

        Raises
        ------
        ValueError
            Before a twin was fitted (see :meth:`twin_env`).
        """
        if self._twin_env is None:
            raise ValueError("twin_cost: no twin fitted yet; tell() a record and call twin_env() first")
        return _expected_cost(self._twin_env, gains)

    @property
    def metric_simulations_(self) -> int:
        """Twin simulations made by :meth:`twin_simulation` and :meth:`twin_metrics` so far, over every twin."""
        return self._retired_simulations + self._current_simulations()

    @property
    def records_(self) -> tuple[Experiment, ...]:
        """``D~``: the records the twin is fitted on, oldest first (``index``: the place in ``D~``, from 0)."""
        return tuple(self._records)

    @property
    def n_told_(self) -> int:
        """Plant experiments told."""
        return len(self._costs)

    @property
    def sigma_eps(self) -> float:
        """``sigma_eps``: ``noise_std``, else the env's ``cost_noise_std``, else 1 % of the mean cost told."""
        if self.noise_std is not None:
            return float(self.noise_std)
        declared = float(getattr(self._env, "cost_noise_std", 0.0) or 0.0)
        if declared > 0.0:
            return declared
        y = np.asarray(self._costs, dtype=float)
        return 0.01 * float(np.mean(np.abs(y))) if y.size else 0.01

    @property
    def noise_floor_(self) -> float:
        """``s``: median noise floor of the records over the step height (0 before any, and for the linear twin)."""
        return float(np.median(self._noise_floors)) if self._noise_floors else 0.0

    @property
    def sensor_quantum_(self) -> float | None:
        """The output's resolution (units of ``y``) if most records show it quantized without visible noise, else
        ``None`` (and for the linear twin).

        White noise of the floor's std ``q / sqrt(12)`` is not such a sensor: its maxima exceed the reference where
        the rounding does not, which adds overshoot and settling time to every twin response (on
        LinearMotorCascade-v0's 5 um encoder, 16 random gains: the noisy twin's costs a median 25 % above the
        plant's, the rounding twin's within 0.2 %; where a response peaks within a level of the reference, one
        level of overshoot more or less still separates them).
        """
        quanta = [q for q in self._quanta if q is not None]
        if not quanta or 2 * len(quanta) <= len(self._quanta):
            return None
        return float(np.median(quanta))

    @property
    def explained_rmse_(self) -> float:
        """The normalised RMSE that measurement noise explains: ``2 max(s, 10^-3)``."""
        return 2.0 * max(self.noise_floor_, RMSE_FLOOR)

    @property
    def eta2_(self) -> float:
        """Threshold of eq. (DT_rmse1): ``eta2``, else ``3 max(s, 10^-3)`` (the linear twin: ``3 sigma_eps``)."""
        if self.eta2 is not None:
            return float(self.eta2)
        if self.twin == "linear":
            return 3.0 * self.sigma_eps
        return 3.0 * max(self.noise_floor_, RMSE_FLOOR)

    # -- trust ------------------------------------------------------------------------------------------
    @property
    def judges_trust(self) -> bool:
        """Whether the twin's promises are checked (not the paper's linear twin, which is always trusted)."""
        return self.twin != "linear"

    @property
    def trusted(self) -> bool:
        """Whether the twin may propose plant experiments (see "Trust" in the module doc)."""
        return self._broken is None

    def promise(self, gains, cost: float, incumbent, incumbent_mean: float) -> None:
        """The twin proposes ``gains``, its cost ``cost``, over the incumbent ``theta_I`` (GP mean ``incumbent_mean``).

        The next :meth:`tell` at ``gains`` compares the promised improvement ``J~(theta_I) - cost``
        with the delivered one, ``incumbent_mean - J`` (see "Trust" in the module doc).
        """
        incumbent = np.asarray(incumbent, dtype=float)
        promised = self.twin_cost(incumbent) - cost
        self._promise = (np.array(gains, dtype=float), incumbent, float(incumbent_mean), promised)

    def _check_promise(self, gains: np.ndarray, cost: float) -> None:
        promise, self._promise = self._promise, None
        if promise is None or not np.allclose(gains, promise[0]):
            return
        _, incumbent, incumbent_mean, promised = promise
        delivered = incumbent_mean - float(cost)
        # worse than promised and worse than the incumbent, each beyond the noise of a difference
        if delivered < min(promised, 0.0) - self._difference_noise:
            self._broken = (promise[0], incumbent, delivered, max(len(self._records), 1))
            self.distrusts_ += 1

    def _restore_trust(self) -> None:
        """After a refit: trusted again if the twin no longer promises the improvement that failed, or if it was
        refitted on at least twice the records it had when it lost trust."""
        if self._broken is None or self._twin_env is None:
            return
        failed, incumbent, delivered, records = self._broken
        if len(self._records) >= 2 * records:
            self._broken = None
            return
        promised = self.twin_cost(incumbent) - self.twin_cost(failed)
        if promised <= delivered + self._difference_noise:
            self._broken = None

    @property
    def _difference_noise(self) -> float:
        """Two standard deviations of a difference of two cost measurements, ``2 sqrt(2) sigma_eps``."""
        return 2.0 * np.sqrt(2.0) * self.sigma_eps

    # -- fits -------------------------------------------------------------------------------------------
    def _current_twin(self):
        """The twin fitted on ``D~``, refitted only when it mispredicts records added since its last fit."""
        new = self._records[self._fitted_on:]
        previous_rmse = None  # the current twin's error on the records added since its fit
        scored = False
        if self._dirty and self.twin_ is not None:
            if not new:
                self._dirty = False
            elif self.trusted:
                previous_rmse, scored = self._error_on(new), True
                # with the cost rule, also when its cost missed and the records have doubled since its fit
                doubled = len(self._records) >= 2 * self._fitted_on
                self._dirty = self._mispredicts(previous_rmse) or (self._cost_missed and doubled)
                if not self._dirty:
                    self._note_explained()
            else:  # a distrusted twin is refitted when the records have doubled since its fit (more excitation)
                self._dirty = len(self._records) >= 2 * self._fitted_on
        if self._dirty and self._records:
            previous = self.twin_
            if previous is not None and new and not scored:
                previous_rmse = self._error_on(new)
            try:
                twin = self._fit(previous)
                twin = self._twin_of_a_changed_plant(twin) or twin
                self.twin_ = twin if np.isfinite(twin.rmse_) else None
            except _FIT_ERRORS:
                self.twin_ = None  # too little excitation to identify: no twin this time
            self._note_explained()
            self._twin_env = None
            self._dirty = self._cost_missed = False
            self._fitted_on = len(self._records)
            if self.twin_ is not None:
                self._record_change(previous_rmse)
                self._twin_env = self._env_for(self.twin_)
                self._restore_trust()
        return self.twin_

    def _error_on(self, new: list[Experiment]) -> float | None:
        """The current twin's normalised RMSE on new records; ``None`` if it cannot simulate them."""
        try:
            return float(-self.twin_.score(new))
        except _FIT_ERRORS:
            return None

    def _mispredicts(self, error: float | None) -> bool:
        """Whether the twin's RMSE on new records exceeds what noise and its own fit error explain."""
        if error is None:
            return True
        if self.twin == "linear":
            return not error <= max(1.5 * self.twin_.rmse_, 0.25 * self.eta2_)
        return not error <= max(1.5 * self.twin_.rmse_, self.explained_rmse_)

    def _explained_its_records(self) -> bool:
        """Whether the twin simulated at least :data:`PLANT_CHANGE_RECORDS` records it was fitted on within the noise
        (the paper's linear twin always counts as having done so: eq. (reinit_DTdataset) unchanged)."""
        if self.twin == "linear" or self.twin_ is None:
            return True
        return self._fitted_on >= PLANT_CHANGE_RECORDS and self.twin_.rmse_ <= self.explained_rmse_

    def _twin_of_a_changed_plant(self, twin):
        """``D~`` re-initialised with the records after the explained ones and their twin, if they show a plant
        change (see "Plant changes" in the module doc); otherwise ``None``."""
        start = self._explained_upto
        later = self._records[start:]
        explained = self.explained_rmse_
        if self.twin == "linear" or start == 0 or len(later) < PLANT_CHANGE_RECORDS or twin.rmse_ <= explained:
            return None
        try:
            candidate = clone(twin).fit(later)
        except _FIT_ERRORS:
            return None  # the later records identify no twin: keep the one of all records
        if not candidate.rmse_ <= explained:
            return None  # no single plant explains the later records either: a missing effect, not a change
        self._reinitialise(start)
        return candidate

    def _reinitialise(self, start: int) -> None:
        """``D~`` restarts from its records after the first ``start`` (eq. (reinit_DTdataset), or a plant change)."""
        self._records = [record.replace(index=k) for k, record in enumerate(self._records[start:])]
        self._stacked = {}
        self._fitted_on = self._diagnosed_on = self._explained_upto = 0
        self.reinitializations_ += 1

    def _note_explained(self) -> None:
        """Record that the current twin simulates every record of ``D~`` within the noise, if it does."""
        if self.twin != "linear" and self.twin_ is not None and self.twin_.rmse_ <= self.explained_rmse_:
            self._explained_upto = len(self._records)

    def _fit(self, previous):
        """A twin fitted on ``D~``: diagnosed (``"auto"``), the paper's linear one, or the given estimator."""
        if self.twin == "auto":
            effects = getattr(previous, "effect_params_", None) or {}
            # the current structure first: the paper's SRIVC twin, or the diagnosed effects from their last values
            twin = clone(previous).fit(self._data_for(previous)) if effects else self._linear_twin()
            n = len(self._records)
            doubled = n >= 2 * self._diagnosed_on and self._diagnosed_on < MAX_DIAGNOSED_RECORDS
            due = self._diagnosed_on == 0 or doubled
            # effects that replay the records but missed a cost: another twin may replay them as well and close the
            # loop right, which the costs of COST_SELECTION_RECORDS records can tell
            recheck = bool(effects) and self._cost_missed and n >= COST_SELECTION_RECORDS
            if due and not effects and not twin.rmse_ <= self.explained_rmse_:  # decimation, or a missing effect?
                twin = self._whole_record_twin(twin)
            cost_error = functools.cache(self._cost_error)  # each twin's closed loop simulated once per fit
            if due and (recheck or not twin.rmse_ <= self.explained_rmse_):  # an error the noise does not explain
                twin = self._diagnosed(twin, cost_error)
            if getattr(twin, "effect_params_", None):
                linear = self._linear_twin()  # refitted in place, so its error is not the cached one
                if self._cost_error(linear) < cost_error(twin):
                    twin = linear  # the effects replay the records but mispredict the experiments' costs
            return twin
        template = self._default_twin() if self.twin == "linear" else self.twin
        twin = previous if previous is not None and previous is not self.twin else clone(template)
        return twin.fit(self._data_for(twin))  # warm start

    def _diagnosed(self, twin, cost_error):
        """The diagnosed twin of ``D~`` if it replays the records better than ``twin``; from
        :data:`COST_SELECTION_RECORDS` records on, of it, ``twin`` and the single-effect twins that replay them within
        the noise, the one whose closed loop predicts the measured costs best (``cost_error``: :meth:`_cost_error`)."""
        spec = ModelSpec(n_poles=self.twin_poles, n_integrators=self._integrators(), output=self._env.loop.plant.output)
        self._diagnosed_on = len(self._records)
        # from the linear model, not from the current effects: the ladder only adds effects, and one that
        # fewer records evidenced (a wrong one, when the true effect showed in only one of them) is dropped
        diagnosed, *alternatives = diagnosed_twins(self._batch(self.n_samples), spec, within=self.explained_rmse_,
                                                   max_effects=MAX_TWIN_EFFECTS, n_samples=self.n_samples)
        best = diagnosed if diagnosed.rmse_ < twin.rmse_ else twin
        if not alternatives or len(self._records) < COST_SELECTION_RECORDS:
            return best
        return min((best, *alternatives), key=cost_error)

    def _batch(self, n_samples: int | None = None) -> Batch:
        """``D~`` as one :class:`~agents.twin.records.Batch` decimated to ``n_samples`` per record (``None``: whole),
        stacked once per state of ``D~`` from the records :meth:`tell` validated
        (:meth:`~agents.twin.records.Batch.stack`)."""
        if n_samples not in self._stacked:
            self._stacked[n_samples] = Batch.stack(self._records, n_samples=n_samples)
        return self._stacked[n_samples]

    def _data_for(self, twin):
        """``D~`` as ``twin`` fits on it: one batch of the whole records for a linear twin (SRIVC decimates inside,
        :class:`~agents.twin.LinearTwin`), one decimated to its ``n_samples`` for a grey-box twin
        (:class:`~agents.twin.GreyBoxTwin`), the :class:`~gbo_envs.Experiment` records for any other estimator."""
        if isinstance(twin, LinearTwin):
            return self._batch()
        if isinstance(twin, GreyBoxTwin):
            return self._batch(twin.n_samples)
        return self._records

    def _linear_twin(self):
        """The paper's SRIVC twin fitted on ``D~``, warm-started from its previous fit in this run."""
        if self._linear is None:
            self._linear = self._default_twin()
        return self._linear.fit(self._batch())

    def _whole_record_twin(self, twin):
        """The linear twin fitted on the whole records if the decimated ones (``n_samples``) identified ``twin`` no
        better than the noise explains and the whole records identify one that does; it is then the run's linear twin
        (refitted on whole records from then on). Otherwise ``twin``.

        Decimating point samples misrepresents a command that moves within the kept sample time: a cascade's current
        command, saturated for a few milliseconds after the step and then swinging through its speed loop's fast
        transient, feeds the double integrator of the linear motor a different impulse at a 3 ms sample time, and
        SRIVC fits the wrong pole (on LinearMotorCascade-v0, two records: ``a_1 = 7.9`` for ``11.27`` 1/s, RMSE
        0.024; on the whole records ``11.271`` 1/s and ``b_0 = 6.2353`` for ``6.2356``, RMSE 1.5e-4).
        """
        if self.n_samples is None:
            return twin
        try:
            whole = self._default_twin(n_samples=None).fit(self._batch())
        except _FIT_ERRORS:
            return twin
        if not whole.rmse_ <= self.explained_rmse_:
            return twin  # the structure, not the decimation: the diagnosis decides
        self._linear = whole
        return whole

    def _cost_error(self, twin) -> float:
        """RMS relative error of ``twin``'s expected cost at the gains of ``D~`` against the measured costs
        (``inf`` if the twin diverges where the plant did not)."""
        gains = np.array([record.gains for record in self._records])
        measured = np.array([record.cost for record in self._records])
        try:
            predicted = self._env_for(twin).evaluate(gains)[1]
        except _FIT_ERRORS:
            return np.inf
        error = float(np.sqrt(np.mean(((predicted - measured) / np.maximum(np.abs(measured), 1e-12)) ** 2)))
        return error if np.isfinite(error) else np.inf

    def _env_for(self, twin):
        """The plant env's loop around ``twin``, with the records' noise floor unless the twin is the paper's; a
        sensor quantized without visible noise (:attr:`sensor_quantum_`) is simulated as that rounding instead."""
        floor, quantum = self.noise_floor_, self.sensor_quantum_
        noisy = self.twin != "linear" and floor > SIMULATED_NOISE_FLOOR and quantum is None
        twin_env = make_twin_env(self._env, twin, measurement_noise_std=floor * self._step_height if noisy else 0.0,
                                 draws=TWIN_NOISE_DRAWS)
        if self.twin != "linear" and quantum is not None and floor > SIMULATED_NOISE_FLOOR:
            twin_env.loop = twin_env.loop.replace(effects=(*twin_env.loop.effects, Quantization(step=quantum)))
        return twin_env

    def _integrators(self) -> int:
        plant = self._env.loop.plant
        integrators = len(plant.den) - len(np.trim_zeros(np.asarray(plant.den), "b"))
        return min(integrators, self.twin_poles - 1)

    def _default_twin(self, n_samples: int | None | str = "keeper") -> LinearTwin:
        """The paper's SRIVC twin, unfitted, on ``n_samples`` per record (``"keeper"``: the keeper's ``n_samples``)."""
        options = IdentifyOptions(n_poles=self.twin_poles, n_zeros=0, n_integrators=self._integrators(),
                                  solver=SrivcOptions(n_samples=self.n_samples if n_samples == "keeper" else n_samples))
        return LinearTwin(options, output=self._env.loop.plant.output, warm_start=True)

    # -- what the run shows -----------------------------------------------------------------------------
    def drain_events(self) -> list[str]:
        """The twin changes announced since the last call (one line each, as ``gbo tune`` prints them)."""
        events, self._events = self._events, []
        return events

    def describe(self) -> dict[str, Any]:
        """The current twin's effects, parameters and RMSE, as a twin row logs them."""
        twin = self.twin_
        return {"twin_effects": ",".join(_effect_values(twin)) or "linear",
                "twin_params": json.dumps({"linear": [float(p) for p in twin.params_], **_effect_values(twin)}),
                "twin_rmse": float(twin.rmse_)}

    def summary(self) -> dict[str, Any]:
        """The keeper's figures for ``TuningResult.info``: restarts, distrusts, the twin, its fits, the noise floor."""
        twin = self.twin_
        return {"reinitializations": self.reinitializations_, "distrusts": self.distrusts_,
                "twin_rmse": twin.rmse_ if twin is not None else None,
                "twin_params": None if twin is None else [float(p) for p in twin.params_],
                "twin_effects": None if twin is None else _effect_values(twin),
                "twin_changes": [{k: v for k, v in c.items() if k != "text"} for c in self.changes_],
                "noise_floor": self.noise_floor_}

    def _record_change(self, previous_rmse: float | None) -> None:
        twin, told = self.twin_, self.n_told_
        effects = _effect_values(twin)
        change = {"experiment": told, "model": _model_label(twin), "effects": effects,
                  "params": [float(p) for p in twin.params_], "rmse": float(twin.rmse_), "previous_rmse": previous_rmse}
        named = ", ".join(f"+ {name} ({_format_values(values)})" for name, values in effects.items()) or "linear"
        spec = getattr(getattr(twin, "greybox_", None), "spec", None)
        if spec is not None and (spec.n_poles > self.twin_poles or spec.n_zeros > 0):  # the linear part grew
            named = f"{spec.n_poles} poles, {spec.n_zeros} zero{'s' if spec.n_zeros != 1 else ''}" + \
                (f", {named}" if effects else "")
        before = f"{previous_rmse:.3g} -> " if previous_rmse is not None else ""
        after = f"{told} experiment" + ("" if told == 1 else "s")
        change["text"] = f"twin: {named}, RMSE {before}{twin.rmse_:.3g} (after {after})"
        self.changes_.append(change)
        self._events.append(change["text"])


def _identifiable(record: Experiment | Mapping | None) -> Experiment | None:
    """The record's :class:`~gbo_envs.Experiment` if it has signals and did not diverge, else ``None``."""
    if isinstance(record, Mapping):
        if record.get("unstable", False) or (not isinstance(record.get("experiment"), Experiment)
                                             and not all(key in record for key in SIGNALS)):
            return None
        try:
            record = Experiment.from_mapping(record)
        except ValueError:  # a non-finite signal
            return None
    if record is None or not record.has_signals:
        return None
    return record


def _expected_cost(twin_env, gains) -> float:
    cost = float(twin_env.evaluate(np.asarray(gains, dtype=float)[None, :])[1][0])
    return cost if np.isfinite(cost) else float(twin_env.unstable_cost)


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
