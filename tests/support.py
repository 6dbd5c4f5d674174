"""Constants and helpers shared by test modules (fixtures live in the ``conftest.py`` files).

Plain module-level values, not fixtures, because tests also use them at import
time (in ``parametrize`` lists and in other module-level constants).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np

from gbo_envs import ClosedLoop, ContinuousPlant, PIController

#: the repository's root folder (examples/, benchmarks/)
REPO_ROOT = Path(__file__).resolve().parents[1]

#: the paper's DC motor ``G(s) = b0 / (s^2 + a1 s + a2)``: b0 (rad/s per V), a1 (1/s), a2 (1/s^2)
DC_MOTOR_PARAMS = np.array([9.544, 4.145, 4.199])
#: the DC motor plant with its 2 ms input delay
DC_PLANT = ContinuousPlant((9.544,), (1.0, 4.145, 4.199), delay=0.002)
#: input (V) that holds the DC motor at rest at 245 rad/s: 245 a2 / b0
U_REST = 245.0 * 4.199 / 9.544

#: columns of study results that hold wall-clock times (they differ between otherwise equal runs)
TIMING_COLUMNS = ["wall_time", "batch_wall_time"]


def dc_loop(*effects, duration: float = 5.0, **kwargs) -> ClosedLoop:
    """The DC motor's PI loop (2 ms samples, 245 -> 306 rad/s step) with optional effect blocks."""
    return ClosedLoop(DC_PLANT, PIController(), dt=0.002, duration=duration, r1=245.0, r2=306.0,
                      effects=tuple(effects), **kwargs)


def gain_grid(env, points_per_gain: int) -> np.ndarray:
    """Regular grid of shape (points_per_gain ** n_gains, n_gains) over an env's action box."""
    box = env.unwrapped.action_space
    axes = [np.linspace(lo, hi, points_per_gain) for lo, hi in zip(box.low, box.high)]
    return np.column_stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")])


def loop_records(effects=None, *, gains, step=(245.0, 306.0), duration: float = 2.0, noise: float = 0.1,
                 seed: int = 0, start_index: int = 0) -> list[dict]:
    """Closed-loop step records of DCMotor-v0 with hidden ``effects`` and white sensor noise (rad/s)."""
    import gymnasium as gym

    import gbo_envs  # noqa: F401  (registers the envs)
    from agents.twin.csvio import records_from_loop

    env = gym.make("gbo_envs/DCMotor-v0", effects=effects, output_noise_std=noise)
    loop = env.unwrapped.loop.replace(r1=step[0], r2=step[1], duration=duration)
    return records_from_loop(loop, np.asarray(gains), rng=np.random.default_rng(seed), start_index=start_index)


def _dc_motor_space():
    from agents.space import GainSpace

    return GainSpace(names=("Kp", "Ki"), low=np.array([0.11, 0.87]), high=np.array([1.10, 2.08]))


#: the DC motor's feasible PI gains (Kp, Ki): the paper's box
DC_MOTOR_SPACE = _dc_motor_space()


def leaky_saturation(limit: float, leak: float):
    """A user's own block: a saturation at ``limit`` that lets the fraction ``leak`` of the excess through."""
    from gbo_envs.physics import Saturation

    class Leaky(Saturation):
        def actuate(self, u, speed):
            clipped = super().actuate(u, speed)
            return clipped + leak * (u - clipped)

    return Leaky(limit)


class RaiseAt(gym.Wrapper):
    """Raises ``error`` on the given (1-based) ``step`` calls; the other calls reach the env."""

    def __init__(self, env, calls, error) -> None:
        super().__init__(env)
        self.calls, self.error, self.count = set(calls), error, 0

    def step(self, action):
        self.count += 1
        if self.count in self.calls:
            raise self.error
        return self.env.step(action)


def benchmark_module(monkeypatch, script: str, **paths):
    """``benchmarks/<script>.py`` imported as a module, with its module-level paths (``RESULTS``, ``RUNS`` ...)
    set to ``paths`` so that a test writes nothing into the checkout."""
    import importlib.util

    monkeypatch.syspath_prepend(str(REPO_ROOT / "benchmarks"))
    spec = importlib.util.spec_from_file_location(f"{script}_bench", REPO_ROOT / "benchmarks" / f"{script}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    for name, value in paths.items():
        monkeypatch.setattr(module, name, value)
    return module

