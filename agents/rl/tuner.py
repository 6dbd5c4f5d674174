"""``RLTuner``: stable-baselines3 (SAC or PPO) behind the ``ask``/``tell`` tuner API."""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import numpy as np

from agents.base import Tuner
from agents.rl.learners import IsolatedRNG, make_driver
from agents.rl.mdp import TuningMDPEnv, TuningObserver, default_horizon, rescaled
from agents.utils import env_id, progress_bar

__all__ = ["RLTuner", "ALGORITHMS", "MODES"]

#: Selectable stable-baselines3 algorithms.
ALGORITHMS = ("sac", "ppo")
#: Where the policy learns: on the plant only, or on a model first.
MODES = ("plant", "twin")


class RLTuner(Tuner):
    """Reinforcement-learning tuner over stable-baselines3: every plant experiment counts.

    The tuning MDP (see :mod:`agents.rl.mdp`)
    -----------------------------------------
    * **Action**: the next gains, in ``[-1, 1]`` per gain through Gymnasium's
      ``RescaleAction`` (``-1`` = ``gain_min``, ``+1`` = ``gain_max``).
    * **Observation** (n_gains + 7 floats): last gains in ``[-1, 1]``, last
      normalised metrics ``f_i / n_i`` (overshoot, settling, rise, ITAE), last
      cost ``J``, best ``J`` of the episode, fraction ``k / H`` of the episode
      used; centre gains and zeros at the start of an episode.
    * **Reward**: ``-J``, the measured cost.
    * **Episode**: ``horizon`` experiments (default: the env's
      ``max_episode_steps``, 35 for ``DCMotor-v0``), truncated, never
      terminated. A new episode restarts the agent's observation only; the plant
      is not reset (a tuning session cannot undo experiments).

    Every action the agent takes on the plant, exploratory or not, is one real
    experiment and one row of the result: the ``run`` loop makes exactly
    ``budget`` plant experiments, the learning happens in between.

    The ask/tell bridge
    -------------------
    SB3's ``learn`` owns its interaction loop, so the tuner drives SB3 step by
    step instead (:mod:`agents.rl.learners`): ``ask`` maps the policy's action
    for the current observation to gains; ``tell`` turns the measured cost and
    metrics into the reward and next observation, stores the transition (SAC:
    replay buffer; PPO: rollout buffer) and runs SB3's ``train`` when due. No
    threads, no queues: the same seed gives the same gains, bit for bit.

    Modes
    -----
    ``mode="plant"``: the agent learns on the plant from scratch; the first
    ``learning_starts`` experiments are uniform random gains (SAC's warm-up).

    ``mode="twin"`` (train-on-twin, the sim-to-real baseline): before the
    first plant experiment, the policy is trained for ``pretrain_steps``
    experiments on ``model_env`` (the nominal identified model, a fitted twin,
    any plant-like env). Those are not plant experiments: they are counted in
    ``result.info["model_experiments"]``. The first plant experiment is the
    trained policy's deterministic action (the deployed controller); afterwards
    the agent fine-tunes on plant data (``finetune=True``, sampled actions) or
    keeps acting deterministically (``finetune=False``).

    Parameters
    ----------
    algorithm : {"sac", "ppo"}, default "sac"
    mode : {"plant", "twin"}, default "plant"
    horizon : int, optional
        Episode length ``H`` in experiments (default: the env's ``max_episode_steps``).
    gamma : float, default 0.5
        Discount. The plant carries no state from one experiment to the next,
        so an action's value is mostly its own reward; a short horizon of
        credit learns faster from few experiments.
    learning_rate : float, default 3e-3
    net_arch : sequence of int, default (64, 64)
        Hidden layers of the actor and the critic.
    learning_starts : int, default 5
        SAC: random warm-up experiments (plant mode) and transitions before the first update.
    train_freq : int, default 1
        SAC: train after every ``train_freq`` experiments.
    gradient_steps : int, default 32
        SAC: gradient steps per training call (many, as data is scarce and costly).
    batch_size : int, default 32
        SAC: minibatch size; PPO: minibatch size of each epoch.
    tau : float, default 0.02
        SAC: target-network soft-update rate.
    n_steps : int, default 8
        PPO: experiments per rollout (one policy update per rollout).
    n_epochs : int, default 10
        PPO: epochs per update.
    model_env : gymnasium.Env, str or callable, optional
        ``mode="twin"``: the model to train on: an env, an env id (made with
        ``model_kwargs``), or ``callable(plant_env) -> env``. Default: the
        plant's own id with ``noise=False`` and the plant's nominal parameters
        (``plant_params``), i.e. the noise-free nominal model. A plant with
        physical effects (a rig env) needs ``model_env`` given explicitly: its
        own id would hand the policy the effects it is not meant to know.
    model_kwargs : dict, optional
        Keyword arguments for ``gym.make`` when ``model_env`` is an id (the plant's
        cost ``normalizers`` are passed too unless given here, so that model and
        plant costs share one scale).
    pretrain_steps : int, default 2000
        ``mode="twin"``: model experiments before deployment.
    pretrain_gradient_steps : int, default 1
        SAC, ``mode="twin"``: gradient steps per model experiment (model data is
        cheap, so the usual one update per step).
    finetune : bool, default True
        ``mode="twin"``: keep learning from plant experiments.
    device : str, default "cpu"
    torch_threads : int or None, default 1
        torch threads while the tuner trains or acts (restored afterwards);
        one is fastest for these small networks. ``None`` leaves torch's setting.
    algorithm_kwargs : dict, optional
        Extra keyword arguments for the SB3 algorithm (override the above).
    progress : bool, default False
        Show a progress bar over the model pre-training.
    """

    name = "rl"

    def __init__(
        self,
        *,
        algorithm: str = "sac",
        mode: str = "plant",
        horizon: int | None = None,
        gamma: float = 0.5,
        learning_rate: float = 3e-3,
        net_arch=(64, 64),
        learning_starts: int = 5,
        train_freq: int = 1,
        gradient_steps: int = 32,
        batch_size: int = 32,
        tau: float = 0.02,
        n_steps: int = 8,
        n_epochs: int = 10,
        model_env=None,
        model_kwargs: dict | None = None,
        pretrain_steps: int = 2000,
        pretrain_gradient_steps: int = 1,
        finetune: bool = True,
        device: str = "cpu",
        torch_threads: int | None = 1,
        algorithm_kwargs: dict | None = None,
        progress: bool = False,
    ) -> None:
        if algorithm not in ALGORITHMS:
            raise ValueError(f"algorithm: must be one of {ALGORITHMS}, got {algorithm!r}")
        if mode not in MODES:
            raise ValueError(f"mode: must be one of {MODES}, got {mode!r}")
        if horizon is not None and int(horizon) < 1:
            raise ValueError(f"horizon: must be an integer >= 1, got {horizon}")
        if int(pretrain_steps) < 0:
            raise ValueError(f"pretrain_steps: must be >= 0, got {pretrain_steps}")
        for label, value in (("learning_starts", learning_starts), ("gradient_steps", gradient_steps),
                             ("pretrain_gradient_steps", pretrain_gradient_steps)):
            if int(value) < 0:
                raise ValueError(f"{label}: must be >= 0, got {value}")
        for label, value in (("train_freq", train_freq), ("batch_size", batch_size), ("n_steps", n_steps),
                             ("n_epochs", n_epochs)):
            if int(value) < 1:
                raise ValueError(f"{label}: must be >= 1, got {value}")
        self.algorithm = algorithm
        self.mode = mode
        self.horizon = horizon
        self.gamma = float(gamma)
        self.learning_rate = float(learning_rate)
        self.net_arch = tuple(int(n) for n in net_arch)
        self.learning_starts = int(learning_starts)
        self.train_freq = int(train_freq)
        self.gradient_steps = int(gradient_steps)
        self.batch_size = int(batch_size)
        self.tau = float(tau)
        self.n_steps = int(n_steps)
        self.n_epochs = int(n_epochs)
        self.model_env = model_env
        self.model_kwargs = dict(model_kwargs or {})
        self.pretrain_steps = int(pretrain_steps)
        self.pretrain_gradient_steps = int(pretrain_gradient_steps)
        self.finetune = bool(finetune)
        self.device = device
        self.torch_threads = None if torch_threads is None else int(torch_threads)
        self.algorithm_kwargs = dict(algorithm_kwargs or {})
        self.progress = bool(progress)
        self._params = {
            "algorithm": algorithm, "mode": mode, "horizon": horizon, "gamma": self.gamma,
            "learning_rate": self.learning_rate, "net_arch": list(self.net_arch),
            "learning_starts": self.learning_starts, "train_freq": self.train_freq,
            "gradient_steps": self.gradient_steps, "batch_size": self.batch_size, "tau": self.tau,
            "n_steps": self.n_steps, "n_epochs": self.n_epochs,
            "model_env": model_env if isinstance(model_env, str) or model_env is None else repr(model_env),
            "model_kwargs": self.model_kwargs, "pretrain_steps": self.pretrain_steps,
            "pretrain_gradient_steps": self.pretrain_gradient_steps, "finetune": self.finetune,
            "device": device, "torch_threads": self.torch_threads, "algorithm_kwargs": self.algorithm_kwargs,
        }

    # -- session set-up ----------------------------------------------------------------------------
    def _setup(self) -> None:
        if self.env is None:
            raise ValueError("RLTuner needs the plant env: use run(env, budget) or setup(space, seed, env=env)")
        horizon = default_horizon(self.env) if self.horizon is None else int(self.horizon)
        self._observer = TuningObserver.for_env(self.env, horizon=horizon)
        self._rescale = rescaled(self.env)
        self._sb3_seed = int(self.seed) if self.seed is not None else int(self.rng.integers(2**31 - 1))
        self._rng_state = IsolatedRNG(self.torch_threads)
        self._n_plant = 0
        self._model_experiments = 0
        self._pretrain_time = 0.0
        train_env = self._build_model_env() if self.mode == "twin" else self.env
        with self._rng_state.active():
            self._model = self._build_algorithm(TuningMDPEnv(train_env, horizon=horizon,
                                                             normalizers=self._observer.normalizers))
            self._driver = make_driver(self._model, self.learning_starts, self.train_freq, self.gradient_steps,
                                       self.batch_size)
        if self.mode == "twin" and self.pretrain_steps:
            self._pretrain(train_env, horizon)
        self._observation = self._observer.reset()

    def _build_algorithm(self, mdp_env: TuningMDPEnv):
        """The SB3 model; it reads its spaces from the tuning MDP env (which it never steps)."""
        policy_kwargs = {"net_arch": list(self.net_arch)}
        if self.algorithm == "sac":
            from stable_baselines3 import SAC

            kwargs = {"learning_rate": self.learning_rate, "buffer_size": 100_000, "learning_starts": 0,
                      "batch_size": self.batch_size, "tau": self.tau, "gamma": self.gamma,
                      "train_freq": self.train_freq, "gradient_steps": self.gradient_steps,
                      "policy_kwargs": policy_kwargs}
            kwargs.update(self.algorithm_kwargs)
            return SAC("MlpPolicy", mdp_env, seed=self._sb3_seed, device=self.device, verbose=0, **kwargs)
        from stable_baselines3 import PPO

        kwargs = {"learning_rate": self.learning_rate, "n_steps": self.n_steps,
                  "batch_size": min(self.batch_size, self.n_steps), "n_epochs": self.n_epochs, "gamma": self.gamma,
                  "gae_lambda": 0.95, "policy_kwargs": policy_kwargs}
        kwargs.update(self.algorithm_kwargs)
        return PPO("MlpPolicy", mdp_env, seed=self._sb3_seed, device=self.device, verbose=0, **kwargs)

    def _build_model_env(self) -> gym.Env:
        """The model the policy pre-trains on (``mode="twin"``)."""
        model_env = self.model_env
        if model_env is None:
            plant, spec = self.env.unwrapped, self.env.spec
            if spec is None:
                raise ValueError("model_env: the plant env has no registered id; pass model_env explicitly")
            if getattr(getattr(plant, "loop", None), "effects", ()):
                raise ValueError(f"model_env: {spec.id} has physical effects its nominal model lacks; pass the "
                                 "nominal model explicitly, e.g. model_env='gbo_envs/DCMotor-v0', "
                                 "model_kwargs={'noise': False}")
            kwargs = {**(spec.kwargs or {}), **getattr(plant, "plant_params", {}), "noise": False,
                      **self.model_kwargs}
            return gym.make(spec.id, **kwargs)
        if isinstance(model_env, str):
            # the model's costs on the plant's scale: reuse the plant's cost normalisers unless told otherwise
            normalizers = getattr(self.env.unwrapped, "normalizers", None)
            kwargs = dict(self.model_kwargs)
            if normalizers is not None and "normalizers" not in kwargs:
                kwargs["normalizers"] = normalizers
            return gym.make(model_env, **kwargs)
        if isinstance(model_env, gym.Env):
            return model_env
        if callable(model_env):
            return model_env(self.env)
        raise TypeError(f"model_env: expected an env, an env id or a callable, got {type(model_env).__name__}")

    def _pretrain(self, model_env: gym.Env, horizon: int) -> None:
        """Train on the model for ``pretrain_steps`` model experiments (not plant experiments)."""
        mdp = TuningMDPEnv(model_env, horizon=horizon, normalizers=self._observer.normalizers)
        start = time.perf_counter()
        plant_gradient_steps = getattr(self._driver, "gradient_steps", None)
        if plant_gradient_steps is not None:
            self._driver.gradient_steps = self.pretrain_gradient_steps
        bar = progress_bar(self.pretrain_steps, f"rl pre-training on {env_id(model_env)}", self.progress)
        observation, _ = mdp.reset(seed=self._sb3_seed)
        try:
            for step in range(self.pretrain_steps):
                with self._rng_state.active():
                    if self.algorithm == "sac" and step < self.learning_starts:
                        action = self.rng.uniform(-1.0, 1.0, self._observer.low.size)
                    else:
                        action = self._driver.act(observation, deterministic=False)
                next_observation, reward, _, truncated, _ = mdp.step(action)
                with self._rng_state.active():
                    self._driver.observe(observation, action, float(reward), next_observation, truncated)
                self._model_experiments += 1
                observation = mdp.reset()[0] if truncated else next_observation
                bar.update(1)
        finally:
            bar.close()
            if plant_gradient_steps is not None:
                self._driver.gradient_steps = plant_gradient_steps
            self._pretrain_time = time.perf_counter() - start

    # -- ask / tell --------------------------------------------------------------------------------
    def _acts_deterministically(self) -> bool:
        if self.mode == "plant":
            return False
        return self._n_plant == 0 or not self.finetune

    def _ask(self) -> np.ndarray:
        warmup = self.mode == "plant" and self.algorithm == "sac" and self._n_plant < self.learning_starts
        if warmup:
            action = self.rng.uniform(-1.0, 1.0, self._observer.low.size)
        else:
            with self._rng_state.active():
                action = self._driver.act(self._observation, deterministic=self._acts_deterministically())
        return np.asarray(self._rescale.action(action), dtype=float)

    def _tell(self, gains: np.ndarray, cost: float, record: dict | None) -> None:
        metrics = (record or {}).get("metrics")
        if metrics is None:
            metrics = np.full(4, np.nan)
        action = self._observer.to_action(gains)
        next_observation, reward, truncated = self._observer.update(gains, cost, metrics)
        learns = self.mode == "plant" or self.finetune
        if learns:
            with self._rng_state.active():
                self._driver.observe(self._observation, action, reward, next_observation, truncated)
        self._n_plant += 1
        self._observation = self._observer.reset() if truncated else next_observation

    def run_summary(self) -> dict[str, Any]:
        """Algorithm, mode, model experiments (not plant experiments), gradient updates, pre-training time."""
        return {
            "algorithm": self.algorithm,
            "mode": self.mode,
            "horizon": self._observer.horizon,
            "model_experiments": self._model_experiments,
            "plant_experiments": self._n_plant,
            "transitions_learned": self._driver.n_transitions,
            "policy_updates": self._driver.n_updates,
            "pretrain_time_s": round(self._pretrain_time, 3),
            "sb3_seed": self._sb3_seed,
        }
