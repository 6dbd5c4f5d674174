"""What a plant and a tuner do, as fingerprints: the arbiter of a shipped reference's staleness.

A reference run (:mod:`evaluation.references`) depends on the code of its tuner and of its
plant. Their source hashes (:mod:`evaluation.fingerprint`) change with every edit, also with
a refactor or a speed-up that keeps every number: such an edit must not make the references
stale, or every one of them costs a rebuild of hours. So a changed source is only a reason to
look: the reference is stale when what the code *does* changed.

- **A plant's behaviour** (:func:`plant_behaviour`): the env made with its kwargs, reset with
  the seeds :data:`PLANT_SEEDS`, then :data:`PLANT_EXPERIMENTS` experiments each at fixed gains
  across its action space (a time-varying env's seed 0 through its whole episode, so that the
  plant after a change or a drift is probed too): the costs and the recorded ``u`` and ``y``,
  and the env's shipped ground-truth table.
- **A tuner's behaviour** (:func:`tuner_behaviour`): its first :data:`TUNER_BUDGET` proposals
  and their costs on :data:`TUNER_ENV`, seed 0, as the study engine runs it
  (:func:`evaluation.study_runner.run_batch`: BLAS single-threaded).

Numbers enter the hash as decimal strings of :data:`SIGNIFICANT` significant digits, so that a
change of the last bits (a sum in another order) is not a change of behaviour. What the probes
do not reach is not seen: a change that moves a tuner only after its fifth experiment, or a
plant only away from the probed gains, leaves the fingerprint as it was, and so does a new numerical
stack (no source changed). ``python benchmarks/reference_reproduction.py`` reruns the references'
seeds on every plant to find those; rebuild them with ``gbo bench suite --rebuild-references --force``.
"""

from __future__ import annotations

import functools
import hashlib
import json

import gymnasium as gym
import numpy as np

import gbo_envs  # noqa: F401  (registers the envs)
from agents.thread_limits import single_thread
from evaluation import fingerprint
from evaluation.study_runner import BatchTask, run_batch
from gbo_envs.envs.time_varying import TimeVaryingMixin

__all__ = ["PLANT_EXPERIMENTS", "PLANT_SEEDS", "SIGNIFICANT", "TUNER_BUDGET", "TUNER_ENV", "forget",
           "plant_behaviour", "tuner_behaviour"]

#: Seeds of the plant probe's resets.
PLANT_SEEDS = (0, 1, 2)
#: Experiments after each reset of the plant probe (a time-varying env's first seed runs its whole episode).
PLANT_EXPERIMENTS = 3
#: Points of the action space the plant probe's gains cycle through (fractions of each gain's range).
PLANT_GAIN_FRACTIONS = (0.5, 0.25, 0.75, 0.4, 0.6)
#: The plant the tuner probe runs on, and its budget (plant experiments).
TUNER_ENV = "gbo_envs/DCMotor-v0"
TUNER_BUDGET = 5
#: Significant digits of the numbers hashed.
SIGNIFICANT = 9


def _digits(values) -> bytes:
    """``values`` as decimal strings of :data:`SIGNIFICANT` significant digits (inf and NaN as words)."""
    flat = np.asarray(values, dtype=float).ravel()
    return " ".join(np.format_float_scientific(v, precision=SIGNIFICANT - 1, unique=False) for v in flat).encode()


def plant_behaviour(env_id: str, env_kwargs: str | dict | None = None) -> str:
    """16 hex digits hashing what the plant ``env_id`` with ``env_kwargs`` does (see the module docstring).

    Parameters
    ----------
    env_id : str
        A registered env.
    env_kwargs : dict or JSON str, optional
        Its ``gym.make`` keyword arguments.
    """
    kwargs = json.loads(env_kwargs) if isinstance(env_kwargs, str) else dict(env_kwargs or {})
    return _plant_behaviour(env_id, json.dumps(kwargs, sort_keys=True))


@functools.cache
def _plant_behaviour(env_id: str, kwargs: str) -> str:
    digest = hashlib.sha256(f"{env_id}\0{kwargs}\0".encode())
    with single_thread(user_api=None):
        env = gym.make(env_id, **json.loads(kwargs))
        space = env.action_space
        episode = env.spec.max_episode_steps or PLANT_EXPERIMENTS
        varying = isinstance(env.unwrapped, TimeVaryingMixin)
        for seed in PLANT_SEEDS:
            env.reset(seed=seed)
            experiments = episode if varying and seed == PLANT_SEEDS[0] else PLANT_EXPERIMENTS
            for k in range(experiments):
                fraction = PLANT_GAIN_FRACTIONS[(seed + k) % len(PLANT_GAIN_FRACTIONS)]
                gains = space.low + fraction * (space.high - space.low)
                _, reward, _, _, info = env.step(gains.astype(space.dtype))
                record = info["experiment"]
                digest.update(_digits([reward]) + b"|" + _digits(record.u) + b"|" + _digits(record.y) + b"\0")
        env.close()
    table = fingerprint.truth_table_path(env_id)
    if table is not None:
        digest.update(b"table\0" + (fingerprint.REPO_ROOT / table).read_bytes())
    return digest.hexdigest()[:16]


def tuner_behaviour(name: str, params: str | dict | None = None) -> str:
    """16 hex digits hashing the registered tuner ``name``'s first proposals with ``params`` (see the module
    docstring).

    Parameters
    ----------
    name : str
        A registered tuner.
    params : dict or JSON str, optional
        Its constructor keyword arguments.
    """
    params = json.loads(params) if isinstance(params, str) else dict(params or {})
    return _tuner_behaviour(name, json.dumps(params, sort_keys=True))


@functools.cache
def _tuner_behaviour(name: str, params: str) -> str:
    task = BatchTask(study="behaviour", label=name, tuner=name, params=json.loads(params), batch=0, seed=0,
                     env_id=TUNER_ENV, env_kwargs={}, budget=TUNER_BUDGET)
    frame = run_batch(task)
    gain_names = list(gym.make(TUNER_ENV).unwrapped.gain_names)
    plant = frame[frame["source"] == "plant"]
    digest = hashlib.sha256(f"{name}\0{params}\0".encode())
    digest.update(_digits(plant[gain_names].to_numpy()) + b"|" + _digits(plant["cost"].to_numpy()))
    return digest.hexdigest()[:16]


def forget() -> None:
    """Forget the fingerprints computed so far (a long-lived process whose tuners or plants were changed; each
    is computed once per process otherwise)."""
    _plant_behaviour.cache_clear()
    _tuner_behaviour.cache_clear()
