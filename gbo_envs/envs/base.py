"""Base class of every plant env: one ``step`` is one closed-loop step experiment.

Subclasses (one plant per module, as in Gymnasium's classic_control) only
build the :class:`~gbo_envs.closed_loop.ClosedLoop`, the feasible set, the
cost weights and the reference gains of the cost normalisation.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from gbo_envs import plotting
from gbo_envs.closed_loop import ClosedLoop, StepResponse
from gbo_envs.constraints import Constraints
from gbo_envs.envs.cost_spec import CostSpec, is_complex, validated_vector
from gbo_envs.experiment import Experiment
from gbo_envs.metrics import METRIC_NAMES, weighted_cost
from gbo_envs.physics.block import validated_count

__all__ = ["ControllerTuningEnv", "OUT_OF_BOUNDS_POLICIES", "expected_outcome"]

#: What :meth:`ControllerTuningEnv.step` does with gains outside the feasible set.
OUT_OF_BOUNDS_POLICIES = ("raise", "clip", "allow")
#: Smallest normaliser computed from the reference gains (a metric they never show, e.g. no overshoot).
NORMALIZER_FLOOR = 1e-9


def normalizer_floors(loop: ClosedLoop) -> np.ndarray:
    """The smallest normalisers ``loop`` can measure, one per metric of :data:`~gbo_envs.metrics.METRIC_NAMES`.

    A quantised sensor of step ``q`` (in output units) reads the overshoot of eq. (zeta) in whole
    steps, ``100 q / |r2 - r1|`` % each, and a reading of one step may be a true overshoot of
    anything between 0 and two steps. A normaliser below one step would weigh that unresolved
    step as several mean overshoots, so the overshoot's floor is one step (the largest step if
    several sensors quantise). The other metrics, and a loop without quantisation, have
    :data:`NORMALIZER_FLOOR`.

    Parameters
    ----------
    loop : ClosedLoop
        The loop whose reference experiments give the normalisers.

    Returns
    -------
    ndarray of shape (4,)
        Floors in the metrics' units (%, s, s, s^2).
    """
    floors = np.full(len(METRIC_NAMES), NORMALIZER_FLOOR)
    steps = [block.step for block in loop.sensor_effects if block.name == "quantization"]
    if steps:
        floors[METRIC_NAMES.index("overshoot_pct")] = max(NORMALIZER_FLOOR, 100.0 * max(steps) / abs(loop.r2 - loop.r1))
    return floors


#: The constraints of an env that has none.
_NO_CONSTRAINTS = Constraints()


class ControllerTuningEnv(gym.Env):
    """A tuning session on one plant; see the subclasses for the plant itself.

    Parameters
    ----------
    loop : ClosedLoop
        The plant, controller and step experiment.
    gain_low, gain_high : array_like of shape (n_gains,)
        Feasible set ``Theta`` (the action ``Box``), in the controller's units.
    cost : CostSpec
        The cost of eq. (J_used): metric weights ``w``, the normalisers (a digital twin reuses
        its plant's) and the cost of a diverging experiment (:class:`~gbo_envs.envs.cost_spec.CostSpec`).
    reference_gains : array_like of shape (n_ref, n_gains), optional
        Gains whose mean metrics are the normalisers when ``cost`` has none (paper: 5 gains
        evenly spanning the feasible set), in the controller's units; computed normalisers
        are at least :func:`normalizer_floors` (one sensor step of overshoot, else :data:`NORMALIZER_FLOOR`).
    cost_noise_std : float
        Standard deviation of the additive cost noise ``epsilon`` of
        ``J = J_hat + epsilon`` (paper, Sec. II), dimensionless.
    max_experiments : int
        Experiments per episode (tuning session), used for the observation.
    out_of_bounds : {"raise", "clip", "allow"}
        Gains outside the feasible set raise ``ValueError`` (default), are
        clipped into it, or are run as given.
    render_mode : {None, "rgb_array"}
        ``"rgb_array"`` renders the last step response.
    noise : bool, default True
        ``False``: :meth:`step` reports the ground truth ``J(theta)``, the
        expected cost over the measurement noise (see :meth:`evaluate`),
        instead of one noisy experiment.
    expectation_draws : int, default 16
        Number ``K`` of fixed noise draws over which :meth:`evaluate` averages
        the cost of a loop with measurement noise, ``>= 1`` (unused for a
        noise-free loop, whose simulation already is the expectation).
    expectation_seed : int, default 0
        Seed of those draws (common random numbers: every gain sees the same
        ``K`` noise realisations), ``>= 0``.

    Attributes
    ----------
    experiment_index : int
        Experiments run since the last :meth:`reset` (what time-varying plants count).
    best_cost : float
        Lowest cost measured since the last :meth:`reset` (``inf`` before the first
        experiment), part of the observation; a resumed session restores both.
    constraints : gbo_envs.constraints.Constraints
        Upper limits the experiments must keep; empty by default. Assigning a mapping sets them
        (``env.constraints = {"overshoot_pct": 2.0, "peak_u": 140.0}``, or ``{"name": (function,
        limit)}`` for a function of the record; the built-in envs take it as ``gym.make(id,
        constraints=...)``). Every :meth:`step` reports ``info["constraints"]`` (name -> value -
        limit, ``<= 0`` kept) and ``info["feasible"]`` (without constraints: ``not unstable``).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 1}
    #: :attr:`~gbo_envs.experiment.Experiment.source` of the records this env produces.
    experiment_source = "plant"
    #: Unit of the measured output ``y`` and the reference ``r`` ("" when unknown).
    output_unit = ""
    #: Unit of the plant input ``u``, the controller's output ("" when unknown).
    input_unit = ""

    def __init__(
        self,
        loop: ClosedLoop,
        gain_low,
        gain_high,
        *,
        cost: CostSpec,
        reference_gains=None,
        cost_noise_std: float = 0.0,
        max_experiments: int = 35,
        out_of_bounds: str = "raise",
        render_mode: str | None = None,
        noise: bool = True,
        expectation_draws: int = 16,
        expectation_seed: int = 0,
    ) -> None:
        self.loop = loop
        if not isinstance(noise, (bool, np.bool_)):  # bool("no") is True: a string or number would pass unseen
            raise TypeError(f"noise: must be True or False, got {noise!r} of type {type(noise).__name__}")
        self.noise = bool(noise)
        self.expectation_draws = validated_count("expectation_draws", expectation_draws, low=1)
        self.expectation_seed = validated_count("expectation_seed", expectation_seed, low=0)
        self.gain_names = tuple(loop.controller.gain_names)
        if self.input_unit and self.output_unit:
            self.gain_units = tuple(loop.controller.units_for(self.input_unit, self.output_unit))
        else:
            self.gain_units = tuple(loop.controller.gain_units)
        low = np.asarray(gain_low, dtype=np.float64)
        high = np.asarray(gain_high, dtype=np.float64)
        if low.shape != (len(self.gain_names),) or high.shape != low.shape or np.any(high <= low):
            raise ValueError(f"gain_low, gain_high: need {len(self.gain_names)} values each with low < high, "
                             f"got {low} and {high}")
        self.action_space = spaces.Box(low=low, high=high, dtype=np.float64)
        n_obs = len(self.gain_names) + len(METRIC_NAMES) + 3
        unbounded = out_of_bounds == "allow"  # gains outside the box may then be observed
        obs_low = np.concatenate([np.full(low.size, -np.inf) if unbounded else low, np.full(n_obs - low.size, -np.inf)])
        obs_high = np.concatenate([np.full(low.size, np.inf) if unbounded else high,
                                   np.full(n_obs - high.size, np.inf)])
        self.observation_space = spaces.Box(low=obs_low, high=obs_high, dtype=np.float64)
        if not isinstance(cost, CostSpec):
            raise TypeError(f"cost: expected a CostSpec, got {cost!r}")
        self.weights = np.array(cost.weights)
        normalizers = cost.normalizers
        if normalizers is None:  # a metric the reference gains hardly show (e.g. no overshoot) still normalises
            reference = np.atleast_2d(np.asarray(reference_gains, dtype=float))
            normalizers = np.maximum(expected_outcome(loop, reference, self.expectation_draws, self.expectation_seed,
                                                      cost=None, record=False)[0].mean(axis=0), normalizer_floors(loop))
        self.normalizers = validated_vector("normalizers", normalizers, len(METRIC_NAMES), positive=True)
        if not np.isfinite(cost_noise_std) or cost_noise_std < 0.0:
            raise ValueError(f"cost_noise_std: must be a finite number >= 0, got {cost_noise_std}")
        self.cost_noise_std = float(cost_noise_std)
        if int(max_experiments) < 1:
            raise ValueError(f"max_experiments: must be >= 1, got {max_experiments}")
        self.max_experiments = int(max_experiments)
        if out_of_bounds not in OUT_OF_BOUNDS_POLICIES:
            raise ValueError(f"out_of_bounds: must be one of {OUT_OF_BOUNDS_POLICIES}, got {out_of_bounds!r}")
        self.out_of_bounds = out_of_bounds
        self.unstable_cost = cost.unstable_cost
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode: must be None or one of {self.metadata['render_modes']}, "
                             f"got {render_mode!r}")
        self.render_mode = render_mode
        self.experiment_index = 0
        self.best_cost = np.inf
        self._last_response: StepResponse | None = None
        self._last_obs = self._observation(None, None, None)

    # -- Gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start a new tuning session (experiment counter and best cost reset)."""
        super().reset(seed=seed)
        self.experiment_index = 0
        self.best_cost = np.inf
        self._last_response = None
        self._last_obs = self._observation(None, None, None)
        return self._last_obs.copy(), {"experiment_index": 0}

    def step(self, action):
        """Run one closed-loop step experiment at the gains ``action``.

        Returns
        -------
        observation, reward, terminated, truncated, info
            ``reward = -cost``. ``info["experiment"]`` is the record of this
            experiment, a :class:`~gbo_envs.experiment.Experiment` (gains, ``t,
            r, u, y``, cost, metrics, ``source="plant"``, ``index``). ``info``
            also keeps its flat keys ``t, r, u, y, gains, metrics, cost,
            true_cost, unstable, experiment_index`` (plus :meth:`extra_info`).
            The record sits inside ``info`` rather than replacing it because
            Gymnasium's wrappers and vector envs merge ``info`` key by key as a
            plain dict of arrays and scalars, and user code reads ``info["y"]``;
            the flat keys hold the same values as the record (as writable copies).
        """
        gains = self.validate_gains(action)
        loop = self.loop_for_experiment(self.experiment_index)
        expected_metrics, expected_cost, response = self._expected(loop, gains[None, :])
        true_cost = float(expected_cost[0])
        if self.noise and loop.stochastic:  # one experiment: one realisation of the measurement noise
            response = loop.simulate(gains[None, :], rng=self.np_random)
            metrics = loop.metrics(response)[0]
            unstable = bool(response.unstable[0])
            cost = self.unstable_cost if unstable else float(self.cost(metrics))
        else:  # the expectation (a noise-free loop's one simulation), with the record of draw 0
            metrics, cost, unstable = expected_metrics[0], true_cost, bool(response.unstable[0])
        if self.noise and not unstable and self.cost_noise_std:
            cost += self.cost_noise_std * self.np_random.standard_normal()
        self.best_cost = min(self.best_cost, cost)
        self._last_response = response
        self._last_gains = gains
        info = {
            "t": response.t.copy(),
            "r": response.r.copy(),
            "u": response.u[0],
            "y": response.y[0],
            "gains": gains.copy(),
            "metrics": {name: float(v) for name, v in zip(METRIC_NAMES, metrics)},
            "cost": cost,
            "true_cost": true_cost,
            "unstable": unstable,
            "experiment_index": self.experiment_index,
        }
        info["experiment"] = Experiment(gains=gains, t=response.t, r=response.r, u=response.u[0], y=response.y[0],
                                        cost=cost, metrics=info["metrics"], source=self.experiment_source,
                                        index=self.experiment_index)
        info.update(self.constraints.judge(info["experiment"], unstable))
        info.update(self.extra_info(self.experiment_index))
        self.experiment_index += 1
        self._last_obs = self._observation(gains, metrics, cost)
        return self._last_obs.copy(), -cost, False, False, info

    def render(self):
        """RGB array of the last step response (``render_mode="rgb_array"``)."""
        if self.render_mode != "rgb_array":
            return None

        if self._last_response is None:
            title = f"{type(self).__name__}: no experiment yet"
        else:
            gains = ", ".join(f"{name} = {value:.3g} {unit}" for name, value, unit in
                              zip(self.gain_names, self._last_gains, self.gain_units))
            title = f"{type(self).__name__}, experiment {self.experiment_index}: {gains}"
        fig = plotting.response_figure(self.loop, self._last_response, title=title, output_unit=self.output_unit,
                              input_unit=self.input_unit)
        return plotting.figure_to_rgb(fig)

    # -- experiment helpers ----------------------------------------------------------------------
    def validate_gains(self, action) -> np.ndarray:
        """Check ``action`` and return it as a float array of shape (n_gains,).

        Raises
        ------
        ValueError
            Wrong shape, NaN/inf, or (with ``out_of_bounds="raise"``) a gain
            outside the feasible set; the message names the gain and its range.
        """
        if is_complex(action):
            raise TypeError(f"action: gains {self.gain_names} must be real numbers, got the complex value(s) "
                            f"{action!r}")
        if _is_boolean(action):
            raise TypeError(f"action: gains {self.gain_names} must be real numbers, got the boolean value(s) "
                            f"{action!r} (True would run as a gain of 1.0)")
        try:
            gains = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"action: expected {len(self.gain_names)} numeric gains "
                             f"{self.gain_names}, got {action!r}") from exc
        if gains.shape != (len(self.gain_names),):
            raise ValueError(f"action: expected shape ({len(self.gain_names)},) for gains {self.gain_names}, "
                             f"got shape {gains.shape}")
        low, high = self.action_space.low, self.action_space.high
        tolerance = 1e-9 * (high - low)
        for name, unit, value, lo, hi, tol in zip(self.gain_names, self.gain_units, gains, low, high, tolerance):
            if not np.isfinite(value):
                raise ValueError(f"{name}: gain must be finite, got {value}")
            if self.out_of_bounds == "raise" and not (lo - tol <= value <= hi + tol):
                raise ValueError(f"{name} = {value:g} {unit} is outside the feasible set [{lo:g}, {hi:g}]; "
                                 "pass out_of_bounds='clip' or 'allow' to gym.make to change this")
        if self.out_of_bounds != "allow":
            gains = np.clip(gains, low, high)
        return gains

    def cost(self, metrics: np.ndarray) -> np.ndarray:
        """Weighted cost ``J`` of eq. (J_used) for metrics of shape (..., 4)."""
        return weighted_cost(metrics, self.weights, self.normalizers)

    def evaluate(self, gains: np.ndarray, experiment_index: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Ground truth: expected metrics and cost for a batch of gains, without counting an experiment.

        ``J(theta) = E_nu[J(theta, nu)]`` over the measurement noise ``nu``
        (the additive cost noise ``epsilon`` has zero mean and drops out). A
        noise-free loop is simulated once. A loop with measurement noise is
        averaged over ``K = expectation_draws`` fixed draws ``nu_1 .. nu_K``
        (seed ``expectation_seed``), the same for every gain (common random
        numbers), so ``J`` is a deterministic function of the gains and
        differences between gains carry little Monte Carlo error.

        Parameters
        ----------
        gains : ndarray of shape (batch, n_gains)
        experiment_index : int, optional
            For time-varying plants: evaluate the plant as it is at this experiment
            (default: the next experiment).

        Returns
        -------
        metrics : ndarray of shape (batch, 4)
            Mean metrics over the draws.
        cost : ndarray of shape (batch,)
            ``J(theta)``; a diverging draw counts as ``unstable_cost``.
        """
        index = self.experiment_index if experiment_index is None else experiment_index
        metrics, cost, _ = self._expected(self.loop_for_experiment(index), np.atleast_2d(gains), record=False)
        return metrics, cost

    @property
    def constraints(self) -> Constraints:
        """The limits of every experiment (see the class doc); assign a mapping to set them."""
        return getattr(self, "_constraints", _NO_CONSTRAINTS)

    @constraints.setter
    def constraints(self, spec) -> None:
        self._constraints = Constraints(spec)

    def evaluate_constraints(self, gains: np.ndarray, experiment_index: int | None = None,
                             constraints: Constraints | None = None) -> tuple[np.ndarray, ...]:
        """Ground truth with :attr:`constraints`: cost, ``value - limit`` and feasibility of a batch of gains.

        :meth:`evaluate_outcome` without the metrics.
        """
        return self.evaluate_outcome(gains, experiment_index, constraints)[1:]

    def evaluate_outcome(self, gains: np.ndarray, experiment_index: int | None = None,
                         constraints: Constraints | None = None) -> tuple[np.ndarray, ...]:
        """Ground truth with :attr:`constraints`: metrics, cost, ``value - limit`` and feasibility of a batch of gains.

        Each gain is judged as ``noise=False`` :meth:`step` judges it: the expected metrics and
        cost of :meth:`evaluate`, ``peak_u`` and user functions on the record of noise draw 0
        (the noise-free experiment of a noise-free loop), an unstable one infeasible.

        Parameters
        ----------
        gains : ndarray of shape (batch, n_gains)
        experiment_index : int, optional
            As in :meth:`evaluate`.
        constraints : Constraints, optional
            The limits to judge by (default: :attr:`constraints`).

        Returns
        -------
        metrics : ndarray of shape (batch, 4)
            The expected metrics of :meth:`evaluate`, from the same simulation.
        cost : ndarray of shape (batch,)
        slacks : ndarray of shape (batch, n_constraints)
            ``value - limit`` in the constraints' order.
        feasible : ndarray of bool, shape (batch,)
        """
        gains = np.atleast_2d(np.asarray(gains, dtype=float))
        index = self.experiment_index if experiment_index is None else experiment_index
        metrics, cost, response = self._expected(self.loop_for_experiment(index), gains, record=True)

        def record(i: int) -> Experiment:
            return Experiment(gains=gains[i], t=response.t, r=response.r, u=response.u[i], y=response.y[i],
                              cost=float(cost[i]), metrics=dict(zip(METRIC_NAMES, map(float, metrics[i]))),
                              source=self.experiment_source)

        limits = self.constraints if constraints is None else Constraints(constraints)
        slacks = limits.batch_slacks(metrics, response.u, record)
        feasible = ~np.asarray(response.unstable, dtype=bool) & np.all(slacks <= 0.0, axis=1)
        return metrics, cost, slacks, feasible

    def _expected(self, loop: ClosedLoop, gains: np.ndarray, record: bool = True):
        """:func:`expected_outcome` of this env's cost on ``loop`` (the record of draw 0 if ``record``)."""
        return expected_outcome(loop, gains, self.expectation_draws, self.expectation_seed,
                                cost=self._cost_or_unstable, record=record)

    def _cost_or_unstable(self, metrics: np.ndarray, unstable: np.ndarray) -> np.ndarray:
        return np.where(unstable, self.unstable_cost, self.cost(metrics))

    def loop_for_experiment(self, index: int) -> ClosedLoop:
        """The loop as it is at experiment ``index``.

        Plant-side effect blocks (e.g. ``drift``) are applied here through
        :meth:`~gbo_envs.closed_loop.ClosedLoop.at_experiment`; time-varying
        plants may override this.
        """
        return self.loop.at_experiment(index)

    def extra_info(self, index: int) -> dict[str, Any]:
        """Extra entries for ``info`` (time-varying plants report their true parameters)."""
        return {}

    def _observation(self, gains, metrics, cost) -> np.ndarray:
        """``[gains, normalised metrics f_i / n_i, J, best J, experiments done / max_experiments]``."""
        if gains is None:
            low, high = self.action_space.low, self.action_space.high
            return np.concatenate([(low + high) / 2.0, np.zeros(len(METRIC_NAMES) + 3)])
        best = self.best_cost
        done = self.experiment_index / self.max_experiments
        return np.concatenate([gains, metrics / self.normalizers, [cost, best, done]]).astype(np.float64)


def expected_outcome(loop: ClosedLoop, gains: np.ndarray, draws: int, seed: int, cost=None,
                     max_rows: int = 4096, record: bool = True):
    """Metrics and cost of ``loop`` at ``gains``, averaged over ``draws`` fixed noise draws if the loop is noisy.

    Row ``(i, j)`` runs gains ``i`` with noise draw ``j`` of ``default_rng(seed)``
    (:class:`~gbo_envs.physics.block.RowNoise`); draws ``0..K-1`` are the same
    for every gain. At most ``max_rows`` rows are simulated at once.

    Parameters
    ----------
    loop : ClosedLoop
    gains : ndarray of shape (batch, n_gains)
    draws : int
        ``K``, used only when ``loop.stochastic``.
    seed : int
    cost : callable ``(metrics, unstable) -> cost``, optional
        Cost of each row; ``None`` skips it.
    record : bool, default True
        Whether to keep the record of draw 0 of every gain; ``False`` returns ``None`` in its
        place (a cost surface needs only the metrics, and the records of 10^4 gains of a DC
        motor are 400 MB to copy).

    Returns
    -------
    metrics : ndarray of shape (batch, 4)
    cost : ndarray of shape (batch,) or None
    response : StepResponse or None
        The record of draw 0 of every gain (``None`` with ``record=False``).
    """
    gains = np.atleast_2d(np.asarray(gains, dtype=float))
    k = int(draws) if loop.stochastic else 1
    per_chunk = max(1, max_rows // k)
    metrics, costs, first_draws = [], [], []
    for start in range(0, gains.shape[0], per_chunk):
        part = gains[start : start + per_chunk]
        rows = np.repeat(part, k, axis=0)
        response = loop.simulate(rows, rng=np.random.default_rng(seed), draws=np.tile(np.arange(k), part.shape[0]),
                                 inputs=record)
        row_metrics = loop.metrics(response)
        metrics.append(row_metrics.reshape(part.shape[0], k, -1).mean(axis=1))
        if cost is not None:
            costs.append(cost(row_metrics, response.unstable).reshape(part.shape[0], k).mean(axis=1))
        if record:  # copies: a strided view would keep the whole chunk's k draws alive (GBs for a rig grid)
            first_draws.append((response.u[::k].copy(), response.y[::k].copy(), response.unstable[::k].copy()))
    kept = None
    if record:
        u, y, unstable = (np.concatenate(parts) for parts in zip(*first_draws))
        kept = StepResponse(t=response.t, r=response.r, u=u, y=y, unstable=unstable)
    return np.concatenate(metrics), (np.concatenate(costs) if cost is not None else None), kept


def _is_boolean(values) -> bool:
    """Whether ``values`` holds a boolean (``True`` would run as the gain 1.0)."""
    if isinstance(values, (bool, np.bool_)):
        return True
    if isinstance(values, (list, tuple)) and any(isinstance(v, (bool, np.bool_)) for v in values):
        return True  # [True, 1.2] converts to float64 without a trace of the bool
    try:
        array = np.asarray(values)
    except (TypeError, ValueError):  # ragged: the float conversion reports it
        return False
    if array.dtype == np.bool_:
        return True
    return array.dtype == object and any(isinstance(v, (bool, np.bool_)) for v in array.ravel())
