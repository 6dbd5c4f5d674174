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
TIMING_COLUMNS = ["wall_time", "batch_wall_time", "batch_cpu_time", "plant_cpu_time"]


def dc_loop(*effects, duration: float = 5.0, **kwargs) -> ClosedLoop:
    """The DC motor's PI loop (2 ms samples, 245 -> 306 rad/s step) with optional effect blocks."""
    return ClosedLoop(DC_PLANT, PIController(), dt=0.002, duration=duration, r1=245.0, r2=306.0,
                      effects=tuple(effects), **kwargs)


def flexible_coupling_plant(omega: float = 15.0, zeta: float = 0.1) -> ContinuousPlant:
    """The DC motor behind a flexible coupling: ``DC_PLANT`` times ``omega^2 / (s^2 + 2 zeta omega s + omega^2)``.

    A lightly damped pole pair (``omega`` in rad/s, ``zeta`` dimensionless) that the paper's
    2-pole twin lacks; 4th order, same static gain and 2 ms input delay as the DC motor.
    """
    w2 = omega**2
    den = np.polymul([1.0, 4.145, 4.199], [1.0, 2.0 * zeta * omega, w2])
    return ContinuousPlant((9.544 * w2,), tuple(float(c) for c in den), delay=0.002)


class FlexibleCouplingRig:
    """A rig function ``gains -> (t, r, u, y)`` for :class:`gbo_envs.ExternalPlantEnv`, as a user wraps hardware.

    DCMotor-v0's PI loop (2 ms samples, 5 s, 245 -> 306 rad/s) around
    :func:`flexible_coupling_plant`, with white sensor noise of ``noise_std`` rad/s
    drawn from its own generator (seeded by ``seed``).
    """

    def __init__(self, omega: float = 15.0, zeta: float = 0.1, noise_std: float = 0.05, seed: int = 0) -> None:
        self.loop = ClosedLoop(flexible_coupling_plant(omega, zeta), PIController(), dt=0.002, duration=5.0,
                               r1=245.0, r2=306.0, output_noise_std=noise_std)
        self.rng = np.random.default_rng(seed)

    def __call__(self, gains):
        response = self.loop.simulate(np.asarray(gains, dtype=float)[None, :], rng=self.rng)
        return response.t, response.r, response.u[0], response.y[0]


def flexible_coupling_env(omega: float = 15.0, zeta: float = 0.1, noise_std: float = 0.05, seed: int = 0):
    """:class:`gbo_envs.ExternalPlantEnv` around a :class:`FlexibleCouplingRig`, DCMotor-v0's gains and cost.

    The cost normalisers are measured on the rig at 5 gains spanning the feasible set, as
    ``examples/external_plant.py`` does (5 rig experiments before the tuning starts).
    """
    from gbo_envs import ExternalPlantEnv, StepExperiment

    low, high = np.array([0.11, 0.87]), np.array([1.10, 2.08])
    return ExternalPlantEnv(FlexibleCouplingRig(omega, zeta, noise_std, seed),
                            {"Kp": (low[0], high[0]), "Ki": (low[1], high[1])}, controller=PIController(),
                            experiment=StepExperiment((245.0, 306.0), dt=0.002, duration=5.0),
                            reference_gains=np.linspace(low, high, 5))


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



#: A small servo measured as real rigs measure it (:func:`real_like_records`): the speed responds to the
#: drive as ``K / (tau s + 1)`` with K = 100 rad/s per input unit and tau = 0.1 s.
SERVO_PLANT = ContinuousPlant((1000.0,), (1.0, 10.0))


def encoder_speed(speed: np.ndarray, dt: float, lines: int = 1024, window: int = 4,
                  rng: np.random.Generator | None = None) -> np.ndarray:
    """The speed an incremental encoder reports: whole counts of the shaft angle, differenced over ``window``.

    The angle (rad) is the trapezoidal integral of ``speed`` (rad/s) from a random phase of the code disc;
    the reported speed is ``(c[k] - c[k - window]) 2 pi / (lines window dt)``, so it moves in steps of
    that quantum and lags by about ``window / 2`` samples. At rest it reads 0.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    increment = 2.0 * np.pi / lines
    angle = np.concatenate([[0.0], np.cumsum(0.5 * dt * (speed[1:] + speed[:-1]))]) + rng.uniform(0.0, increment)
    counts = np.floor(angle / increment)
    measured = np.zeros_like(speed)
    measured[window:] = (counts[window:] - counts[:-window]) * increment / (window * dt)
    return measured


def real_like_records(effects=None, *, n_records: int = 6, duration: float = 2.0, dt: float = 1e-3,
                      quiet: float = 0.1, levels=(0.3, 0.6), lines: int = 1024, window: int = 4, seed: int = 0,
                      plant: ContinuousPlant = SERVO_PLANT) -> list:
    """Open-loop records as a real servo rig produces them, with known hidden ``effects``.

    Each record starts at rest (``u = 0``, ``y = 0`` for ``quiet`` s), then holds two input levels
    (the first, then the second from the middle of the record), each drawn within +-15 % of
    ``levels``; the records alternate in sign, so the motor runs both ways. The speed comes from
    an incremental encoder (:func:`encoder_speed`: quantum ``2 pi / (lines window dt)`` rad/s).
    ``r`` equals ``u`` (no controller). Sampled every ``dt`` s.

    Returns
    -------
    list of gbo_envs.Experiment
        Indexed from 0.
    """
    from agents.twin.open_loop import simulate_open_loop
    from gbo_envs import Experiment
    from gbo_envs.physics.effects import build_effects

    rng = np.random.default_rng(seed)
    n = int(round(duration / dt)) + 1
    t = np.arange(n) * dt
    blocks = build_effects(effects or {})
    records = []
    for k in range(n_records):
        sign = 1.0 if k % 2 == 0 else -1.0
        u = np.zeros(n)
        first, second = (lvl * rng.uniform(0.85, 1.15) for lvl in levels)
        u[int(round(quiet / dt)):] = sign * first
        u[n // 2:] = sign * second
        speed = simulate_open_loop(plant, u[None], dt, blocks, y0=0.0, bias=0.0).y_true[0]
        y = encoder_speed(speed, dt, lines, window, rng)
        records.append(Experiment(gains=(), t=t, r=u.copy(), u=u, y=y, index=k))
    return records
