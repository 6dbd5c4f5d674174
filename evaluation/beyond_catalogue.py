"""Rigs with physics outside the effect catalogue, wrapped as a user wraps hardware (issue 36).

Each plant is the paper's DC motor speed loop (DCMotor-v0's PI gains, 245 -> 306 rad/s, 5 s at
2 ms, its cost weights) with one thing the catalogue's blocks do not model, simulated by a
function ``gains -> (t, r, u, y)`` and wrapped in :class:`gbo_envs.ExternalPlantEnv`, with white
sensor noise of 0.05 rad/s on the measured speed:

* ``beyond/FlexibleCoupling-v0``: the load behind a flexible coupling, an extra lightly damped
  pole pair ``w^2 / (s^2 + 2 zeta w s + w^2)`` at 15 rad/s, ``zeta = 0.1`` (a two-mass
  resonance measured at the load);
* ``beyond/CurrentLoopLag-v0``: a slow current (torque) loop, an extra lag ``1 / (0.1 s + 1)``;
* ``beyond/VelocityFilter-v0``: the drive reports the speed averaged over a moving window of
  25 samples (50 ms), a FIR filter in the feedback path (not a rational transfer function);
* ``beyond/DahlFriction-v0``: friction with pre-sliding hysteresis (Dahl's model,
  ``dF/dt = sigma (1 - F sgn(w) / Fc) w``, ``Fc = 8`` input units, ``sigma = 400`` input units
  per rad of travel), where the catalogue's Coulomb friction switches at once;
* ``beyond/StribeckFriction-v0``: a speed-dependent friction curve, ``F(w) = (Fc + (Fs - Fc)
  exp(-(w / ws)^2)) sgn(w) + b w`` with ``Fc = 5``, ``Fs = 12``, ``ws = 50`` rad/s, ``b = 0.02``
  input units per rad/s (a control: the linear twin absorbs it locally).

The rigs are simulated, so unlike real hardware they have a noise-free expected cost:
:class:`SimulatedRig` adds ``evaluate`` (the mean cost over ``draws`` fixed noise draws, common
random numbers as the built-in envs), which :func:`gbo_envs.ground_truth` needs for ``J*``.
Import this module (a study's ``imports``, ``gbo tune --import evaluation.beyond_catalogue``) to
register the ids.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from gbo_envs import ClosedLoop, ContinuousPlant, CostSpec, ExternalPlantEnv, PIController, StepExperiment
from gbo_envs.physics.block import EffectBlock, EffectParameter

__all__ = ["BEYOND_IDS", "DahlFriction", "MovingAverageSpeed", "SimulatedRig", "StribeckFriction", "rig_loop"]

#: DCMotor-v0's feasible PI gains (Kp, Ki), reference step and timing.
GAIN_BOUNDS = {"Kp": (0.11, 1.10), "Ki": (0.87, 2.08)}
REFERENCE = (245.0, 306.0)
DT, DURATION = 0.002, 5.0
#: The paper's DC motor, 9.544 / (s^2 + 4.145 s + 4.199) e^{-0.002 s}.
DC_NUM, DC_DEN, DC_DELAY = (9.544,), (1.0, 4.145, 4.199), 0.002
#: White sensor noise on the measured speed, rad/s.
NOISE_STD = 0.05


class MovingAverageSpeed(EffectBlock):
    """The drive's speed estimate: the mean of the last ``window`` samples of the true speed (a FIR filter)."""

    name = "moving_average_speed"
    side = "sensor"
    parameters = (EffectParameter("window", "samples", 1.0, 1e6, None, 1.0, "samples averaged"),)
    magnitude_param = "window"

    def __init__(self, window: int) -> None:
        self._set_params(window=window)
        self.window = int(window)

    def reset(self, batch, rng, dt, draws=None):
        self._past = None

    def level_for(self, y_measured):
        return y_measured

    def measure(self, y):
        if self._past is None:  # at rest at the first speed before the step
            self._past = np.repeat(np.asarray(y, dtype=float)[None, :], self.window, axis=0)
            self._slot = 0
        self._past[self._slot] = y
        self._slot = (self._slot + 1) % self.window
        return self._past.mean(axis=0)


class DahlFriction(EffectBlock):
    """Friction with pre-sliding hysteresis (Dahl): ``dF/dt = sigma (1 - F sgn(w) / Fc) w``, as an input loss.

    Integrated over each sample with the speed at its start (explicit Euler on the travel
    ``w dt``, the state clipped to ``[-Fc, Fc]``); at rest ``F`` holds its last value.
    """

    name = "dahl_friction"
    side = "actuator"
    parameters = (EffectParameter("level", "input units", 0.0, 1e9, None, 0.0, "Coulomb level Fc"),
                  EffectParameter("stiffness", "input units per rad", 0.0, 1e9, 400.0, float("nan"),
                                  "pre-sliding stiffness sigma"))
    magnitude_param = "level"

    def __init__(self, level: float, stiffness: float = 400.0) -> None:
        self._set_params(level=level, stiffness=stiffness)

    def reset(self, batch, rng, dt, draws=None):
        self._dt, self._force = dt, np.zeros(batch)

    def command_for(self, u_applied, speed):
        self._force = self.level * np.sign(speed)
        return u_applied + self._force

    def actuate(self, u, speed):
        travel = speed * self._dt
        step = self.stiffness * (1.0 - self._force * np.sign(speed) / max(self.level, 1e-12)) * travel
        self._force = np.clip(self._force + step, -self.level, self.level)
        return u - self._force


class StribeckFriction(EffectBlock):
    """A speed-dependent friction curve: ``(Fc + (Fs - Fc) exp(-(w / ws)^2)) sgn(w) + b w`` as an input loss."""

    name = "stribeck_friction"
    side = "actuator"
    parameters = (EffectParameter("coulomb", "input units", 0.0, 1e9, None, 0.0, "Coulomb level Fc"),
                  EffectParameter("static", "input units", 0.0, 1e9, None, float("nan"), "static level Fs"),
                  EffectParameter("stribeck_speed", "speed units", 1e-9, 1e9, None, float("nan"), "Stribeck speed"),
                  EffectParameter("viscous", "input units per speed unit", 0.0, 1e9, 0.0, float("nan"),
                                  "viscous coefficient b"))
    magnitude_param = "coulomb"

    def __init__(self, coulomb: float, static: float, stribeck_speed: float, viscous: float = 0.0) -> None:
        self._set_params(coulomb=coulomb, static=static, stribeck_speed=stribeck_speed, viscous=viscous)

    def _friction(self, speed):
        curve = self.coulomb + (self.static - self.coulomb) * np.exp(-(speed / self.stribeck_speed) ** 2)
        return curve * np.sign(speed) + self.viscous * speed

    def command_for(self, u_applied, speed):
        return u_applied + self._friction(speed)

    def actuate(self, u, speed):
        return u - self._friction(speed)


def rig_loop(kind: str) -> ClosedLoop:
    """The simulated rig of ``kind`` (a key of :data:`KINDS`) as a closed loop with sensor noise."""
    plant = ContinuousPlant(DC_NUM, DC_DEN, delay=DC_DELAY)
    effects: tuple = ()
    if kind == "flexible_coupling":
        w, zeta = 15.0, 0.1
        plant = ContinuousPlant((DC_NUM[0] * w**2,), tuple(np.polymul(DC_DEN, [1.0, 2.0 * zeta * w, w**2])),
                                delay=DC_DELAY)
    elif kind == "current_loop_lag":  # G(s) / (0.1 s + 1), monic: 10 G(s) / (s + 10)
        plant = ContinuousPlant((10.0 * DC_NUM[0],), tuple(np.polymul(DC_DEN, [1.0, 10.0])), delay=DC_DELAY)
    elif kind == "velocity_filter":
        effects = (MovingAverageSpeed(25),)
    elif kind == "dahl_friction":
        effects = (DahlFriction(8.0, 400.0),)
    elif kind == "stribeck_friction":
        effects = (StribeckFriction(5.0, 12.0, 50.0, 0.02),)
    else:
        raise ValueError(f"kind: must be one of {tuple(KINDS)}, got {kind!r}")
    return ClosedLoop(plant, PIController(), dt=DT, duration=DURATION, r1=REFERENCE[0], r2=REFERENCE[1],
                      effects=effects, output_noise_std=NOISE_STD)


class SimulatedRig(ExternalPlantEnv):
    """:class:`gbo_envs.ExternalPlantEnv` around a simulated rig (:func:`rig_loop`), with a noise-free truth.

    ``step`` runs the rig's function ``gains -> (t, r, u, y)`` as a user's hardware would, with
    its own noise generator seeded by ``reset(seed=...)``. ``evaluate`` (what a real rig cannot
    give) is the mean cost over ``draws`` fixed noise draws at every gain, for the ground truth.
    The metric normalisers are measured once, noise-free, at 5 gains evenly spanning the set
    (as DCMotor-v0's), so that every build of the env has the same cost scale.
    """

    def __init__(self, kind: str = "flexible_coupling", draws: int = 16, **kwargs) -> None:
        self.kind, self.draws = kind, int(draws)
        self._rig_loop = rig_loop(kind)
        self._rig_rng = np.random.default_rng(0)
        low, high = (np.array([b[i] for b in GAIN_BOUNDS.values()]) for i in (0, 1))
        quiet = self._rig_loop.replace(output_noise_std=0.0)
        metrics = quiet.metrics(quiet.simulate(np.linspace(low, high, 5), rng=np.random.default_rng(0)))
        super().__init__(self._run, GAIN_BOUNDS, experiment=StepExperiment(REFERENCE, dt=DT, duration=DURATION),
                         controller=PIController(), cost=CostSpec(normalizers=metrics.mean(axis=0)), **kwargs)

    def _run(self, gains):
        response = self._rig_loop.simulate(np.asarray(gains, dtype=float)[None, :], rng=self._rig_rng)
        return response.t, response.r, response.u[0], response.y[0]

    def reset(self, *, seed=None, options=None):
        if seed is not None:
            self._rig_rng = np.random.default_rng(seed)
        return super().reset(seed=seed, options=options)

    def step(self, action):
        """One experiment on the rig; ``info["true_cost"]`` is the simulated rig's expected cost (:meth:`evaluate`),
        which the optimality ratio of the studies reads (a real rig's record has none)."""
        obs, reward, terminated, truncated, info = super().step(action)
        if not info.get("failed") and "gains" in info:
            info["true_cost"] = float(self.evaluate(np.asarray(info["gains"], dtype=float))[1][0])
        return obs, reward, terminated, truncated, info

    def evaluate(self, gains, experiment_index=None):
        """Metrics of shape (batch, 4) and expected cost of shape (batch,) over ``draws`` fixed noise draws."""
        gains = np.atleast_2d(np.asarray(gains, dtype=float))
        batch = gains.shape[0]
        rows = np.repeat(gains, self.draws, axis=0)
        draws = np.tile(np.arange(self.draws), batch)
        response = self._rig_loop.simulate(rows, rng=np.random.default_rng(12345), draws=draws, inputs=False)
        metrics = self._rig_loop.metrics(response)
        costs = np.where(response.unstable, self.unstable_cost, self.cost(metrics))
        return metrics.reshape(batch, self.draws, -1).mean(axis=1), costs.reshape(batch, self.draws).mean(axis=1)


#: The plants of this module: gym id -> rig kind.
KINDS = {"flexible_coupling": "FlexibleCoupling", "current_loop_lag": "CurrentLoopLag",
         "velocity_filter": "VelocityFilter", "dahl_friction": "DahlFriction", "stribeck_friction": "StribeckFriction"}
BEYOND_IDS = tuple(f"beyond/{name}-v0" for name in KINDS.values())

for _kind, _name in KINDS.items():
    if f"beyond/{_name}-v0" not in gym.registry:
        gym.register(id=f"beyond/{_name}-v0", entry_point="evaluation.beyond_catalogue:SimulatedRig",
                     kwargs={"kind": _kind}, max_episode_steps=35)
