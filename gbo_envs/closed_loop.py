"""One closed-loop step experiment, simulated for a whole batch of gains at once.

The loop is the sampled-data system a real-time target runs: every ``dt`` the
output is measured, the digital controller (:mod:`gbo_envs.controllers`)
computes the command ``u``, the actuator holds it (zero-order hold) and the
plant, discretised exactly with its delay (:mod:`gbo_envs.physics.lti`),
advances one sample. Physical effect blocks (:mod:`gbo_envs.physics`) sit on
the actuator side (between ``u`` and the plant) or on the sensor side (between
the plant output and the measurement). The experiment starts at rest at ``r1``
and the reference steps to ``r2`` at ``t = 0``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.signal import lfilter, ss2tf

from gbo_envs.controllers import Controller
from gbo_envs.metrics import step_metrics
from gbo_envs.physics.lti import ContinuousPlant

__all__ = ["ClosedLoop", "StepResponse", "UNSTABLE_LIMIT"]

#: A response that leaves ``r2 +- UNSTABLE_LIMIT * |r2 - r1|`` (or overflows) is flagged unstable.
UNSTABLE_LIMIT = 100.0


@dataclass(frozen=True, eq=False)
class StepResponse:
    """Record of a batch of step experiments.

    Attributes
    ----------
    t : ndarray of shape (n_steps,)
        Time since the step in s.
    r : ndarray of shape (n_steps,)
        Reference.
    u : ndarray of shape (batch, n_steps)
        Commanded plant input (controller output, before actuator effects).
    y : ndarray of shape (batch, n_steps)
        Measured output (after sensor effects and sensor noise).
    unstable : ndarray of bool, shape (batch,)
        Whether the response diverged; its ``u``, ``y`` are clipped to stay finite.
    """

    t: np.ndarray
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    unstable: np.ndarray

    def metrics(self, r1: float, r2: float) -> np.ndarray:
        """Metrics of shape (batch, 4), see :func:`gbo_envs.metrics.step_metrics`."""
        return step_metrics(self.t, self.y, r1, r2)


@dataclass(frozen=True, eq=False)
class ClosedLoop:
    """A sampled-data feedback loop and its step experiment.

    Parameters
    ----------
    plant : ContinuousPlant
        Linear part of the plant (with its input delay).
    controller : Controller
        Digital controller; its ``gain_names`` name the action entries.
    dt : float
        Sample time in s.
    duration : float
        Length ``T`` of the experiment in s; ``round(T / dt) + 1`` samples.
    r1, r2 : float
        Reference before and after the step, in output units.
    effects : tuple of effect blocks, default ()
        Physical effects (:mod:`gbo_envs.physics.effects`), applied in order.
    output_noise_std : float, default 0.0
        Standard deviation of white sensor noise on the measured output, in
        output units; it enters the feedback and the record.
    """

    plant: ContinuousPlant
    controller: Controller
    dt: float
    duration: float
    r1: float
    r2: float
    effects: tuple = ()
    output_noise_std: float = 0.0
    _discrete: object = field(default=None, init=False, repr=False)
    _linear_parts: tuple = field(default=(), init=False, repr=False)

    def __post_init__(self) -> None:
        if not np.isfinite(self.duration) or self.duration <= self.dt:
            raise ValueError(f"duration: must exceed dt = {self.dt} s, got {self.duration}")
        if self.r1 == self.r2:
            raise ValueError("r1, r2: the reference step must have non-zero height")
        if self.output_noise_std < 0.0:
            raise ValueError(f"output_noise_std: must be >= 0, got {self.output_noise_std}")
        object.__setattr__(self, "_discrete", self.plant.discretize(self.dt))
        num_p, den_p = self._plant_polynomials
        _, u0 = self._discrete.equilibrium(self.r1)
        width = max(den_p.size, num_p.size) + 1
        object.__setattr__(self, "_linear_parts", (num_p, den_p, float(u0[0]), width))

    def replace(self, **changes) -> ClosedLoop:
        """Copy with fields replaced (e.g. another plant for a digital twin)."""
        return replace(self, **changes)

    @property
    def n_steps(self) -> int:
        """Samples per experiment."""
        return int(round(self.duration / self.dt)) + 1

    @property
    def time(self) -> np.ndarray:
        """Sample times of shape (n_steps,) in s."""
        return np.arange(self.n_steps) * self.dt

    @property
    def step_height(self) -> float:
        """``r2 - r1`` in output units."""
        return self.r2 - self.r1

    def simulate(self, gains: np.ndarray, rng: np.random.Generator | None = None) -> StepResponse:
        """Run the step experiment for every row of ``gains``.

        Parameters
        ----------
        gains : array_like of shape (batch, n_gains) or (n_gains,)
            Controller gains in the units of ``controller.gain_units``.
        rng : numpy.random.Generator, optional
            Source of sensor noise and of random effect behaviour; required when
            ``output_noise_std > 0``.

        Returns
        -------
        StepResponse
        """
        gains = np.atleast_2d(np.asarray(gains, dtype=float))
        if self.output_noise_std > 0.0 and rng is None:
            raise ValueError("rng: a numpy Generator is required when output_noise_std > 0")
        noise = None
        if self.output_noise_std > 0.0:
            noise = self.output_noise_std * rng.standard_normal((gains.shape[0], self.n_steps))
        with np.errstate(over="ignore", invalid="ignore"):
            if self.effects:
                u_out, y_out, u_start = self._simulate_stepping(gains, noise, rng)
            else:
                u_out, y_out, u_start = self._simulate_linear(gains, noise)
        return self._finish(u_out, y_out, u_start)

    def _simulate_linear(self, gains, noise):
        """Exact response of the linear loop from its closed-loop transfer functions in ``z^-1``.

        With ``P = Np/Dp`` (plant incl. delay) and ``C = Nc/Dc`` (controller), in
        deviations from the equilibrium at ``r1``: ``dy = T (dr - n)`` and
        ``du = S_u (dr - n)`` with ``T = Np Nc / (Dp Dc + Np Nc)`` and
        ``S_u = Nc Dp / (Dp Dc + Np Nc)``; the measurement is ``y + n``.
        """
        batch, n = gains.shape[0], self.n_steps
        b0, b1, a1 = self.controller.coefficients(gains, self.dt)
        num_p, den_p, u0, width = self._linear_parts
        # first-order controller: Nc = b0 + b1 z^-1, Dc = 1 + a1 z^-1
        num_t = np.zeros((batch, width))
        num_u = np.zeros((batch, width))
        den = np.zeros((batch, width))
        for lag, (coef_n, coef_d) in enumerate(((b0, 1.0), (b1, a1))):
            coef_n = np.reshape(coef_n, (-1, 1))
            coef_d = np.reshape(coef_d, (-1, 1)) if np.ndim(coef_d) else coef_d
            num_t[:, lag : lag + num_p.size] += coef_n * num_p
            num_u[:, lag : lag + den_p.size] += coef_n * den_p
            den[:, lag : lag + den_p.size] += coef_d * den_p
        den += num_t
        step = np.full(n, self.step_height)
        dy = np.empty((batch, n))
        du = np.empty((batch, n))
        for i in range(batch):
            drive = step if noise is None else step - noise[i]
            dy[i] = lfilter(num_t[i], den[i], drive)
            du[i] = lfilter(num_u[i], den[i], drive)
        y = self.r1 + dy if noise is None else self.r1 + dy + noise
        return u0 + du, y, np.full(batch, u0)

    @property
    def _plant_polynomials(self) -> tuple[np.ndarray, np.ndarray]:
        """Sampled plant ``P(z) = z^-d c (zI - Phi)^-1 (Gamma0 + Gamma1 z^-1)`` as ``(num, den)`` in ``z^-1``."""
        plant = self._discrete
        n0, den = ss2tf(plant.phi, plant.gamma0[:, None], plant.c[None, :], np.zeros((1, 1)))
        n1, _ = ss2tf(plant.phi, plant.gamma1[:, None], plant.c[None, :], np.zeros((1, 1)))
        d = plant.delay_steps
        num = np.zeros(d + 2 + n0.shape[1])
        num[d : d + n0.shape[1]] += n0[0]
        num[d + 1 : d + 1 + n1.shape[1]] += n1[0]
        return np.trim_zeros(num, "b"), den

    def _simulate_stepping(self, gains, noise, rng):
        """Sample-by-sample simulation for loops with (nonlinear) effect blocks."""
        batch = gains.shape[0]
        plant = self._discrete
        n, dt = self.n_steps, self.dt
        r = np.full(n, float(self.r2))
        b0, b1, a1 = self.controller.coefficients(gains, dt)

        # start at rest at r1: plant equilibrium, then back through the actuator effects
        x, u_applied0 = plant.equilibrium(np.full(batch, float(self.r1)))
        speed_row = plant.velocity_row() if self.plant.output == "position" else plant.c
        speed0 = speed_row @ x
        for block in self.effects:
            block.reset(batch, rng, dt)
        u_cmd0 = u_applied0.copy()
        for block in reversed(self.actuator_effects):
            u_cmd0 = block.command_for(u_cmd0, speed0)

        history = [u_applied0.copy() for _ in range(plant.delay_steps + 1)]
        u_prev, e_prev = u_cmd0.copy(), np.zeros(batch)
        u_rec = np.empty((n, batch))
        y_rec = np.empty((n, batch))
        phi, gamma0, gamma1, c = plant.phi, plant.gamma0[:, None], plant.gamma1[:, None], plant.c
        actuators, sensors = self.actuator_effects, self.sensor_effects
        lag = plant.delay_steps
        for k in range(n):
            y_meas = c @ x
            for block in sensors:
                y_meas = block.measure(y_meas)
            if noise is not None:
                y_meas = y_meas + noise[:, k]
            y_rec[k] = y_meas
            e = r[k] - y_meas
            u = b0 * e + b1 * e_prev - a1 * u_prev
            u_rec[k] = u
            u_prev, e_prev = u, e
            if actuators:
                speed = speed_row @ x
                for block in actuators:
                    u = block.actuate(u, speed)
            history.append(u)
            x = phi @ x + gamma0 * history[-1 - lag] + gamma1 * history[-2 - lag]
            history.pop(0)
        return u_rec.T.copy(), y_rec.T.copy(), u_cmd0

    def _finish(self, u_out, y_out, u_start):
        """Flag diverged responses and clip them to finite values."""
        t = self.time
        r = np.full(self.n_steps, float(self.r2))
        limit = UNSTABLE_LIMIT * abs(self.step_height)
        # one pass each: NaN compares False, so "not <= limit" also catches NaN and inf
        unstable = ~(np.max(np.abs(y_out - self.r2), axis=1) <= limit) | ~np.isfinite(u_out.sum(axis=1))
        if unstable.any():
            y_out[unstable] = np.clip(np.nan_to_num(y_out[unstable], nan=self.r2), self.r2 - limit, self.r2 + limit)
            u_bound = limit * max(1.0, float(np.max(np.abs(u_start))))
            u_out[unstable] = np.clip(np.nan_to_num(u_out[unstable], nan=0.0), -u_bound, u_bound)
        return StepResponse(t=t, r=r, u=u_out, y=y_out, unstable=unstable)

    # -- effect plumbing -------------------------------------------------------------------------
    @property
    def actuator_effects(self) -> tuple:
        """Effect blocks between the command and the plant input."""
        return tuple(b for b in self.effects if b.side == "actuator")

    @property
    def sensor_effects(self) -> tuple:
        """Effect blocks between the plant output and the measurement."""
        return tuple(b for b in self.effects if b.side == "sensor")

    def metrics(self, response: StepResponse) -> np.ndarray:
        """Metrics of shape (batch, 4) of a response of this loop."""
        return response.metrics(self.r1, self.r2)

