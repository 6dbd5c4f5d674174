"""A digital twin's performance metrics as the prior mean of the metric GPs.

Guided BO's default (``GuidedBO(guidance="prior")``) fits the default BO's
metric GPs (:mod:`agents.metric_surrogate`) to the *discrepancy* between plant
and twin: the GP of metric ``i`` models ``T_i(f_i(theta)) - T_i(f~_i(theta))``,
``f~_i`` the twin's metric (:class:`agents.twin.TwinEnv`, simulated with the
plant's controller, step and noise floor). Where the twin is right the
discrepancy is flat and the posterior follows the twin everywhere, also far
from the plant data; where it is wrong, the plant data correct it locally.

The twin is simulated once per candidate point and twin: :class:`TwinSimulation`
keeps every row it has simulated, so the EI grid (10^4 gains) costs one batched
simulation per fitted twin, and every later GP prediction is a look-up. One
simulation, two readers: :class:`TwinMetrics` reads the metrics, and guided BO's
safety filter (:class:`agents.twin_safety.TwinSafetyFilter`) the constraint slacks
of the same simulated records.
"""

from __future__ import annotations

import numpy as np

__all__ = ["EVALUATION_BATCH", "TwinMetrics", "TwinSimulation", "unstable_metrics"]


def unstable_metrics(env) -> np.ndarray:
    """Metrics of shape (n_metrics,) whose cost is the env's ``unstable_cost``: ``n_i unstable_cost / sum_j w_j``.

    ``J = sum_i w_i f_i / n_i`` (eq. (J_used)) of these metrics is ``unstable_cost``; they
    stand for a diverging experiment (plant or twin) in the metric GPs.
    """
    weights = np.asarray(env.weights, dtype=float)
    return np.asarray(env.normalizers, dtype=float) * float(env.unstable_cost) / float(np.sum(weights))


#: A noisy twin's expected metrics (its noise draws) are simulated only where its noise-free cost is
#: within this factor of the lowest expected cost found so far; elsewhere the noise-free metrics stand.
NOISY_COST_FACTOR = 1.5

#: Gains per batch of the expected-metric simulations (times the draws: the rows simulated at once).
NOISY_BATCH = 512

#: Gains at most per call whose expected metrics are simulated, the lowest noise-free costs first. It
#: bounds only the first call on the 10^4-gain EI grid of two gains (the bound above admits 1,000-1,400
#: on DCMotorRig-v0's twin); beyond two gains every admitted candidate of EI's 2,048 gets them.
NOISY_MAX_GAINS = 4096


#: Gains per batched twin simulation that records the constraints (bounds the memory of the records ``u``).
EVALUATION_BATCH = 1024


class TwinSimulation:
    """The noise-free twin's metrics, cost and constraint slacks at physical gains, each gain simulated once.

    Parameters
    ----------
    twin_env : agents.twin.TwinEnv
        The twin in the plant's closed loop; its :meth:`~agents.twin.TwinEnv.noise_free` loop is
        simulated.
    constraints : gbo_envs.constraints.Constraints, optional
        Limits judged on the simulated records as well (:meth:`gbo_envs.ControllerTuningEnv.evaluate_outcome`,
        in batches of :data:`EVALUATION_BATCH` gains); ``None``: the metrics alone, without the records.

    Attributes
    ----------
    simulations_ : int
        Gains simulated so far (each once).

    Notes
    -----
    The metrics and cost are the twin's as simulated (:class:`TwinMetrics` prices a diverging loop);
    a slack is ``+inf`` where the twin's loop diverged or the slack is not finite.
    """

    def __init__(self, twin_env, constraints=None) -> None:
        self.twin_env = twin_env
        self.constraints = constraints if constraints else None
        self._noise_free = getattr(twin_env, "noise_free", lambda: twin_env)()
        self._rows: dict[bytes, tuple[np.ndarray, float, np.ndarray | None]] = {}
        self.simulations_ = 0

    @property
    def noise_free_env(self):
        """The twin env that is simulated (the twin itself if it has no random parts)."""
        return self._noise_free

    def outcome(self, gains: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Metrics (m, n_metrics), cost (m,) and slacks (m, n_c) or ``None`` at physical gains of shape (m, d)."""
        gains = np.atleast_2d(np.asarray(gains, dtype=float))
        keys = [row.tobytes() for row in gains]
        missing = list(dict.fromkeys(key for key in keys if key not in self._rows))
        if missing:
            self._simulate(missing)
        rows = [self._rows[key] for key in keys]
        slacks = None if self.constraints is None else np.vstack([row[2] for row in rows])
        return np.vstack([row[0] for row in rows]), np.array([row[1] for row in rows]), slacks

    def _simulate(self, keys: list[bytes]) -> None:
        new = np.vstack([np.frombuffer(key, dtype=float) for key in keys])
        self.simulations_ += len(keys)
        if self.constraints is None:  # one batched call without the records
            metrics, cost = self._noise_free.evaluate(new)[:2]
            self._rows.update(zip(keys, zip(metrics, cost, [None] * len(keys))))
            return
        for start in range(0, new.shape[0], EVALUATION_BATCH):
            batch = slice(start, start + EVALUATION_BATCH)
            metrics, cost, slacks, feasible = self._noise_free.evaluate_outcome(new[batch],
                                                                               constraints=self.constraints)
            diverged = ~feasible & np.all(slacks <= 0.0, axis=1)  # infeasible with every limit kept: unstable
            slacks = np.where(diverged[:, None] | ~np.isfinite(slacks), np.inf, slacks)
            self._rows.update(zip(keys[batch], zip(metrics, cost, slacks)))


class TwinMetrics:
    """``prior(X) -> f~`` of a twin env at unit-box gains: the twin's expected raw metrics, cached per row.

    Parameters
    ----------
    twin_env : agents.twin.TwinEnv or TwinSimulation
        The twin in the plant's closed loop; :meth:`~agents.twin.TwinEnv.evaluate` gives its
        expected metrics (over its measurement noise draws, if any). A :class:`TwinSimulation`
        of it: its noise-free metrics are read from there (shared with its other readers).
    space : agents.GainSpace
        Maps unit-box inputs to physical gains.

    Attributes
    ----------
    simulation : TwinSimulation
        The noise-free twin's simulations this prior reads.
    simulations_ : int
        Gains simulated so far (each noise-free gain once, by :attr:`simulation`; a noisy
        twin's gain counts once more if its expected metrics were simulated too).
    best_expected_cost_ : float
        A noisy twin's lowest expected cost found so far (``inf`` before any, and for a
        twin without noise).

    Notes
    -----
    Where the twin's loop diverges (or a metric is not finite), every metric is set so that
    the twin's cost is the env's ``unstable_cost``: ``f~_i = n_i unstable_cost / sum_j w_j``,
    since ``J = sum_i w_i f_i / n_i`` (eq. (J_used)).

    A twin with measurement noise, or a cogging ripple starting at random angles
    (:meth:`agents.twin.TwinEnv.noise_free` is not the twin itself), costs its ``draws``
    simulations per gain, 8 times the noise-free one (no noise, one start angle). The noise
    only raises the cost (later settling, larger ITAE and overshoot; on the DCMotorRig-v0
    plant with 0.09 and 0.2 rad/s of sensor noise the expected cost is at least 0.998 times
    the noise-free one over a 25 x 25 grid, and the gains within the bound are 12 % and 24 %
    of the grid), so a gain whose noise-free cost is above :data:`NOISY_COST_FACTOR` times
    the lowest expected cost found so far cannot be near the twin's expected optimum: it
    keeps its noise-free metrics. The new gains of a call are simulated without noise, then,
    in order of their noise-free cost and in batches of :data:`NOISY_BATCH`, with noise
    while that bound admits them, at most :data:`NOISY_MAX_GAINS` per call. An admitted gain
    must not keep its noise-free metrics: they are optimistic, most where the twin has
    friction (on LinearMotorCascadeRig-v0's Coulomb twin the noise-free overshoot is 0 where
    the expected one is 0.19 %), and EI's argmax lands on such a gain (its EI fell from
    0.0325 to 0.0019 once its expected metrics were simulated).
    A gain keeps the values of its first call, so the same gains give the same prior.
    """

    def __init__(self, twin_env, space) -> None:
        self.simulation = twin_env if isinstance(twin_env, TwinSimulation) else TwinSimulation(twin_env)
        self.twin_env = self.simulation.twin_env
        self.space = space
        self._unstable = unstable_metrics(self.twin_env)
        self._rows: dict[bytes, np.ndarray] = {}
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self._expected_simulations = 0
        self.best_expected_cost_ = np.inf

    @property
    def simulations_(self) -> int:
        """Gains simulated so far: the noise-free ones of :attr:`simulation`, then the expected ones."""
        return self.simulation.simulations_ + self._expected_simulations

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """Raw twin metrics of shape (m, n_metrics) at unit-box inputs of shape (m, d)."""
        if self._last is not None and X is self._last[0]:
            return self._last[1]  # the same candidate array as the previous call (one per metric GP)
        X = np.atleast_2d(np.asarray(X, dtype=float))
        keys = [row.tobytes() for row in X]
        missing = [i for i, key in enumerate(keys) if key not in self._rows]
        if missing:
            first: dict[bytes, int] = {}  # each new gain once, at its first row
            for i in missing:
                first.setdefault(keys[i], i)
            self._rows.update(zip(first, self._simulate(self.space.from_unit(X[list(first.values())]))))
        values = np.vstack([self._rows[key] for key in keys])
        self._last = (X, values)
        return values

    def _simulate(self, gains: np.ndarray) -> np.ndarray:
        """The twin's metrics (m, n_metrics) at physical gains (m, d): expected where they may matter."""
        metrics, cost = self._priced(*self.simulation.outcome(gains)[:2])
        if self.simulation.noise_free_env is self.twin_env:
            return metrics
        order, start = np.argsort(cost, kind="stable"), 0
        while start < min(order.size, NOISY_MAX_GAINS):
            # the first expected cost sets the bound: before it, only the lowest noise-free cost is simulated
            size = NOISY_BATCH if np.isfinite(self.best_expected_cost_) else 1
            batch = order[start:start + size]
            batch = batch[cost[batch] <= NOISY_COST_FACTOR * self.best_expected_cost_]
            if batch.size == 0:
                break  # sorted: no later gain is admitted either
            metrics[batch], expected = self._priced(*self.twin_env.evaluate(gains[batch])[:2])
            self._expected_simulations += batch.size
            self.best_expected_cost_ = min(self.best_expected_cost_, float(np.min(expected)))
            start += size
        return metrics

    def _priced(self, metrics: np.ndarray, cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Metrics (m, n_metrics) and cost (m,) of the twin, diverging rows priced at ``unstable_cost``."""
        bad = ~np.all(np.isfinite(metrics), axis=1) | ~np.isfinite(cost)
        return (np.where(bad[:, None], self._unstable, metrics),
                np.where(bad, float(self.twin_env.unstable_cost), cost))
