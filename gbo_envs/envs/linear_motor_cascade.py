"""The paper's linear servo motor (LinMot P01) under a position -> speed cascade, four gains, as a Gymnasium env.

The drive runs the cascade servo drives run (:class:`~gbo_envs.controllers.CascadeController`):
a setpoint filter, position P with velocity feed-forward, speed PI on the speed
estimated from the position sensor, and the current command limited to 7 A with
the speed integrator clamped against it. The plant, the sensor, the step and the
cost weights are those of ``gbo_envs/LinearMotor-v0``.

Nominal design
--------------
The symmetric optimum for the speed loop and the technical optimum for the
position loop (Kessler; Schroeder, *Elektrische Antriebe - Regelung von
Antriebssystemen*, ch. 3), the standard tuning rule of drive cascades:

* speed plant, current to speed: ``0.44262 / (0.070983 s + 0.8) = K / (T s + 1)``
  with ``K = 0.5533`` (m/s)/A and ``T = 88.7`` ms;
* small time constants: the 1 ms input delay, the sample-and-hold (``dt / 2``),
  the speed filter ``Tv = 1`` ms and the difference quotient (``dt / 2``):
  ``T_sigma = 3`` ms;
* speed PI by the symmetric optimum: ``Kp0 = T / (2 K T_sigma) = 26.7`` A/(m/s),
  ``Ti = 4 T_sigma``, ``Ki0 = 1 / Ti = 83.3`` 1/s;
* the closed speed loop is about ``1 / (4 T_sigma s + 1)``; position P by the
  technical optimum on it: ``Kv0 = 1 / (2 * 4 T_sigma) = 41.7`` 1/s;
* full velocity feed-forward ``Kff0 = 1``, from a setpoint filter of
  ``Tr = 15`` ms: its peak speed ``10 mm / Tr = 0.67`` m/s is the peak speed of
  the fastest 7 A move over the 10 mm step, ``sqrt(7 A * 6.236 m/s^2/A * 10 mm) =
  0.66`` m/s.

Margins of the nominal loop (broken at the current command, the sampled loop
with its delay, :func:`gbo_envs.envs.margins.loop_margins`): phase margin
30.8 deg at 190 rad/s, gain margin 11.3 dB, gain reduction margin -17.4 dB (a
loop with two integrators is conditionally stable).

Feasible set
------------
``[theta0 / f, f theta0]`` for ``(Kv, Kp, Ki)`` with the widest of ``f = 1.25,
1.5, 2`` whose eight corners keep the paper's criterion for the linear motor, a
phase margin above 20 deg (Sec. VI-B): ``f = 1.25`` (``f = 1.5`` leaves 12.9
deg), rounded to ``Kv in [33.3, 52.1]`` 1/s, ``Kp in [21.4, 33.4]`` A/(m/s),
``Ki in [66.7, 104.2]`` 1/s. ``Kff`` does not enter the feedback law, so not the
margins either; it spans no to full feed-forward, ``[0, 1]``. At every corner the
loop is stable; the worst phase margin is 21.8 deg at ``(52.1, 21.4, 104.2)``,
the worst gain margin 8.7 dB at ``(52.1, 33.4, 104.2)``
(``tests/gbo_envs/test_cascade_env.py`` checks all of them).

Cost normalisers: the mean metrics over the 16 corners of the feasible set,
the overshoot's at least one 5 um count (0.05 % of the step,
:func:`~gbo_envs.envs.base.normalizer_floors`). The corners overshoot by a
quarter of a count on average, and near the optimum a count of overshoot is the
quantised loop's chatter, not a true overshoot: the plant without its sensor's
quantisation does not overshoot there by a tenth of a count
(``tests/agents/test_guided_bo_nd.py``). One count costs the overshoot's
weight, 0.10 (with the corner mean as normaliser it cost 0.40, two thirds of
J*).

Cost surface: the certified search (``gbo_envs.ground_truth``) finds
``J* = 0.5951`` at about ``(52.1, 21.5, 96.0, 1.0)``, on the faces
``Kv = Kv_max`` (the margin bound) and ``Kff = 1``, without overshoot; the
nominal design costs 0.671. The paper's ``sigma_eps = 0.001`` (same weights,
corner normalisation) is kept: 0.17 % of that optimum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gbo_envs.controllers import ANTI_WINDUP, CascadeController
from gbo_envs.envs.dc_motor_pid import corner_gains
from gbo_envs.envs.linear_motor import LINEAR_MOTOR, LinearMotorDrive, LinearMotorEnv
from gbo_envs.envs.plant_options import checked_fields

__all__ = ["CascadeDrive", "LINEAR_CASCADE", "LinearMotorCascadeEnv", "nominal_cascade"]

#: Calibration facts of the cascade (the plant, sensor, step and weights are those of ``LINEAR_MOTOR``).
LINEAR_CASCADE = {
    "speed_filter_time": 0.001,  # s, Tv of the speed estimate
    "reference_filter_time": 0.015,  # s, Tr of the setpoint filter
    "small_time_constant": 0.003,  # s, T_sigma: delay 1 ms + dt/2 + Tv + dt/2
    "gain_low": (33.3, 21.4, 66.7, 0.0),  # Kv in 1/s, Kp in A/(m/s), Ki in 1/s, Kff
    "gain_high": (52.1, 33.4, 104.2, 1.0),
    "max_experiments": 50,
}


@dataclass(frozen=True)
class CascadeDrive(LinearMotorDrive):
    """The drive of the position -> speed cascade: :class:`LinearMotorDrive` and how its speed PI meets the limit.

    Parameters
    ----------
    current_limit, sensor_resolution
        As in :class:`LinearMotorDrive`; the current limit is the controller's output limit.
    anti_windup : {"clamping", "back-calculation", "none"}, default "clamping"
        The speed integrator against the current limit (:class:`~gbo_envs.controllers.CascadeController`).
    tracking_time : float, optional
        Back-calculation's tracking time in s (default: the controller's).
    """

    anti_windup: str = "clamping"
    tracking_time: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.anti_windup not in ANTI_WINDUP:
            raise ValueError(f"anti_windup: must be one of {ANTI_WINDUP}, got {self.anti_windup!r}")
        checked_fields(self, tracking_time={"allow_none": True})


def nominal_cascade(gain: float = LINEAR_MOTOR["gain"], inertia: float = LINEAR_MOTOR["inertia"],
                    damping: float = LINEAR_MOTOR["damping"],
                    small_time_constant: float = LINEAR_CASCADE["small_time_constant"]) -> np.ndarray:
    """The nominal cascade ``(Kv, Kp, Ki, Kff)`` by the symmetric and technical optima (module docstring).

    Parameters
    ----------
    gain, inertia, damping : float
        Coefficients of ``G(s) = gain / (inertia s^2 + damping s)``, ``damping > 0``.
    small_time_constant : float
        ``T_sigma`` in s.
    """
    if not damping > 0.0:
        raise ValueError(f"damping: the speed plant K / (T s + 1) needs damping > 0, got {damping}")
    k, t, sigma = gain / damping, inertia / damping, small_time_constant
    return np.array([1.0 / (8.0 * sigma), t / (2.0 * k * sigma), 1.0 / (4.0 * sigma), 1.0])


class LinearMotorCascadeEnv(LinearMotorEnv):
    """Cascaded position control of the paper's linear servo motor; one step = one step experiment.

    ## Description

    The plant of ``gbo_envs/LinearMotor-v0``, ``G(s) = 0.44262 / (0.070983 s^2 +
    0.8 s) e^{-0.001 s}`` from drive current (A) to slider position (m), its 5 um
    position sensor and its experiment (at rest at 30 mm, the reference steps to
    40 mm, 0.30 s at 1 kHz, 301 samples), under the drive's cascade
    (:class:`~gbo_envs.controllers.CascadeController`, Tustin at 1 kHz)::

        r_f   = r / (Tr s + 1)                         setpoint filter, Tr = 15 ms
        v_hat = s / (Tv s + 1) y                       filtered difference of the sensor, Tv = 1 ms
        v_ref = Kv (r_f - y) + Kff r_f'                position P, velocity feed-forward
        i     = Kp (e_v + Ki int e_v dt),  e_v = v_ref - v_hat      speed PI

    The current command ``i`` is limited to ``[-7 A, 7 A]`` (the drive's limit)
    and the speed integrator is clamped while it is limited (conditional
    integration). The nominal design and the feasible set follow from stability
    margins (module docstring).

    ## Action Space

    ``Box(low=[33.3, 21.4, 66.7, 0.0], high=[52.1, 33.4, 104.2, 1.0], dtype=float64)``:

    | Num | Gain | Min  | Max   | Unit    |
    |-----|------|------|-------|---------|
    | 0   | Kv   | 33.3 | 52.1  | 1/s     |
    | 1   | Kp   | 21.4 | 33.4  | A/(m/s) |
    | 2   | Ki   | 66.7 | 104.2 | 1/s     |
    | 3   | Kff  | 0.0  | 1.0   | 1       |

    Gains outside the set raise ``ValueError`` unless ``out_of_bounds`` says otherwise.

    ## Observation Space

    ``Box(shape=(11,), dtype=float64)``: the last gains, the last normalised
    metrics ``f_i / n_i``, the last cost ``J``, the best cost so far and the
    fraction of the session's ``max_experiments`` used; before the first
    experiment the centre of the feasible set and zeros.

    ## Rewards

    ``-J`` with ``J = 0.10 zeta/n_1 + 0.18 T_s/n_2 + 0.69 T_r/n_3 + 0.04 e_ITAE/n_4``
    (eq. J_used, the linear motor's weights), each metric normalised by its mean
    ``n_i`` over the 16 corners of the feasible set (the reference gains; the
    paper normalised the linear motor's cost over the corners of its set), plus
    ``epsilon ~ N(0, cost_noise_std^2)``. A diverging loop gets ``J =
    unstable_cost`` and ``info["unstable"] = True``.

    ``info`` holds the whole record as on ``LinearMotor-v0``: ``t, r, u, y``
    (shape (301,); ``u`` is the drive's current command in A, within the 7 A
    limit; ``y`` the measured position in m, the controlled output),
    ``gains``, ``metrics``, ``cost``, ``true_cost``, ``unstable``,
    ``experiment_index`` and ``experiment``. The drive's speed estimate is not
    recorded: it is a function of ``y``,
    :meth:`~gbo_envs.controllers.CascadeController.speed_estimate`.

    ## Episode End

    An episode is one tuning session. It never terminates; ``gym.make``
    truncates it after ``max_episode_steps = 50`` experiments (four gains need
    more than the paper's 25 for two).

    ## Arguments

    ``gym.make("gbo_envs/LinearMotorCascade-v0", drive=CascadeDrive(current_limit=7.0,
    sensor_resolution=5e-6, anti_windup="clamping", tracking_time=None), **kwargs)``: those of
    ``LinearMotor-v0`` (keyword-only; a field of an option object may also be given by its name),
    with the cascade's drive (:class:`CascadeDrive`):

    * ``current_limit``: the drive's current limit in A, where the cascade
      clips its command (``None``: unlimited, a linear loop).
    * ``anti_windup``: ``"clamping"``, ``"back-calculation"`` (with
      ``tracking_time`` in s) or ``"none"``.
    * ``effects``: further effect blocks ``{name: {param: value}}`` after the
      sensor's quantisation (an entry ``"quantization"`` replaces it).
    * ``out_of_bounds``, ``unstable_cost``, ``normalizers``, ``expectation_draws``,
      ``expectation_seed``: as on ``LinearMotor-v0``.

    ## Version History

    * v0: initial version.
    """

    calibration = {**LINEAR_MOTOR, **LINEAR_CASCADE}
    limit_in_plant = False

    def __init__(self, *, drive: CascadeDrive = CascadeDrive(), **kwargs) -> None:
        if not isinstance(drive, CascadeDrive):
            raise TypeError(f"drive: the cascade's drive is a CascadeDrive (with its anti-windup), got {drive!r}")
        super().__init__(drive=drive, **kwargs)

    def _controller(self, options: dict):
        """The loop's controller: the cascade, its current command limited to the drive's ``current_limit``."""
        drive = options["drive"]
        return CascadeController(speed_filter_time=LINEAR_CASCADE["speed_filter_time"],
                                 reference_filter_time=LINEAR_CASCADE["reference_filter_time"],
                                 output_limit=drive.current_limit, anti_windup=drive.anti_windup,
                                 tracking_time=drive.tracking_time)

    @staticmethod
    def _reference_gains(low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """Gains whose mean metrics normalise the cost: the 16 corners of the feasible set."""
        return corner_gains(low, high)
