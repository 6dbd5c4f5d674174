"""Step-by-step drivers of stable-baselines3 algorithms, so that ``ask``/``tell`` stay synchronous.

SB3's ``learn`` owns the interaction loop (it calls ``env.step`` itself). A
tuner is driven the other way round: the caller runs the experiment. These
drivers therefore do by hand what SB3's ``collect_rollouts`` does, one
transition at a time, with SB3's own policy, buffers and ``train``:

* off-policy (SAC): ``act`` samples from the policy (``model.predict``),
  ``observe`` stores the transition in ``model.replay_buffer`` and calls
  ``model.train(gradient_steps, batch_size)`` every ``train_freq`` transitions
  once ``learning_starts`` transitions are stored;
* on-policy (PPO): ``act`` evaluates the policy (action, value, log-prob),
  ``observe`` adds the step to ``model.rollout_buffer`` (bootstrapping the
  reward on truncation as SB3 does), and when ``n_steps`` steps are in, it
  computes GAE returns and calls ``model.train()``.

All randomness (SB3 seeds Python's ``random``, NumPy's global generator and
torch's; the replay buffer samples with NumPy's global generator) runs inside
:class:`IsolatedRNG`, which keeps the driver's own generator states and
restores the caller's, so a run is reproducible whatever else uses those
global generators in between. It also runs torch on a fixed number of threads
(one by default: the networks are tiny, and on a busy machine several threads
per gradient step are up to ten times slower than one).
"""

from __future__ import annotations

import random
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.logger import configure
from stable_baselines3.common.utils import obs_as_tensor

__all__ = ["IsolatedRNG", "OffPolicyDriver", "OnPolicyDriver", "make_driver"]


class IsolatedRNG:
    """Private states of the global ``random``, NumPy and torch generators, and torch's thread count.

    Parameters
    ----------
    threads : int or None, default 1
        torch intra-op threads inside :meth:`active` (``None``: leave as is).
    """

    def __init__(self, threads: int | None = 1) -> None:
        self._state: tuple | None = None
        self.threads = threads

    @staticmethod
    def _capture() -> tuple:
        return random.getstate(), np.random.get_state(), torch.get_rng_state()

    @staticmethod
    def _restore(state: tuple) -> None:
        random.setstate(state[0])
        np.random.set_state(state[1])
        torch.set_rng_state(state[2])

    @contextmanager
    def active(self) -> Iterator[None]:
        """Swap in the private states for the ``with`` block (the first block starts from the caller's)."""
        outside = self._capture()
        outside_threads = torch.get_num_threads()
        if self._state is not None:
            self._restore(self._state)
        if self.threads is not None:
            torch.set_num_threads(int(self.threads))
        try:
            yield
        finally:
            self._state = self._capture()
            self._restore(outside)
            torch.set_num_threads(outside_threads)


class OffPolicyDriver:
    """Transition-by-transition training of an off-policy SB3 model (SAC, TD3, DDPG).

    Parameters
    ----------
    model : stable_baselines3.common.off_policy_algorithm.OffPolicyAlgorithm
    learning_starts : int
        Transitions stored before the first gradient step.
    train_freq : int
        Train after every ``train_freq`` transitions.
    gradient_steps : int
        Gradient steps per training call.
    batch_size : int
        Transitions per gradient step (capped by the number stored).
    """

    def __init__(self, model: BaseAlgorithm, learning_starts: int, train_freq: int, gradient_steps: int,
                 batch_size: int) -> None:
        self.model = model
        self.learning_starts = int(learning_starts)
        self.train_freq = max(1, int(train_freq))
        self.gradient_steps = int(gradient_steps)
        self.batch_size = int(batch_size)
        self.n_transitions = 0
        self.n_updates = 0
        model.set_logger(configure(folder=None, format_strings=[]))

    def act(self, observation: np.ndarray, deterministic: bool) -> np.ndarray:
        """Action in ``[-1, 1]`` of shape (n_gains,) for ``observation``."""
        action, _ = self.model.predict(observation, deterministic=deterministic)
        return np.clip(np.asarray(action, dtype=float), -1.0, 1.0)

    def observe(self, observation: np.ndarray, action: np.ndarray, reward: float, next_observation: np.ndarray,
                truncated: bool) -> None:
        """Store one transition and train when due.

        The tuning MDP never terminates, so every transition bootstraps
        (``done = False``), truncated or not, as SB3 does for time limits.
        """
        self.model.replay_buffer.add(observation[None], next_observation[None],
                                     np.asarray(action, np.float32)[None], np.array([reward], np.float32),
                                     np.array([False]), [{}])
        self.n_transitions += 1
        self.model.num_timesteps = self.n_transitions
        if self.n_transitions >= self.learning_starts and self.n_transitions % self.train_freq == 0:
            batch = min(self.batch_size, self.n_transitions)
            self.model.train(gradient_steps=self.gradient_steps, batch_size=batch)
            self.n_updates += self.gradient_steps


class OnPolicyDriver:
    """Step-by-step rollouts and updates of an on-policy SB3 model (PPO, A2C).

    Parameters
    ----------
    model : stable_baselines3.common.on_policy_algorithm.OnPolicyAlgorithm
        Its ``n_steps`` is the rollout length between updates.
    """

    def __init__(self, model: BaseAlgorithm) -> None:
        self.model = model
        self.n_transitions = 0
        self.n_updates = 0
        self._episode_start = True
        self._last: tuple[np.ndarray, np.ndarray, torch.Tensor, torch.Tensor] | None = None
        model.set_logger(configure(folder=None, format_strings=[]))
        model.rollout_buffer.reset()

    def act(self, observation: np.ndarray, deterministic: bool) -> np.ndarray:
        """Action in ``[-1, 1]`` of shape (n_gains,); remembers the raw Gaussian sample, value and log-prob."""
        policy = self.model.policy
        policy.set_training_mode(False)
        with torch.no_grad():
            obs = obs_as_tensor(observation[None], self.model.device)
            raw, value, log_prob = policy(obs, deterministic=deterministic)
        raw = raw.cpu().numpy()[0]
        action = np.clip(raw, -1.0, 1.0)
        self._last = (observation.copy(), action, raw, value, log_prob)
        return action.astype(float)

    def _value_and_log_prob(self, observation: np.ndarray, action: np.ndarray):
        last = self._last
        if last is not None and np.array_equal(last[0], observation) and np.allclose(last[1], action):
            return last[2], last[3], last[4]
        with torch.no_grad():  # an action the policy did not propose (a caller's own gains)
            obs = obs_as_tensor(observation[None], self.model.device)
            act = torch.as_tensor(np.asarray(action, np.float32)[None], device=self.model.device)
            value, log_prob, _ = self.model.policy.evaluate_actions(obs, act)
        return np.asarray(action, np.float32), value.flatten(), log_prob

    def observe(self, observation: np.ndarray, action: np.ndarray, reward: float, next_observation: np.ndarray,
                truncated: bool) -> None:
        """Add one step to the rollout; update the policy when ``n_steps`` steps are in."""
        model = self.model
        raw, value, log_prob = self._value_and_log_prob(observation, action)
        if truncated:  # time limit: bootstrap with the value of the last observation (SB3 issue #633)
            with torch.no_grad():
                reward += model.gamma * float(model.policy.predict_values(
                    obs_as_tensor(next_observation[None], model.device))[0, 0])
        model.rollout_buffer.add(observation[None], np.asarray(raw, np.float32)[None], np.array([reward]),
                                 np.array([self._episode_start]), value, log_prob)
        self._episode_start = bool(truncated)
        self.n_transitions += 1
        model.num_timesteps = self.n_transitions
        if model.rollout_buffer.full:
            with torch.no_grad():
                last_value = model.policy.predict_values(obs_as_tensor(next_observation[None], model.device))
            model.rollout_buffer.compute_returns_and_advantage(last_values=last_value,
                                                               dones=np.array([truncated]))
            model.train()
            model.rollout_buffer.reset()
            self.n_updates += 1


def make_driver(model: BaseAlgorithm, learning_starts: int, train_freq: int, gradient_steps: int,
                batch_size: int) -> OffPolicyDriver | OnPolicyDriver:
    """The driver matching ``model`` (off-policy if it has a replay buffer, else on-policy)."""
    if hasattr(model, "replay_buffer"):
        return OffPolicyDriver(model, learning_starts, train_freq, gradient_steps, batch_size)
    return OnPolicyDriver(model)
