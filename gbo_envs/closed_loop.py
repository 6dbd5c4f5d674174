"""One closed-loop step experiment, simulated for a whole batch of gains at once.

The loop is the sampled-data system a real-time target runs: every ``dt`` the
output is measured, the digital controller (:mod:`gbo_envs.controllers`)
computes the command ``u``, the actuator holds it (zero-order hold) and the
plant, discretised exactly with its delay (:mod:`gbo_envs.physics.lti`),
advances one sample. Physical effect blocks (:mod:`gbo_envs.physics`) sit on
the actuator side (between the delayed command ``u`` and the plant input), on
the sensor side (between the plant output and the measurement) or on the plant
side (changing the linear plant before its discretisation, e.g. per
experiment). The experiment starts at rest at ``r1`` and the reference steps
to ``r2`` at ``t = 0``. Without actuator or sensor effects the loop is linear
and is solved exactly from its closed-loop transfer functions; otherwise it is
stepped sample by sample, still for the whole batch at once.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from gbo_envs.controllers import Controller
from gbo_envs.metrics import step_metrics
from gbo_envs.physics.block import RowNoise, validated_finite
from gbo_envs.physics.lti import ContinuousPlant

__all__ = ["ClosedLoop", "SIMULATION_METHODS", "StepResponse", "UNSTABLE_LIMIT"]

#: Values of the ``method`` argument of :meth:`ClosedLoop.simulate`.
SIMULATION_METHODS = ("auto", "linear", "stepping")

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
        Physical effects (:mod:`gbo_envs.physics`; build them with
        :func:`gbo_envs.physics.effects.build_effects`). Actuator blocks act in
        order from the controller to the plant input, after the input delay;
        sensor blocks in order from the plant output to the measurement;
        plant blocks change ``plant`` before it is discretised.
    output_noise_std : float, default 0.0
        Standard deviation of white sensor noise on the measured output, in
        output units; it enters the feedback and the record.
    experiment_index : int, default 0
        Experiment of the session that this loop simulates; plant-side effects
        such as ``drift`` depend on it (see :meth:`at_experiment`).
    """

    plant: ContinuousPlant
    controller: Controller
    dt: float
    duration: float
    r1: float
    r2: float
    effects: tuple = ()
    output_noise_std: float = 0.0
    experiment_index: int = 0
    _discrete: object = field(default=None, init=False, repr=False)
    _linear_parts: tuple = field(default=(), init=False, repr=False)

    def __post_init__(self) -> None:
        if not np.isfinite(self.duration) or self.duration <= self.dt:
            raise ValueError(f"duration: must exceed dt = {self.dt} s, got {self.duration}")
        if self.r1 == self.r2:
            raise ValueError("r1, r2: the reference step must have non-zero height")
        object.__setattr__(self, "output_noise_std", validated_finite("output_noise_std", self.output_noise_std,
                                                                      "output units"))
        plant = self.current_plant
        self._check_delay(plant)
        object.__setattr__(self, "_discrete", plant.discretize(self.dt))
        num_p, den_p = self._discrete.transfer_function()
        _, u0 = self._discrete.equilibrium(self.r1)
        width = max(den_p.size, num_p.size) + 1
        object.__setattr__(self, "_linear_parts", (num_p, den_p, float(u0[0]), width))

    def _check_delay(self, plant: ContinuousPlant) -> None:
        """A dead time longer than the experiment never lets the input reach the output: refuse it."""
        if plant.delay <= self.duration:
            return
        extra = sum(block.delay for block in self.plant_effects if block.name == "time_delay")
        if extra and self.plant.delay + extra > self.duration:
            raise ValueError(f"time_delay: parameter 'delay' must be in [0, {self.duration - self.plant.delay:g}] "
                             f"(s; with the plant's own delay of {self.plant.delay:g} s at most the experiment's "
                             f"length, duration = {self.duration:g} s), got {extra:g}")
        raise ValueError(f"drift: the plant's delay at experiment {self.experiment_index} is {plant.delay:g} s, "
                         f"longer than the experiment (duration = {self.duration:g} s)")

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

    @property
    def stochastic(self) -> bool:
        """Whether an experiment is random: sensor noise, a block with measurement noise, or a random start
        (:meth:`~gbo_envs.physics.block.EffectBlock.random_in`: cogging's angle in a speed loop)."""
        moving = self.plant.output != "position"  # a speed loop turns at its rest level
        return self.output_noise_std > 0.0 or any(block.random_in(moving) for block in self.effects)

    def simulate(self, gains: np.ndarray, rng: np.random.Generator | None = None,
                 method: str = "auto", draws=None, inputs: bool = True) -> StepResponse:
        """Run the step experiment for every row of ``gains``.

        Parameters
        ----------
        gains : array_like of shape (batch, n_gains) or (n_gains,)
            Controller gains in the units of ``controller.gain_units``.
        rng : numpy.random.Generator, optional
            Source of sensor noise and of random effect behaviour; required when
            ``output_noise_std > 0``.
        method : {"auto", "linear", "stepping"}, default "auto"
            ``"linear"``: the exact closed-loop transfer functions (only without
            actuator and sensor effects and without a controller output limit);
            ``"stepping"``: sample by sample through the effect blocks;
            ``"auto"``: linear for a first-order controller (PI, PDT1) in a loop
            without actuator or sensor effects, else stepping. A controller of
            higher order (:attr:`~gbo_envs.controllers.base.Controller.has_state_space`)
            is stepped: its closed loop has several poles clustered near
            ``z = 1``, where the transfer-function filter loses about ``1e-7`` of
            the step height to rounding, and the state space keeps ``1e-12``, as fast.
        draws : array_like of int, shape (batch,), optional
            Draw index of each row: rows with the same index see the same
            measurement noise (common random numbers, see
            :class:`~gbo_envs.physics.block.RowNoise`). ``None``: independent rows.
        inputs : bool, default True
            Whether to record the command ``u``. ``False`` (an evaluation that needs only the
            metrics, which read ``y``) returns ``u`` of shape (batch, 0): the linear loop skips
            its filter, the stepping one its copy. The unstable flag is the same, except that a
            linear loop's command that overflows while ``y`` stays bounded (an unstable plant pole
            cancelled by a controller zero) is not seen.

        Returns
        -------
        StepResponse
        """
        gains = np.atleast_2d(np.asarray(gains, dtype=float))
        if method not in SIMULATION_METHODS:
            raise ValueError(f"method: must be one of {SIMULATION_METHODS}, got {method!r}")
        nonlinear = self.nonlinear
        if method == "linear" and nonlinear:
            raise ValueError("method: 'linear' needs a loop without actuator or sensor effects and a controller "
                             f"without an output limit, this one has {self.actuator_effects + self.sensor_effects} "
                             f"and output_limit={self.controller.output_limit}")
        if self.stochastic and rng is None:
            raise ValueError("rng: a numpy Generator is required for a loop with random behaviour "
                             "(measurement noise, a random cogging start angle)")
        noise = None
        if self.output_noise_std > 0.0:
            noise = self.output_noise_std * RowNoise(rng, gains.shape[0], draws).rows(self.n_steps)
        with np.errstate(over="ignore", invalid="ignore"):
            if method == "stepping" or (method == "auto" and (nonlinear or self.controller.has_state_space)):
                u_out, y_out, u_start = self._simulate_stepping(gains, noise, rng, draws, inputs)
            else:
                u_out, y_out, u_start = self._simulate_linear(gains, noise, inputs)
        response = self._finish(u_out, y_out, u_start)
        return response if inputs else replace(response, u=response.u[:, :0])

    def _simulate_linear(self, gains, noise, inputs=True):
        """Exact response of the linear loop from its closed-loop transfer functions in ``z^-1``.

        With ``P = Np/Dp`` (plant incl. delay) and the controller ``U = (Ne E + Nr dR) / Dc``
        (:meth:`~gbo_envs.controllers.base.Controller.z_transfer`; ``Nr = 0`` for a law of the error
        only), in deviations from the equilibrium at ``r1``, with the measurement ``y + n``:
        ``dy = (Np Nref dr - Np Ne n) / Den`` and ``du = (Dp Nref dr - Dp Ne n) / Den`` with
        ``Nref = Ne + Nr`` and ``Den = Dp Dc + Np Ne``.
        """
        batch, n = gains.shape[0], self.n_steps
        num_c, num_ref, den_c = self.controller.z_transfer(gains, self.dt)
        num_p, den_p, u0, width = self._linear_parts
        width += num_c.shape[1] - 2  # the plant's width + 1 fits a first-order law
        num_t, num_u = _times_plant(num_c, num_p, den_p, width)
        den = np.zeros((batch, width))
        for lag in range(den_c.shape[1]):
            den[:, lag : lag + den_p.size] += den_c[:, lag : lag + 1] * den_p
        den += num_t
        two_dof = num_ref is not None
        if two_dof:
            ref_t, ref_u = _times_plant(num_c + num_ref, num_p, den_p, width)
        from scipy.signal import lfilter  # imported here: scipy.signal takes 0.3 s to import, the twin needs none

        step = np.full(n, self.step_height)
        dy = np.empty((batch, n))
        du = np.empty((batch, n if inputs else 0))
        for i in range(batch):
            if not two_dof:
                drive = step if noise is None else step - noise[i]
                dy[i] = lfilter(num_t[i], den[i], drive)
                if inputs:
                    du[i] = lfilter(num_u[i], den[i], drive)
                continue
            dy[i] = lfilter(ref_t[i], den[i], step)
            if inputs:
                du[i] = lfilter(ref_u[i], den[i], step)
            if noise is not None:
                dy[i] -= lfilter(num_t[i], den[i], noise[i])
                if inputs:
                    du[i] -= lfilter(num_u[i], den[i], noise[i])
        y = self.r1 + dy if noise is None else self.r1 + dy + noise
        return u0 + du, y, np.full(batch, u0)

    def _simulate_stepping(self, gains, noise, rng, draws=None, inputs=True):
        """Sample-by-sample simulation through the effect blocks.

        At sample ``k``: the sensor blocks (and the noise) turn the plant output
        ``c x[k]`` into the measurement, the controller computes ``u[k]``, the
        actuator blocks turn the delayed command ``u[k-d]`` into the plant
        input ``v[k]`` at the current mechanical speed (friction acts on the
        mechanics when the command reaches them), and the exact ZOH model
        advances, ``x[k+1] = Phi x[k] + Gamma0 v[k] + Gamma1 v[k-1]``
        (:meth:`gbo_envs.physics.lti.ContinuousPlant.discretize`).

        The start at rest is computed here; the stepping runs in the compiled kernel
        (:func:`gbo_envs.physics.kernels.closed_loop_kernel`) when it knows every actuator
        and sensor block, else in :meth:`_step_numpy` (the same operations, vectorised
        over the batch), which gives the same numbers.
        """
        batch = gains.shape[0]
        plant = self._discrete
        n, dt, lag = self.n_steps, self.dt, plant.delay_steps
        law = self.controller.state_space(gains, dt)
        if law is None:  # the first-order recursion
            b0, b1, a1 = (np.ascontiguousarray(np.broadcast_to(np.asarray(coef, dtype=float), (batch,)))
                          for coef in self.controller.coefficients(gains, dt))
        else:
            b0 = b1 = a1 = np.zeros(batch)
        actuators, sensors = self.actuator_effects, self.sensor_effects

        # start at rest: the measurement reads r1 (sensor blocks inverted), the plant rests there
        # and the command holds it (actuator blocks inverted, which also sets their state)
        y_rest = np.full(batch, float(self.r1))
        for block in reversed(sensors):
            y_rest = block.level_for(y_rest)
        x, v_prev = plant.equilibrium(y_rest)
        speed_is_output = self.current_plant.output != "position"
        speed_row = plant.c if speed_is_output else plant.velocity_row()
        for block in self.effects:
            block.reset(batch, rng, dt, draws)
        speed0 = speed_row @ x
        u_prev = v_prev.copy()
        for block in reversed(actuators):
            u_prev = block.command_for(u_prev, speed0)
        u_start = np.array(u_prev, dtype=float, copy=True)
        fractional = bool(np.any(plant.gamma1 != 0.0))
        start = (np.ascontiguousarray(x.T), np.asarray(v_prev, dtype=float), u_start)

        # heavy dependency: numba, imported by the first stepping simulation, not by `import gbo_envs` (0.3 s)
        from gbo_envs.physics import kernels

        packed_sensors = kernels.pack_blocks(((j, b, slice(None)) for j, b in enumerate(sensors)), batch, dt)
        packed_actuators = kernels.pack_blocks(((j, b, slice(None)) for j, b in enumerate(actuators)), batch, dt)
        if packed_sensors is not None and packed_actuators is not None:
            sensor_noise = kernels.draw_sensor_noise(packed_sensors, sensors, rng, n, draws)
            u_out, y_out = np.empty((batch, n)), np.empty((batch, n))
            contiguous = np.ascontiguousarray
            kernels.closed_loop_kernel(
                contiguous(plant.phi), contiguous(plant.gamma0), contiguous(plant.gamma1), contiguous(plant.c),
                contiguous(speed_row, dtype=float), fractional, speed_is_output, int(lag), float(self.r2), b0, b1, a1,
                *_kernel_law(law, batch), float(self.step_height),
                *start, packed_sensors.code, packed_sensors.params, packed_sensors.state, packed_sensors.noise,
                packed_actuators.code, packed_actuators.params, packed_actuators.state, sensor_noise,
                np.zeros((0, 0)) if noise is None else contiguous(noise, dtype=float), u_out, y_out)
        else:
            u_out, y_out = self._step_numpy(b0, b1, a1, start, speed_row, speed_is_output, fractional, noise, law)
        if not inputs:  # the command's rows only say whether it stayed finite (see _finish)
            return np.where(np.isfinite(u_out.sum(axis=1)), 0.0, np.nan)[:, None], y_out, u_start
        return u_out, y_out, u_start

    def _step_numpy(self, b0, b1, a1, start, speed_row, speed_is_output, fractional, noise, law=None):
        """The stepping of :meth:`_simulate_stepping` in numpy, vectorised over the batch (blocks the kernel does
        not know). Every sum is accumulated from left to right, as the compiled kernel does; ``law`` is the
        controller's :class:`~gbo_envs.controllers.base.DiscreteStateSpace` (``None``: the first-order recursion).

        Returns ``(u, y)`` of shape (batch, n_steps).
        """
        plant = self._discrete
        n, lag, r2 = self.n_steps, plant.delay_steps, float(self.r2)
        actuators, sensors = self.actuator_effects, self.sensor_effects
        x, v_prev, u_start = start
        batch, order = x.shape
        u_prev = u_start.copy()
        pending = np.empty((n + lag, batch))  # commands on their way through the input delay
        pending[:lag] = u_start
        u_rec = np.empty((n, batch))
        y_rec = np.empty((n, batch))
        noise_rows = None if noise is None else np.ascontiguousarray(noise.T)
        # batch last, elementwise: x[k+1] = sum_j [Phi Gamma0 Gamma1][:, j] [x[k]; v[k]; v[k-1]][j]
        columns = [plant.phi, plant.gamma0[:, None]] + ([plant.gamma1[:, None]] if fractional else [])
        transition = np.hstack(columns)[:, :, None]
        stacked = np.empty((transition.shape[1], batch))
        stacked[:order] = x.T
        if fractional:
            stacked[order + 1] = v_prev
        state = stacked[:order]
        products = np.empty((order, transition.shape[1], batch))
        c_col, speed_col = plant.c[:, None], np.asarray(speed_row, dtype=float)[:, None]
        weighted = np.empty((order, batch))
        e_prev = np.zeros(batch)
        if law is not None:
            controller = _NumpyLaw(law, u_start, float(self.step_height))
        for k in range(n):
            y_true = np.add.reduce(np.multiply(c_col, state, out=weighted), axis=0)
            y_meas = y_true
            for block in sensors:
                y_meas = block.measure(y_meas)
            if noise_rows is not None:
                y_meas = y_meas + noise_rows[k]
            y_rec[k] = y_meas
            e = r2 - y_meas
            u = b0 * e + b1 * e_prev - a1 * u_prev if law is None else controller.step(e)
            u_rec[k] = u
            u_prev, e_prev = u, e
            if lag:
                pending[k + lag] = u
                v = pending[k]
            else:
                v = u
            if actuators:
                speed = y_true if speed_is_output else np.add.reduce(np.multiply(speed_col, state, out=weighted),
                                                                       axis=0)
                for block in actuators:
                    v = block.actuate(v, speed)
            stacked[order] = v
            np.add.reduce(np.multiply(transition, stacked, out=products), axis=1, out=state)
            if fractional:
                stacked[order + 1] = v
        return _transposed(u_rec), _transposed(y_rec)

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

    @property
    def nonlinear(self) -> bool:
        """Whether the loop has actuator or sensor effects or a controller that clips its output (it is then
        stepped sample by sample)."""
        return bool(self.actuator_effects or self.sensor_effects or self.controller.output_limit is not None)

    # -- effect plumbing -------------------------------------------------------------------------
    @property
    def actuator_effects(self) -> tuple:
        """Effect blocks between the command and the plant input."""
        return tuple(b for b in self.effects if b.side == "actuator")

    @property
    def sensor_effects(self) -> tuple:
        """Effect blocks between the plant output and the measurement."""
        return tuple(b for b in self.effects if b.side == "sensor")

    @property
    def plant_effects(self) -> tuple:
        """Effect blocks that change the linear plant (time delay, drift)."""
        return tuple(b for b in self.effects if b.side == "plant")

    @property
    def current_plant(self) -> ContinuousPlant:
        """``plant`` with the plant-side effects applied, as at experiment ``experiment_index``."""
        plant = self.plant
        for block in self.plant_effects:
            plant = block.modify_plant(plant, self.experiment_index)
        return plant

    def at_experiment(self, index: int) -> ClosedLoop:
        """The loop as it is at experiment ``index`` (itself if no plant-side effect depends on it)."""
        if int(index) == self.experiment_index or not self.plant_effects:
            return self
        return self.replace(experiment_index=int(index))

    def metrics(self, response: StepResponse) -> np.ndarray:
        """Metrics of shape (batch, 4) of a response of this loop."""
        return response.metrics(self.r1, self.r2)


def _kernel_law(law, batch: int) -> tuple:
    """The controller state space as :func:`~gbo_envs.physics.kernels.closed_loop_kernel` reads it (empty arrays
    for the first-order recursion)."""
    if law is None:
        return (np.zeros((batch, 0, 0)), np.zeros((batch, 0, 2)), np.zeros((batch, 0)), np.zeros((batch, 2)),
                np.zeros((batch, 0)), np.zeros(0), np.inf)
    contiguous = np.ascontiguousarray
    return (contiguous(law.a, dtype=float), contiguous(law.b, dtype=float), contiguous(law.c, dtype=float),
            contiguous(law.d, dtype=float), contiguous(law.injection, dtype=float),
            np.asarray(law.clamp, dtype=float), float(law.limit))


class _NumpyLaw:
    """The controller state space of :func:`~gbo_envs.physics.kernels.closed_loop_kernel`, one sample at a time
    for the whole batch, with the kernel's operations in its order."""

    def __init__(self, law, u_start: np.ndarray, step: float) -> None:
        self.law, self.u_start, self.step_height = law, u_start, step
        self.x = np.zeros((law.order, u_start.size))

    def step(self, e: np.ndarray) -> np.ndarray:
        law, x, dr = self.law, self.x, self.step_height
        n = law.order
        v = self.u_start + law.d[:, 0] * e
        v = v + law.d[:, 1] * dr
        for i in range(n):
            v = v + law.c[:, i] * x[i]
        u = np.minimum(np.maximum(v, -law.limit), law.limit)
        excess = u - v
        x_next = np.empty_like(x)
        for i in range(n):
            acc = law.b[:, i, 0] * e
            acc = acc + law.b[:, i, 1] * dr
            for m in range(n):
                acc = acc + law.a[:, i, m] * x[m]
            acc = acc + law.injection[:, i] * excess
            if law.clamp[i]:  # conditional integration: hold while the update drives the command further out
                acc = np.where((excess != 0.0) & (law.c[:, i] * (acc - x[i]) * excess < 0.0), x[i], acc)
            x_next[i] = acc
        self.x = x_next
        return u


def _times_plant(num_c: np.ndarray, num_p: np.ndarray, den_p: np.ndarray, width: int):
    """``(Nc Np, Nc Dp)`` of shape (batch, width): the controller numerators times the plant's polynomials."""
    batch = num_c.shape[0]
    num_t = np.zeros((batch, width))
    num_u = np.zeros((batch, width))
    for lag in range(num_c.shape[1]):
        coef = num_c[:, lag : lag + 1]
        num_t[:, lag : lag + num_p.size] += coef * num_p
        num_u[:, lag : lag + den_p.size] += coef * den_p
    return num_t, num_u


def _transposed(a: np.ndarray, block: int = 64) -> np.ndarray:
    """C-contiguous transpose of a 2-D array, copied in cache-sized blocks (about 4x faster than ``a.T.copy()``)."""
    out = np.empty((a.shape[1], a.shape[0]))
    for start in range(0, a.shape[0], block):
        out[:, start : start + block] = a[start : start + block].T
    return out

