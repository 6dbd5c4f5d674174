"""The tuning MDP that a reinforcement-learning agent sees, and a Gymnasium env of it.

One step of the MDP is one closed-loop experiment:

* **action** ``a`` of shape (n_gains,) in ``[-1, 1]``: the next gains, mapped
  onto the feasible set by Gymnasium's :class:`~gymnasium.wrappers.RescaleAction`
  (``-1`` is ``gain_min``, ``+1`` is ``gain_max``);
* **observation** of shape (n_gains + 7,), float32: the last gains rescaled to
  ``[-1, 1]``, the last normalised metrics ``f_i / n_i`` (overshoot, settling
  time, rise time, ITAE; ``n_i`` the plant's cost normalisers), the last cost
  ``J``, the best cost of the current episode, and the fraction ``k / H`` of the
  episode used. Metrics and costs are clipped to ``[-clip, clip]`` (a diverging
  experiment costs ``unstable_cost = 10``). Before the first experiment of an
  episode: centre gains (zeros) and zeros, as the plant env's own reset
  observation;
* **reward** ``-J``, the measured (noisy) cost of the experiment;
* **episode**: ``H`` experiments (default the env's ``max_episode_steps``),
  never terminated, only truncated. A new episode restarts the *agent's*
  observation; it does **not** reset the plant: the experiment counter, the
  plant's drift and its noise stream go on, since a tuning session cannot undo
  an experiment.

The plant has no state that carries from one experiment to the next, so the
return of an action is its own reward; the observation lets a policy steer
from where it is (a state-dependent search), and the best cost lets it know
how good that is.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import RescaleAction

from gbo_envs.metrics import METRIC_NAMES

__all__ = ["TuningObserver", "TuningMDPEnv", "rescaled", "default_horizon"]


def rescaled(env: gym.Env) -> RescaleAction:
    """``env`` behind Gymnasium's ``RescaleAction`` so that actions live in ``[-1, 1]``.

    The action space is float32, the dtype stable-baselines3 wants (a float64 Box makes its
    env checker warn); the gains handed to ``env`` are float64, rescaled with its float64 bounds.
    """
    wrapper = RescaleAction(env, min_action=-1.0, max_action=1.0)
    wrapper.action_space = spaces.Box(-1.0, 1.0, shape=env.action_space.shape, dtype=np.float32)
    return wrapper


def default_horizon(env: gym.Env, fallback: int = 35) -> int:
    """Episode length ``H``: the env's ``max_episode_steps``, else its ``max_experiments``, else ``fallback``."""
    spec = getattr(env, "spec", None)
    if spec is not None and spec.max_episode_steps:
        return int(spec.max_episode_steps)
    return int(getattr(env.unwrapped, "max_experiments", fallback))


class TuningObserver:
    """Builds the observations and rewards of the tuning MDP from experiment records.

    Parameters
    ----------
    low, high : array_like of shape (n_gains,)
        Feasible set in physical units.
    normalizers : array_like of shape (4,), optional
        Metric normalisers ``n_i`` (default: ones).
    horizon : int
        Episode length ``H`` in experiments.
    clip : float, default 10.0
        Bound on the normalised metrics and the costs in the observation.
    """

    def __init__(self, low, high, normalizers=None, horizon: int = 35, clip: float = 10.0) -> None:
        self.low = np.asarray(low, dtype=float)
        self.high = np.asarray(high, dtype=float)
        self.normalizers = np.ones(len(METRIC_NAMES)) if normalizers is None else np.asarray(normalizers, float)
        if int(horizon) < 1:
            raise ValueError(f"horizon: must be an integer >= 1, got {horizon}")
        self.horizon = int(horizon)
        self.clip = float(clip)
        n_gains = self.low.size
        n_metrics = len(METRIC_NAMES)
        obs_low = np.concatenate([-np.ones(n_gains), np.zeros(n_metrics), [-self.clip, -self.clip, 0.0]])
        obs_high = np.concatenate([np.ones(n_gains), np.full(n_metrics, self.clip), [self.clip, self.clip, 1.0]])
        self.observation_space = spaces.Box(obs_low.astype(np.float32), obs_high.astype(np.float32),
                                            dtype=np.float32)
        self.step_in_episode = 0
        self.best = np.inf

    @classmethod
    def for_env(cls, env: gym.Env, horizon: int | None = None, normalizers=None, clip: float = 10.0):
        """Observer for a plant env: its feasible set, its normalisers (unless given) and ``H``."""
        plant = env.unwrapped
        if normalizers is None:
            normalizers = getattr(plant, "normalizers", None)
        return cls(plant.action_space.low, plant.action_space.high, normalizers,
                   default_horizon(env) if horizon is None else horizon, clip)

    def to_action(self, gains) -> np.ndarray:
        """Gains of shape (n_gains,) as an action in ``[-1, 1]``."""
        return np.clip(2.0 * (np.asarray(gains, float) - self.low) / (self.high - self.low) - 1.0, -1.0, 1.0)

    def reset(self) -> np.ndarray:
        """Start an agent episode: the reset observation (centre gains, zeros)."""
        self.step_in_episode = 0
        self.best = np.inf
        return np.zeros(self.observation_space.shape, dtype=np.float32)

    def update(self, gains, cost: float, metrics) -> tuple[np.ndarray, float, bool]:
        """Account for one experiment of the episode.

        Parameters
        ----------
        gains : array_like of shape (n_gains,)
        cost : float
            Measured cost ``J``.
        metrics : dict or array_like of shape (4,)
            The record's metrics (raw, in their units).

        Returns
        -------
        observation : ndarray of shape (n_gains + 7,)
        reward : float
            ``-J``.
        truncated : bool
            Whether the episode has reached ``H`` experiments (call :meth:`reset` next).
        """
        if isinstance(metrics, dict):
            metrics = [metrics.get(name, np.nan) for name in METRIC_NAMES]
        scaled = np.asarray(metrics, dtype=float) / self.normalizers
        scaled = np.clip(np.nan_to_num(scaled, nan=self.clip, posinf=self.clip), 0.0, self.clip)
        cost = float(cost)
        self.best = min(self.best, cost)
        self.step_in_episode += 1
        observation = np.concatenate([
            self.to_action(gains), scaled,
            np.clip([cost, self.best], -self.clip, self.clip), [self.step_in_episode / self.horizon],
        ]).astype(np.float32)
        return observation, -cost, self.step_in_episode >= self.horizon


class TuningMDPEnv(gym.Env):
    """The tuning MDP over a plant env, as a Gymnasium env (see the module docstring).

    SB3 can learn on it directly (``SAC("MlpPolicy", TuningMDPEnv(env)).learn(...)``);
    :class:`~agents.rl.RLTuner` steps it by hand to pre-train on a model.

    Parameters
    ----------
    env : gymnasium.Env
        A plant env (``step`` takes gains, returns the experiment record in ``info``).
    horizon : int, optional
        Episode length ``H`` (default: the env's ``max_episode_steps``).
    normalizers : array_like of shape (4,), optional
        Metric normalisers for the observation (default: the env's).
    clip : float, default 10.0

    Notes
    -----
    ``reset(seed=...)`` starts a tuning session: it seeds and resets the plant.
    ``reset()`` without a seed (what a learning loop calls after truncation)
    starts a new agent episode on the same, un-reset plant.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, env: gym.Env, horizon: int | None = None, normalizers=None, clip: float = 10.0) -> None:
        self.plant = rescaled(env)
        self.observer = TuningObserver.for_env(env, horizon=horizon, normalizers=normalizers, clip=clip)
        self.horizon = self.observer.horizon
        self.observation_space = self.observer.observation_space
        n_gains = self.observer.low.size
        self.action_space = spaces.Box(-1.0, 1.0, shape=(n_gains,), dtype=np.float32)
        self._session_started = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """New agent episode; with ``seed`` (or on the first call) also a new plant session."""
        super().reset(seed=seed)
        if seed is not None or not self._session_started:
            self.plant.reset(seed=seed)
            self._session_started = True
        return self.observer.reset(), {}

    def step(self, action):
        """Run one experiment at ``action`` in ``[-1, 1]``; reward ``-J``, truncated after ``H`` steps."""
        action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        _, _, _, _, info = self.plant.step(action)
        observation, reward, truncated = self.observer.update(info["gains"], info["cost"], info["metrics"])
        return observation, reward, False, truncated, info

    def close(self) -> None:
        """Close the plant env."""
        self.plant.close()
