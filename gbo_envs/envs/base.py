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

from gbo_envs.closed_loop import ClosedLoop, StepResponse
from gbo_envs.metrics import METRIC_NAMES, weighted_cost

__all__ = ["ControllerTuningEnv", "OUT_OF_BOUNDS_POLICIES"]

#: What :meth:`ControllerTuningEnv.step` does with gains outside the feasible set.
OUT_OF_BOUNDS_POLICIES = ("raise", "clip", "allow")


class ControllerTuningEnv(gym.Env):
    """A tuning session on one plant; see the subclasses for the plant itself.

    Parameters
    ----------
    loop : ClosedLoop
        The plant, controller and step experiment.
    gain_low, gain_high : array_like of shape (n_gains,)
        Feasible set ``Theta`` (the action ``Box``), in the controller's units.
    weights : array_like of shape (4,)
        Metric weights ``w`` of eq. (J_used), in :data:`~gbo_envs.metrics.METRIC_NAMES` order.
    reference_gains : array_like of shape (n_ref, n_gains)
        Gains whose mean metrics normalise the cost (paper: 5 gains evenly
        spanning the feasible set). Ignored when ``normalizers`` is given.
    normalizers : array_like of shape (4,), optional
        Explicit normalisers (a digital twin reuses its plant's).
    cost_noise_std : float
        Standard deviation of the additive cost noise ``epsilon`` of
        ``J = J_hat + epsilon`` (paper, Sec. II), dimensionless.
    max_experiments : int
        Experiments per episode (tuning session), used for the observation.
    out_of_bounds : {"raise", "clip", "allow"}
        Gains outside the feasible set raise ``ValueError`` (default), are
        clipped into it, or are run as given.
    unstable_cost : float
        Finite cost reported for a diverging experiment (``info["unstable"]``).
    render_mode : {None, "rgb_array"}
        ``"rgb_array"`` renders the last step response.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 1}

    def __init__(
        self,
        loop: ClosedLoop,
        gain_low,
        gain_high,
        weights,
        reference_gains=None,
        normalizers=None,
        cost_noise_std: float = 0.0,
        max_experiments: int = 35,
        out_of_bounds: str = "raise",
        unstable_cost: float = 10.0,
        render_mode: str | None = None,
    ) -> None:
        self.loop = loop
        self.gain_names = tuple(loop.controller.gain_names)
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
        self.weights = _validated_vector("weights", weights, len(METRIC_NAMES), positive=True)
        if normalizers is None:
            reference = np.atleast_2d(np.asarray(reference_gains, dtype=float))
            clean = loop.replace(output_noise_std=0.0)
            normalizers = clean.metrics(clean.simulate(reference, rng=np.random.default_rng(0))).mean(axis=0)
        self.normalizers = _validated_vector("normalizers", normalizers, len(METRIC_NAMES), positive=True,
                                             floor=1e-9)
        if not np.isfinite(cost_noise_std) or cost_noise_std < 0.0:
            raise ValueError(f"cost_noise_std: must be a finite number >= 0, got {cost_noise_std}")
        self.cost_noise_std = float(cost_noise_std)
        if int(max_experiments) < 1:
            raise ValueError(f"max_experiments: must be >= 1, got {max_experiments}")
        self.max_experiments = int(max_experiments)
        if out_of_bounds not in OUT_OF_BOUNDS_POLICIES:
            raise ValueError(f"out_of_bounds: must be one of {OUT_OF_BOUNDS_POLICIES}, got {out_of_bounds!r}")
        self.out_of_bounds = out_of_bounds
        if not np.isfinite(unstable_cost):
            raise ValueError(f"unstable_cost: must be finite, got {unstable_cost}")
        self.unstable_cost = float(unstable_cost)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode: must be None or one of {self.metadata['render_modes']}, "
                             f"got {render_mode!r}")
        self.render_mode = render_mode
        self.experiment_index = 0
        self._best_cost = np.inf
        self._last_response: StepResponse | None = None
        self._last_obs = self._observation(None, None, None)

    # -- Gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start a new tuning session (experiment counter and best cost reset)."""
        super().reset(seed=seed)
        self.experiment_index = 0
        self._best_cost = np.inf
        self._last_response = None
        self._last_obs = self._observation(None, None, None)
        return self._last_obs.copy(), {"experiment_index": 0}

    def step(self, action):
        """Run one closed-loop step experiment at the gains ``action``."""
        gains = self.validate_gains(action)
        loop = self.loop_for_experiment(self.experiment_index)
        response = loop.simulate(gains[None, :], rng=self.np_random)
        metrics = loop.metrics(response)[0]
        unstable = bool(response.unstable[0])
        clean_cost = float(self.cost(metrics))
        if unstable:
            cost = self.unstable_cost
        else:
            noise = self.cost_noise_std * self.np_random.standard_normal() if self.cost_noise_std else 0.0
            cost = clean_cost + noise
        true_cost = float(self.evaluate(gains[None, :], experiment_index=self.experiment_index)[1][0])
        self._best_cost = min(self._best_cost, cost)
        self._last_response = response
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
        info.update(self.extra_info(self.experiment_index))
        self.experiment_index += 1
        self._last_obs = self._observation(gains, metrics, cost)
        return self._last_obs.copy(), -cost, False, False, info

    def render(self):
        """RGB array of the last step response (``render_mode="rgb_array"``)."""
        if self.render_mode != "rgb_array":
            return None
        from gbo_envs.plotting import figure_to_rgb, response_figure

        fig = response_figure(self.loop, self._last_response)
        return figure_to_rgb(fig)

    # -- experiment helpers ----------------------------------------------------------------------
    def validate_gains(self, action) -> np.ndarray:
        """Check ``action`` and return it as a float array of shape (n_gains,).

        Raises
        ------
        ValueError
            Wrong shape, NaN/inf, or (with ``out_of_bounds="raise"``) a gain
            outside the feasible set; the message names the gain and its range.
        """
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
        """Noise-free metrics and cost for a batch of gains, without counting an experiment.

        Parameters
        ----------
        gains : ndarray of shape (batch, n_gains)
        experiment_index : int, optional
            For time-varying plants: evaluate the plant as it is at this experiment
            (default: the next experiment).

        Returns
        -------
        metrics : ndarray of shape (batch, 4)
        cost : ndarray of shape (batch,)
            ``unstable_cost`` where the loop diverges.
        """
        index = self.experiment_index if experiment_index is None else experiment_index
        loop = self._noise_free(self.loop_for_experiment(index))
        response = loop.simulate(np.atleast_2d(gains), rng=np.random.default_rng(0))
        metrics = loop.metrics(response)
        cost = np.where(response.unstable, self.unstable_cost, self.cost(metrics))
        return metrics, cost

    def _noise_free(self, loop: ClosedLoop) -> ClosedLoop:
        """``loop`` without sensor noise; the copy is cached, since it re-discretises the plant."""
        if loop.output_noise_std == 0.0:
            return loop
        cached = self.__dict__.get("_noise_free_cache")
        if cached is None or cached[0] is not loop:
            cached = (loop, loop.replace(output_noise_std=0.0))
            self._noise_free_cache = cached
        return cached[1]

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
        best = self._best_cost
        done = self.experiment_index / self.max_experiments
        return np.concatenate([gains, metrics / self.normalizers, [cost, best, done]]).astype(np.float64)


def _validated_vector(name: str, values, size: int, positive: bool = False, floor: float | None = None) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if array.shape != (size,) or not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: expected {size} finite numbers, got {values!r}")
    if floor is not None:
        array = np.maximum(array, floor)
    if positive and np.any(array <= 0.0):
        raise ValueError(f"{name}: every entry must be > 0, got {array}")
    return array
