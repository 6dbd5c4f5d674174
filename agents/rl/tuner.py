"""``RLTuner``: stable-baselines3 (SAC or PPO) behind the ``ask``/``tell`` tuner API."""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import numpy as np

from agents.base import Tuner
from agents.parameters import HasMethods, Interval, Options, validate_params
from agents.rl.learners import IsolatedRNG, make_driver
from agents.rl.mdp import TuningMDPEnv, TuningObserver, default_horizon, rescaled
from agents.run_display import env_id, progress_bar

__all__ = ["RLTuner", "ALGORITHMS", "MODES"]

#: Selectable stable-baselines3 algorithms.
ALGORITHMS = ("sac", "ppo")
#: Where the policy learns: on the plant only, or on a model first.
MODES = ("plant", "twin")

#: SB3 hyperparameters of each algorithm (SB3's names), overridden by ``algorithm_kwargs``. Few, costly
#: experiments: a high learning rate, many gradient steps per experiment (SAC) and short rollouts (PPO).
HYPERPARAMETERS = {
    "sac": {"learning_rate": 3e-3, "gamma": 0.5, "batch_size": 32, "tau": 0.02, "train_freq": 1,
            "learning_starts": 5, "buffer_size": 100_000, "policy_kwargs": {"net_arch": [64, 64]}},
    "ppo": {"learning_rate": 3e-3, "gamma": 0.5, "n_steps": 8, "batch_size": 32, "n_epochs": 10,
            "gae_lambda": 0.95, "policy_kwargs": {"net_arch": [64, 64]}},
}


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
    ``learning_starts`` experiments (5, see ``algorithm_kwargs``) are uniform random
    gains (SAC's warm-up).

    ``mode="twin"`` (train-on-twin, the sim-to-real baseline): before the
    first plant experiment, the policy is trained for ``pretrain_steps``
    experiments on ``model_env`` (the nominal identified model, a fitted twin,
    any plant-like env). Those are not plant experiments: they are counted in
    ``result.info["model_experiments"]``. The first plant experiment is the
    trained policy's deterministic action (the deployed controller); afterwards
    the agent fine-tunes on plant data with sampled actions.

    Parameters
    ----------
    algorithm : {"sac", "ppo"}, default "sac"
    mode : {"plant", "twin"}, default "plant"
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
        ``mode="twin"``: model experiments before deployment (SAC: one gradient
        step per model experiment, as model data is cheap).
    gradient_steps : int, default 32
        SAC: gradient steps per training call on plant data (many, as plant data
        is scarce and costly).
    algorithm_kwargs : dict, optional
        stable-baselines3 hyperparameters, by SB3's names, overriding
        :data:`HYPERPARAMETERS` (e.g. ``{"batch_size": 8, "learning_starts": 3}``).
        SAC's ``learning_starts`` is the number of random warm-up experiments
        (plant mode) and of transitions before the first update; ``train_freq``
        and ``batch_size`` also pace the tuner's own updates. PPO's
        ``batch_size`` is capped at ``n_steps``.
    progress : bool or None, default False
        Show a progress bar (stderr) over the model pre-training; ``None``: only when stderr is a terminal.
        Without it, the pre-training bar follows ``run(..., progress=...)`` (so ``gbo tune`` shows it).

    Notes
    -----
    The episode length ``H`` is the env's ``max_episode_steps``; the discount
    ``gamma = 0.5`` is short because the plant carries no state from one
    experiment to the next, so an action's value is mostly its own reward.
    torch runs with one thread while the tuner trains or acts (fastest for
    these small networks), on the CPU.
    """

    name = "rl"

    _parameter_constraints = {
        "algorithm": [Options(ALGORITHMS)],
        "mode": [Options(MODES)],
        "model_kwargs": [None, HasMethods(("keys",))],
        "pretrain_steps": [Interval(int, 0, None)],
        "gradient_steps": [Interval(int, 1, None)],
        "algorithm_kwargs": [None, HasMethods(("keys",))],
    }

    def __init__(self, *, algorithm: str = "sac", mode: str = "plant", model_env=None, model_kwargs: dict | None = None,
                 pretrain_steps: int = 2000, gradient_steps: int = 32, algorithm_kwargs: dict | None = None,
                 progress: bool | None = False) -> None:
        checked = validate_params(self._parameter_constraints, {
            "algorithm": algorithm, "mode": mode, "model_kwargs": model_kwargs, "pretrain_steps": pretrain_steps,
            "gradient_steps": gradient_steps, "algorithm_kwargs": algorithm_kwargs})
        if not (model_env is None or isinstance(model_env, (str, gym.Env)) or callable(model_env)):
            raise ValueError(f"model_env: must be None, an env, an env id or a callable, got {model_env!r}")
        self.algorithm = algorithm
        self.mode = mode
        self.model_env = model_env
        self.model_kwargs = dict(model_kwargs or {})
        self.pretrain_steps = checked["pretrain_steps"]
        self.gradient_steps = checked["gradient_steps"]
        self.algorithm_kwargs = dict(algorithm_kwargs or {})
        self.progress = None if progress is None else bool(progress)
        self._hyper = {**HYPERPARAMETERS[algorithm],
                                 **({"gradient_steps": self.gradient_steps} if algorithm == "sac" else {}),
                                 **self.algorithm_kwargs}
        for name in ("learning_starts", "train_freq", "batch_size", "n_steps", "n_epochs", "gradient_steps"):
            value = self._hyper.get(name)
            low = 0 if name == "learning_starts" else 1
            if value is not None and not Interval(int, low, None).admits(value):
                raise ValueError(f"algorithm_kwargs[{name!r}]: must be an int in [{low}, inf), got {value!r}")
        self._params = {
            "algorithm": algorithm, "mode": mode,
            "model_env": model_env if isinstance(model_env, str) or model_env is None else repr(model_env),
            "model_kwargs": self.model_kwargs, "pretrain_steps": self.pretrain_steps,
            "gradient_steps": self.gradient_steps, "algorithm_kwargs": self.algorithm_kwargs,
        }

    # -- session set-up ----------------------------------------------------------------------------
    def _setup(self) -> None:
        if self.env is None:
            raise ValueError("RLTuner needs the plant env: use run(env, budget) or setup(space, seed, env=env)")
        horizon = default_horizon(self.env)
        self._observer = TuningObserver.for_env(self.env, horizon=horizon)
        self._rescale = rescaled(self.env)
        self._sb3_seed = int(self.seed) if self.seed is not None else int(self.rng.integers(2**31 - 1))
        self._rng_state = IsolatedRNG(1)
        self._n_plant = 0
        self._model_experiments = 0
        self._pretrain_time = 0.0
        train_env = self._build_model_env() if self.mode == "twin" else self.env
        with self._rng_state.active():
            self._model = self._build_algorithm(TuningMDPEnv(train_env, horizon=horizon,
                                                             normalizers=self._observer.normalizers))
            self._driver = make_driver(self._model, self._hyper.get("learning_starts", 0),
                                       self._hyper.get("train_freq", 1), self._hyper.get("gradient_steps", 1),
                                       self._hyper["batch_size"])
        if self.mode == "twin" and self.pretrain_steps:
            self._pretrain(train_env, horizon)
        self._observation = self._observer.reset()

    def _build_algorithm(self, mdp_env: TuningMDPEnv):
        """The SB3 model; it reads its spaces from the tuning MDP env (which it never steps)."""
        kwargs = dict(self._hyper)
        if self.algorithm == "sac":
            from stable_baselines3 import SAC

            kwargs["learning_starts"] = 0  # the warm-up is the tuner's (random gains), the driver paces updates
            return SAC("MlpPolicy", mdp_env, seed=self._sb3_seed, **{"device": "cpu", "verbose": 0, **kwargs})
        from stable_baselines3 import PPO

        kwargs["batch_size"] = min(kwargs["batch_size"], kwargs["n_steps"])
        return PPO("MlpPolicy", mdp_env, seed=self._sb3_seed, **{"device": "cpu", "verbose": 0, **kwargs})

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
            self._driver.gradient_steps = 1
        bar = progress_bar(self.pretrain_steps, f"rl pre-training on {env_id(model_env)}",
                           self.progress or self._run_progress)
        observation, _ = mdp.reset(seed=self._sb3_seed)
        try:
            for step in range(self.pretrain_steps):
                with self._rng_state.active():
                    if self.algorithm == "sac" and step < self._hyper["learning_starts"]:
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
        return self._n_plant == 0

    def _ask(self) -> np.ndarray:
        warmup = self.mode == "plant" and self.algorithm == "sac" and self._n_plant < self._hyper["learning_starts"]
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
