"""The paper's identified DC motor speed loop under a PID controller (three gains) as a Gymnasium environment.

Feasible set
------------
Derived as the paper derives the PI set (Sec. IV-B): a nominal design, then a
box around it whose corners keep stability margins
(:func:`gbo_envs.envs.margins.loop_margins`, on the sampled loop with its
delay, as simulated).

* Nominal PID: the paper's first nominal PGM PI (Table nominal_ctl_specs,
  ``Phi_m = 60 deg``, ``A_m = 46 dB``: ``Kp = 0.855``, ``Ki = 1.070`` 1/s in the
  form ``Kp (1 + Ki / s)``, see :data:`~gbo_envs.envs.dc_motor.NOMINAL_FOPDT`) in
  parallel form, ``Kp0 = 0.855``, ``Ki0 = 0.855 * 1.070 = 0.915``, plus a
  derivative term with the classical ratio ``Td = Ti / 4`` (Ziegler-Nichols and
  most PID tables; ``Ti = 1 / 1.070 s``): ``Kd0 = Kp0 Ti / 4 = 0.200``. The
  derivative filter ``Tf = 0.02 s`` is ``Td / 12`` (tables use ``Td / N`` with
  ``N`` of 5 to 20) and ten samples. Margins: gain margin 44.3 dB, phase margin
  87.2 deg at 2.0 rad/s.
* Box: ``[theta0 / f, f theta0]`` with the widest of ``f = 1.25, 1.5, 2, 2.5``
  whose eight corners all keep a phase margin of at least 30 deg (the paper's PI
  set keeps 34.3 deg at its worst corner, ``(1.10, 2.08)``, with 36.3 dB of gain
  margin): ``f = 2`` (``f = 2.5`` leaves 23.9 deg), rounded to ``Kp in [0.43,
  1.71]``, ``Ki in [0.46, 1.83]``, ``Kd in [0.10, 0.40]``. Every corner is stable;
  the worst phase margin is 32.8 deg at ``(0.43, 1.83, 0.10)``, the worst gain
  margin 38.3 dB at ``(1.71, 1.83, 0.40)`` (``tests/gbo_envs/test_pid_env.py``
  checks all eight).

Cost surface: a coarse search (4096 Sobol points, then Nelder-Mead from the best
eight) finds ``J* = 0.1585`` at ``(1.71, 1.779, 0.365)``, on the face
``Kp = Kp_max`` (the margin bound; in this linear model a faster loop keeps
paying); the best corner, ``(1.71, 1.83, 0.40)``, has ``J = 0.175`` (10 % more),
the nominal PID 0.344.
"""

from __future__ import annotations

import itertools

import numpy as np

from gbo_envs.controllers import PIDController
from gbo_envs.envs.dc_motor import DC_MOTOR, DCMotorEnv

__all__ = ["DCMotorPIDEnv", "DC_MOTOR_PID", "corner_gains"]

#: Calibration facts of the DC motor under PID (the plant, step and weights are those of ``DC_MOTOR``).
DC_MOTOR_PID = {
    "nominal": (0.855, 0.855 * 1.070, 0.855 / 1.070 / 4.0),  # Kp, Ki, Kd of the nominal PID (module docstring)
    "filter_time": 0.02,  # s, derivative filter Tf
    "gain_low": (0.43, 0.46, 0.10),
    "gain_high": (1.71, 1.83, 0.40),
    # sigma_eps / J* of the paper, 0.03 / 0.79 = 3.8 %, on this env's J* = 0.158
    "cost_noise_std": 0.006,
}


def corner_gains(low, high) -> np.ndarray:
    """The ``2^n`` corners of the box ``[low, high]``, shape (2^n, n), the last gain varying fastest."""
    return np.array(list(itertools.product(*zip(np.asarray(low, dtype=float), np.asarray(high, dtype=float)))))


class DCMotorPIDEnv(DCMotorEnv):
    """PID speed control of the paper's identified DC motor; one step = one step experiment.

    ## Description

    The plant of ``gbo_envs/DCMotor-v0``, the linear model identified on the
    paper's DC motor rig (Table I), ``G(s) = 9.544 / (s^2 + 4.145 s + 4.199)
    e^{-0.002 s}``, with its 2 ms sampling and its experiment (at rest at 245
    rad/s, the reference steps to 306 rad/s, 5 s, 2501 samples), under a digital
    PID with a filtered derivative (Tustin at 2 ms,
    :class:`~gbo_envs.controllers.PIDController`)::

        C(s) = Kp + Ki / s + Kd s / (Tf s + 1),    Tf = 0.02 s.

    The feasible set is derived from stability margins around a nominal PID,
    the paper's first nominal PGM PI plus a derivative term (module docstring).

    ## Action Space

    ``Box(low=[0.43, 0.46, 0.10], high=[1.71, 1.83, 0.40], dtype=float64)``:

    | Num | Gain | Min  | Max  | Unit |
    |-----|------|------|------|------|
    | 0   | Kp   | 0.43 | 1.71 | input units per rad/s |
    | 1   | Ki   | 0.46 | 1.83 | input units per rad |
    | 2   | Kd   | 0.10 | 0.40 | input units s per rad/s |

    (``Ki`` per rad: per (rad/s) s.) Gains outside the set raise ``ValueError``
    unless ``out_of_bounds`` says otherwise.

    ## Observation Space

    ``Box(shape=(10,), dtype=float64)``: the last gains ``[Kp, Ki, Kd]``, the
    last normalised metrics ``f_i / n_i`` (overshoot, settling time, rise time,
    ITAE), the last cost ``J``, the best cost so far, and the fraction of the
    session's ``max_experiments`` used. Before the first experiment: the centre
    of the feasible set and zeros.

    ## Rewards

    ``-J`` with ``J = 0.44 zeta/n_1 + 0.22 T_s/n_2 + 0.22 T_r/n_3 + 0.11 e_ITAE/n_4``
    (eq. J_used, the DC motor's weights), each metric normalised by its mean
    ``n_i`` over the eight corners of the feasible set (the reference gains), plus
    the measurement noise ``epsilon ~ N(0, cost_noise_std^2)`` of the paper's
    ``J = J_hat + epsilon``. A diverging loop gets ``J = unstable_cost`` and
    ``info["unstable"] = True``.

    ``info`` holds the whole experiment record as on ``DCMotor-v0``: ``t, r, u,
    y`` (arrays of shape (2501,)), ``gains``, ``metrics``, ``cost``,
    ``true_cost`` (noise-free, for evaluation only), ``unstable``,
    ``experiment_index`` and ``experiment``.

    ## Episode End

    An episode is one tuning session. It never terminates; ``gym.make``
    truncates it after ``max_episode_steps = 35`` experiments (the paper's
    ``n_max`` of the numerical study).

    ## Arguments

    ``gym.make("gbo_envs/DCMotorPID-v0", filter_time=0.02, **kwargs)``: those of
    ``DCMotor-v0`` (keyword-only), plus the derivative filter ``filter_time``
    (``Tf`` in s). The default ``cost_noise_std`` of ``measurement_noise`` is
    0.006, 3.8 % of the ground-truth optimum ``J* = 0.158`` as on ``DCMotor-v0``.

    ## Version History

    * v0: initial version.
    """

    calibration = {**DC_MOTOR, **DC_MOTOR_PID}
    nominal_design = None

    def __init__(self, *, filter_time: float = DC_MOTOR_PID["filter_time"], **kwargs) -> None:
        self.filter_time = float(filter_time)
        super().__init__(**kwargs)

    def _controller(self, options: dict):
        """The loop's controller: the PID with the derivative filter ``Tf = filter_time``."""
        return PIDController(filter_time=self.filter_time)

    @staticmethod
    def _reference_gains(low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """Gains whose mean metrics normalise the cost: the eight corners of the feasible set."""
        return corner_gains(low, high)
