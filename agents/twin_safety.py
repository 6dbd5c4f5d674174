r"""The digital twin as a safety filter: gains the twin predicts unsafe are refused before the plant runs them.

Safe BO (``agents.make("bo", safe=True)``) admits a gain when the constraint GPs, fitted on the
plant's experiments alone, give ``PF(theta) >= 1 - delta_t`` (:mod:`agents.feasibility`): its
safe set grows only as far as the plant was measured. Guided BO has a twin that simulates the
whole feasible set, records ``u`` and ``y`` included, so it can judge every constraint of
:mod:`gbo_envs.constraints` at any gain without a plant experiment. :class:`TwinSafetyFilter`
makes that judgement safe by the twin's own measured error:

* **Prediction.** ``c~_j(theta)``: the slack ``value_j - limit_j`` of constraint ``j`` on the
  noise-free twin's simulated record at ``theta`` (its metrics, its ``peak_u``, a user
  function of the record; :meth:`gbo_envs.ControllerTuningEnv.evaluate_constraints`); a twin
  loop that diverges predicts every slack ``+inf``.
* **Measured error.** Every plant experiment at gains the twin had predicted before it ran
  (the twin fitted on the earlier records only, so the error is out of sample) gives
  ``e_ji = c_j(theta_i) - c~_j(theta_i)``, the plant's slack (measured on its noisy record)
  minus the twin's. A plant that diverged where the twin did not is an error of ``+inf``.
* **Margin.** The errors are grouped by the twin that predicted them: a refitted twin is another
  predictor with its own systematic error. The model is ``e_ki = b_k + eps_ki``, ``b_k`` the bias of
  twin ``k`` and ``eps`` independent normal errors of one variance ``sigma_j^2`` for every twin (the
  plant's noise and the error's change over the gains the tuner visits). The next error of the
  current twin ``K`` has the one-sided Student-t prediction bound of this one-way (fixed-effects)
  model,

      m_j = e_Kj + t_{n-g}(1 - delta') s_j sqrt(1 + 1/n_K),

  ``e_Kj`` the mean of the current twin's ``n_K`` errors, ``s_j^2`` the within-twin variance
  ``sum_k sum_i (e_kij - e_kj)^2 / (n - g)`` of the ``n`` errors of the ``g`` twins that have any,
  at the risk ``delta' = delta_t / n_c`` (``n_c`` constraints, ``delta_t`` the run's risk at
  experiment ``t``, :func:`agents.feasibility.run_risk`). With one twin (``g = 1``) it is the
  bound of ``n`` normal errors of unknown mean and variance. The twin admits nothing
  (``m_j = inf``) while the current twin has no measured error (``n_K = 0``: its bias is unknown)
  or no twin has two (``n - g = 0``). One sample of the errors of all twins would take the
  differences between their biases for noise, and its mean would understate a twin whose bias
  exceeds its predecessors': on DCMotorRig-v0 (seed 0) the three twins' ``peak_u`` errors at the
  safe start were 8.87, 7.27 and 5.09 V, within 0.3 V for one twin; pooled, the spread was 1.45 V
  and the margin 13-15 V against 5.9 V of twin slack at the start, so that no gain near it was
  admitted. The errors are measured where the tuner goes, on the edge of the safe set, which is
  where the next proposal is.
* **Admission.** ``theta`` is twin-safe when ``c~_j(theta) + m_j <= 0`` for every ``j``: by the
  union bound over the constraints it keeps them all with probability ``>= 1 - delta_t``, and
  the whole run with ``>= 1 - delta``.
* **Safe set.** The twin-safe gains alone. They span every gain the twin simulates within its
  margin, also far from the plant experiments: the safe set grows on the twin, not on the plant.
  The constraint GPs weigh the acquisition (``PF``) but admit nothing: fitted on a few
  experiments whose slacks are nearly equal (a safe start close to a limit), they call gains
  safe that are not (on DCMotorRig-v0, ``PF = 0.9994`` at (0.39, 1.041) after two experiments,
  whose peak command broke its limit by 1.6). Where nothing is twin-safe (before two errors
  are measured, after a refit of the twin, or a margin too wide), the plant runs the best
  feasible gains measured again, and that experiment measures the current twin's error.

The acquisition (:class:`TwinSafeAcquisition`) is constrained EI, ``EI(theta) x PF(theta)``,
inside that safe set and ``-1`` outside it.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import stdtrit

from agents.feasibility import ConstrainedAcquisition, ConstraintModel, run_risk
from agents.twin.prior import TwinSimulation

__all__ = ["TwinSafeAcquisition", "TwinSafetyFilter"]


class TwinSafetyFilter:
    r"""Twin-predicted constraint slacks with a margin from the twin's measured error (module doc).

    Parameters
    ----------
    constraints : gbo_envs.constraints.Constraints
        The plant's limits (``env.unwrapped.constraints``), judged on the twin's records.
    delta : float
        The run's risk of breaking a limit, in ``(0, 1)`` (split over its experiments by
        :func:`agents.feasibility.run_risk`).

    Attributes
    ----------
    errors_ : list of ndarray
        The out-of-sample errors ``e_i`` (plant slack - twin slack, each of shape (n_c,)).
    error_twins_ : list of int
        The twin that predicted each error (numbered from 0 in the order the twins were first
        seen by :meth:`expect` or :meth:`admits`).
    admitted_ : int
        Proposals the twin admitted (the others repeat the best feasible gains measured).
    """

    def __init__(self, constraints, delta: float) -> None:
        if not constraints:
            raise ValueError("constraints: the twin safety filter needs the plant's constraints; got none")
        if not 0.0 < float(delta) < 1.0:
            raise ValueError(f"delta: must be in (0, 1), got {delta}")
        self.constraints, self.delta = constraints, float(delta)
        self.errors_: list[np.ndarray] = []
        self.error_twins_: list[int] = []
        self.admitted_ = 0
        self._twin, self._twins_seen = None, 0  # the latest twin env and how many twins were seen
        self._pending: tuple[np.ndarray, np.ndarray, int] | None = None

    def _twin_number(self, twin: TwinSimulation) -> int:
        """The number of ``twin``'s twin env, a new one for a twin not seen last."""
        if twin.twin_env is not self._twin:
            self._twin, self._twins_seen = twin.twin_env, self._twins_seen + 1
        return self._twins_seen - 1

    # -- the twin's prediction ------------------------------------------------------------------------
    def checked(self, twin: TwinSimulation) -> TwinSimulation:
        """``twin`` if it is a :class:`~agents.twin.prior.TwinSimulation` judging the filter's constraints
        (the keeper's, :meth:`agents.twin_keeper.TwinKeeper.twin_simulation`, shared with the metrics prior).

        Raises
        ------
        TypeError
            ``twin`` is not a TwinSimulation (a twin env: wrap it, ``TwinSimulation(twin_env, constraints)``).
        ValueError
            The simulation judges other constraints than the filter.
        """
        if not isinstance(twin, TwinSimulation):
            raise TypeError(f"twin: expected an agents.twin.prior.TwinSimulation (a twin env goes in "
                            f"TwinSimulation(twin_env, constraints)), got {type(twin).__name__}")
        names = None if twin.constraints is None else twin.constraints.names
        if names != self.constraints.names:
            raise ValueError(f"twin: the simulation judges the constraints {names}, the filter "
                             f"{self.constraints.names}")
        return twin

    def predicted_slacks(self, twin: TwinSimulation, gains: np.ndarray) -> np.ndarray:
        """``c~(theta)``: the noise-free twin's slacks at physical gains of shape (m, d), shape (m, n_c).

        ``twin``: the twin's :class:`~agents.twin.prior.TwinSimulation` (:meth:`checked`), which simulates
        each gain once per twin (the EI grid once); a diverging twin loop gives ``+inf``.
        """
        return self.checked(twin).outcome(gains)[2]

    # -- the twin's error ------------------------------------------------------------------------------
    def expect(self, twin: TwinSimulation | None, gains) -> None:
        """The twin's simulation (:meth:`checked`), fitted on the records so far, predicts the next plant
        experiment at ``gains`` (physical); ``None``: no twin, no prediction."""
        gains = np.asarray(gains, dtype=float)
        self._pending = None if twin is None else (gains.copy(), self.predicted_slacks(twin, gains[None])[0],
                                                   self._twin_number(twin))

    def observe(self, gains, record: dict | None) -> None:
        """The plant experiment at ``gains`` ran: its error against the prediction of :meth:`expect`, if any.

        A plant slack that the experiment does not report, or a twin that predicted divergence,
        teaches nothing about the twin's error where it admits gains; a plant that diverged where
        the twin did not is an error of ``+inf``.
        """
        pending, self._pending = self._pending, None
        if pending is None or not np.allclose(pending[0], np.asarray(gains, dtype=float), rtol=0.0, atol=1e-12):
            return
        slacks = (record or {}).get("constraints") or {}
        if not np.all(np.isfinite(pending[1])) or any(name not in slacks for name in self.constraints.names):
            return
        measured = np.array([float(slacks[name]) for name in self.constraints.names])
        if (record or {}).get("unstable", False):
            measured = np.full_like(measured, np.inf)
        self.errors_.append(np.where(np.isnan(measured), np.inf, measured - pending[1]))
        self.error_twins_.append(pending[2])

    def margin(self, experiment: int, twin: int | None = None) -> np.ndarray:
        """``m_j = e_Kj + t_{n-g}(1 - delta') s_j sqrt(1 + 1/n_K)`` for experiment ``t`` (module doc), shape (n_c,).

        ``twin``: the number of the twin ``K`` whose next error is bounded (default: the latest twin
        seen, else the latest that predicted an error)."""
        n_c = len(self.constraints)
        if len(self.error_twins_) != len(self.errors_):
            raise ValueError(f"error_twins_: one twin per error, got {len(self.error_twins_)} for "
                             f"{len(self.errors_)} errors")
        labels = np.asarray(self.error_twins_, dtype=int)
        if twin is None:
            twin = self._twins_seen - 1 if self._twin is not None else (int(labels[-1]) if labels.size else 0)
        mine = labels == twin
        groups, index = np.unique(labels, return_inverse=True)
        dof = labels.size - groups.size  # n - g
        if not np.any(mine) or dof < 1:
            return np.full(n_c, np.inf)
        errors = np.vstack(self.errors_)  # a constraint with an infinite error keeps an infinite margin
        return np.where(np.all(np.isfinite(errors), axis=0),
                        self._bound(errors, index, groups.size, mine, experiment), np.inf)

    def _bound(self, errors: np.ndarray, index: np.ndarray, n_groups: int, mine: np.ndarray,
               experiment: int) -> np.ndarray:
        finite = np.where(np.isfinite(errors), errors, 0.0)
        means = np.vstack([finite[index == k].mean(axis=0) for k in range(n_groups)])
        dof = index.size - n_groups
        within = np.sqrt(np.sum((finite - means[index]) ** 2, axis=0) / dof)
        risk = run_risk(self.delta, experiment) / errors.shape[1]
        quantile = float(stdtrit(dof, 1.0 - risk))
        n_twin = int(np.sum(mine))
        return finite[mine].mean(axis=0) + quantile * within * math.sqrt(1.0 + 1.0 / n_twin)

    def admits(self, twin: TwinSimulation | None, gains: np.ndarray, experiment: int) -> np.ndarray:
        """Whether each physical gain (m, d) is twin-safe at experiment ``t``: ``c~_j + m_j <= 0`` for all ``j``.

        ``twin``: the twin's simulation (:meth:`checked`), ``None`` without a twin. Shape (m,); nothing is
        twin-safe without a twin or with an infinite margin."""
        gains = np.atleast_2d(np.asarray(gains, dtype=float))
        if twin is None:
            return np.zeros(gains.shape[0], dtype=bool)
        twin = self.checked(twin)
        margin = self.margin(experiment, self._twin_number(twin))
        if not np.all(np.isfinite(margin)):
            return np.zeros(gains.shape[0], dtype=bool)
        return np.all(twin.outcome(gains)[2] + margin <= 0.0, axis=1)  # c~(theta), twin checked above



class TwinSafeAcquisition:
    """``EI x PF`` on the twin-safe gains, ``-1`` elsewhere (module doc).

    Parameters
    ----------
    ei : callable or None
        Expected Improvement over the best feasible cost (``None``: maximise ``PF``).
    constraints : ConstraintModel
        The fitted constraint GPs.
    safety : TwinSafetyFilter
    twin : agents.twin.prior.TwinSimulation or None
        The current twin's simulations, shared with the metrics prior (``None``: nothing is admitted).
    space : agents.GainSpace
        Maps the unit-box inputs to physical gains.
    experiment : int
        ``t``, the number of the experiment proposed.
    """

    def __init__(self, ei, constraints: ConstraintModel, safety: TwinSafetyFilter, twin: TwinSimulation | None,
                 space, experiment: int) -> None:
        self.base = ConstrainedAcquisition(ei, constraints)
        self.safety, self.twin, self.space, self.experiment = (safety, None if twin is None else safety.checked(twin),
                                                               space, experiment)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(X)
        admitted = self.safety.admits(self.twin, self.space.from_unit(X), self.experiment)
        if not np.any(admitted):
            return np.full(X.shape[0], -1.0)
        return np.where(admitted, self.base(X), -1.0)
