"""The paper's linear servo motor position loop (LinMot P01 on an NTI DM01 module) as a Gymnasium environment.

Nominal model and calibrated damping
------------------------------------
The authors' nominal model is a double integrator from the drive current ``i``
(A) to the slider position ``x`` (m), ``G0(s) = 0.44262 / (0.070983 s^2)
e^{-0.001 s}``, i.e. ``0.070983 x'' = 0.44262 i``: 6.236 m/s^2 per A. It has no
damping at all, and under the paper's PDT1 gains it overshoots 6-36 % (with
the 7 A limit and the 5 um sensor), whereas the hardware reached 0.06 % at the
optimum. The hardware therefore has damping the datasheet model lacks. We add
a viscous term ``c x'``::

    0.070983 x'' + c x' = 0.44262 i,    G(s) = 0.44262 / (0.070983 s^2 + c s) e^{-0.001 s}

with ``c = 0.8`` in the units of the model's other coefficients (divided by
0.44262 the equation is a current balance, ``i = 0.1604 x'' + 1.807 x'`` with
``i`` in A, ``x'`` in m/s and ``x''`` in m/s^2), which means:

* the drag balances a drive current of ``c / 0.44262 = 1.81 A`` per m/s of
  slider speed; at the experiment's peak speed of about 0.63 m/s that is
  1.1 A, 16 % of the 7 A current limit;
* a coasting slider slows down with the time constant
  ``0.070983 / c = 89 ms`` (pole at ``-11.3 1/s``), far below the loop's
  crossover near 300 rad/s, so it adds only about 2 deg of small-signal phase
  margin (discrete loop: 25.2-29.8 deg over the feasible set instead of
  23.3-27.6 deg) and mainly damps the saturated, large-signal part of the step.

Physically, three sources of speed-proportional drag act on the slider and are
all missing from a datasheet double integrator: the viscous shear of the
lubricant in the module's ball guide and its wiper seals, eddy currents the
magnets of the moving slider induce in the stator's metal housing, and
back-EMF that the drive's current controller compensates only up to its finite
bandwidth and voltage headroom. Their size is not in the paper, so ``c`` is
the one calibrated number: with it, the ground-truth optimum lies near the
paper's (5341 A/m, 49.7 A s/m): at (5349 A/m, 50.8 A s/m) with 0.05 %
overshoot (one sensor step) on the 100 x 100 grid. Any ``c`` in
``[0.6, 0.9]`` gives the same picture (``tests/gbo_envs/test_linear_motor.py``). In
terms of the effect catalogue, ``c`` equals a ``viscous_friction`` block with
``coefficient = c / 0.44262 = 1.81`` A s/m, kept in the linear plant so that
it is discretised exactly and enters the linear stability analysis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from gbo_envs.controllers import PDT1Controller
from gbo_envs.envs.motor_env import MotorEnv
from gbo_envs.envs.plant_options import checked_fields
from gbo_envs.physics.lti import ContinuousPlant

__all__ = ["LinearMotorDrive", "LinearMotorEnv", "LinearMotorPlant", "LINEAR_MOTOR", "linear_motor_plant",
           "vertex_gains"]

#: Calibration facts of the linear servo motor position loop (paper, Sec. VI-B).
LINEAR_MOTOR = {
    "gain": 0.44262,  # numerator of G(s) (authors' nominal model), see the module docstring
    "inertia": 0.070983,  # s^2 coefficient of G(s): 0.070983 / 0.44262 = 0.160 A per m/s^2
    "damping": 0.8,  # s coefficient of G(s), calibrated (module docstring): 1.81 A per m/s
    "delay": 0.001,  # s, one sample of the 1 kHz axis controller
    "dt": 0.001,  # s, 1 kHz sampling
    "filter_time": 0.001,  # s, derivative filter of the PDT1 controller, eq. (LM_Controller)
    "current_limit": 7.0,  # A, drive current clipped to [-7 A, 7 A]
    "sensor_resolution": 5e-6,  # m, MS01 position sensor (5 um absolute resolution)
    "duration": 0.30,  # s
    "r1": 0.030,  # m
    "r2": 0.040,  # m
    "gain_low": (5123.8, 40.1),  # eq. (LM_gain_bounds): Kp in A/m, Kd in A s/m
    "gain_high": (6136.2, 51.0),
    "weights": (0.10, 0.18, 0.69, 0.04),
    "max_experiments": 25,
    # the paper's sigma_eps = 0.001 on a cost normalised by the mean metrics over the four
    # vertices, exactly as here (J averages sum(w) = 1.01 over the vertices), so the level
    # carries over unchanged: 0.12 % of our ground-truth J* = 0.849
    "cost_noise_std": 0.001,
    # m; 0 by default so that the measured J follows the paper's J = J_hat + epsilon exactly
    "output_noise_std": 0.0,
}


def linear_motor_plant(gain: float, inertia: float, damping: float, delay: float) -> ContinuousPlant:
    """``G(s) = gain / (inertia s^2 + damping s) e^{-s delay}``, position output in m, current input in A.

    Parameters
    ----------
    gain : float
        Numerator, ``> 0`` (0.44262 in the authors' model).
    inertia : float
        Coefficient of ``s^2``, ``> 0``; ``inertia / gain`` is the current per
        unit acceleration in A s^2/m.
    damping : float
        Coefficient of ``s``, ``>= 0``; ``damping / gain`` is the current per
        unit speed in A s/m that balances the viscous drag.
    delay : float
        Input delay in s.
    """
    if not (gain > 0.0 and inertia > 0.0 and damping >= 0.0):
        raise ValueError(f"linear motor: need gain > 0, inertia > 0 and damping >= 0, "
                         f"got gain={gain}, inertia={inertia}, damping={damping}")
    return ContinuousPlant(num=(gain,), den=(inertia, damping, 0.0), delay=delay, output="position")


@dataclass(frozen=True)
class LinearMotorPlant:
    """The linear motor model: ``G(s) = gain / (inertia s^2 + damping s) e^{-s delay}``, position in m, current in A.

    Parameters
    ----------
    gain : float, default 0.44262
        Numerator, ``> 0``.
    inertia : float, default 0.070983
        Coefficient of ``s^2``, ``> 0``; ``inertia / gain`` is the current per unit acceleration in A s^2/m.
    damping : float, default 0.8
        Coefficient of ``s``, ``>= 0``; ``damping / gain`` is the current per unit speed in A s/m
        (``0``: the authors' bare nominal model).
    delay : float, default 0.001
        Input delay in s, ``>= 0``.
    """

    gain: float = LINEAR_MOTOR["gain"]
    inertia: float = LINEAR_MOTOR["inertia"]
    damping: float = LINEAR_MOTOR["damping"]
    delay: float = LINEAR_MOTOR["delay"]

    def __post_init__(self) -> None:
        checked_fields(self, gain={}, inertia={}, damping={}, delay={"low": 0.0})  # the signs: linear_motor_plant


@dataclass(frozen=True)
class LinearMotorDrive:
    """The linear motor's drive and position sensor.

    Parameters
    ----------
    current_limit : float or None, default 7.0
        The drive's current limit in A, ``> 0`` (``None``: unlimited).
    sensor_resolution : float or None, default 5e-6
        The position sensor's increment in m, ``> 0`` (``None``: an exact measurement).
    """

    current_limit: float | None = LINEAR_MOTOR["current_limit"]
    sensor_resolution: float | None = LINEAR_MOTOR["sensor_resolution"]

    def __post_init__(self) -> None:
        checked_fields(self, current_limit={"allow_none": True}, sensor_resolution={"allow_none": True})
        for name in ("current_limit", "sensor_resolution"):
            if getattr(self, name) is not None and getattr(self, name) <= 0.0:
                raise ValueError(f"{name}: must be > 0 or None, got {getattr(self, name)}")


class LinearMotorEnv(MotorEnv):
    """PDT1 position control of the paper's linear servo motor; one step = one step experiment.

    ## Description

    The plant is the authors' nominal model of the LinMot P01 linear motor on
    an NTI DM01 module with the calibrated viscous damping ``c`` (see the
    module docstring for its physical justification),
    ``G(s) = 0.44262 / (0.070983 s^2 + c s) e^{-0.001 s}`` with ``c = 0.8``,
    from drive current (A) to slider position (m). The industrial PDT1
    controller ``C(s) = Kp + Kd s / (0.001 s + 1)`` (eq. LM_Controller) runs at
    1 kHz (Tustin) and commands the current, which the drive clips to
    ``[-7 A, 7 A]`` (``saturation`` effect). The position sensor has a 5 um
    resolution (``quantization`` effect on the measurement, which feeds back
    and enters the metrics). Each experiment starts at rest at 30 mm and steps
    the reference to 40 mm for 0.30 s (301 samples). All lengths are in metres.
    The commanded current jumps to hundreds of A at the step, so at every gain
    of the feasible set the move is close to bang-bang (about 15 ms at +7 A,
    then 10-20 ms of braking at -7 A); the gains shape the braking and the
    final approach.

    ## Action Space

    ``Box(low=[5123.8, 40.1], high=[6136.2, 51.0], dtype=float64)``, the
    paper's feasible set (eq. LM_gain_bounds):

    | Num | Gain | Min    | Max    | Unit  |
    |-----|------|--------|--------|-------|
    | 0   | Kp   | 5123.8 | 6136.2 | A/m   |
    | 1   | Kd   | 40.1   | 51.0   | A s/m |

    Gains outside the set raise ``ValueError`` unless ``out_of_bounds`` says otherwise.

    ## Observation Space

    ``Box(shape=(9,), dtype=float64)``: the last gains ``[Kp, Kd]``, the last
    normalised metrics ``f_i / n_i`` (overshoot, settling time, rise time,
    ITAE), the last cost ``J``, the best cost so far, and the fraction of the
    session's ``max_experiments`` used. Before the first experiment: the centre
    of the feasible set and zeros.

    ## Rewards

    ``-J`` with ``J = 0.10 zeta/n_1 + 0.18 T_s/n_2 + 0.69 T_r/n_3 + 0.04 e_ITAE/n_4``
    (eq. J_used; the paper's weights, which add up to 1.01), each metric
    normalised by its mean ``n_i`` over the four vertices of the feasible set
    (as the paper did on the hardware), so that ``J`` averages 1.01 there, plus the
    measurement noise ``epsilon ~ N(0, cost_noise_std^2)``. A diverging loop
    gets ``J = unstable_cost`` and ``info["unstable"] = True``.

    ``info`` holds the whole experiment record: ``t, r, u, y`` (arrays of
    shape (301,); ``u`` is the commanded current in A before the 7 A clip,
    ``y`` the measured position in m), ``gains``, ``metrics``
    (``overshoot_pct`` in %, ``settling_time`` and ``rise_time`` in s, ``itae``
    in m s^2), ``cost`` (measured, noisy), ``true_cost`` (noise-free, for
    evaluation only), ``unstable`` and ``experiment_index``.

    ## Episode End

    An episode is one tuning session. It never terminates; ``gym.make``
    truncates it after ``max_episode_steps = 25`` experiments (the paper's
    ``n_max`` on the linear motor).

    ## Arguments

    ``gym.make("gbo_envs/LinearMotor-v0", noise=True, measurement_noise=MeasurementNoise(cost_noise_std=0.001,
    output_noise_std=0.0), plant=LinearMotorPlant(gain=0.44262, inertia=0.070983, damping=0.8, delay=0.001),
    drive=LinearMotorDrive(current_limit=7.0, sensor_resolution=5e-6), effects=None, out_of_bounds="raise",
    unstable_cost=10.0, render_mode=None)``, all keyword-only; a field of an option object may also be
    given by its name (``gym.make("gbo_envs/LinearMotor-v0", current_limit=None)``,
    :func:`gbo_envs.envs.plant_options.grouped`).

    * ``noise``: ``False`` gives the noise-free plant (both noise sources 0).
    * ``measurement_noise`` (:class:`~gbo_envs.envs.plant_options.MeasurementNoise`):
      ``cost_noise_std``, the std of the additive cost noise (dimensionless; the
      paper's ``sigma_eps = 0.001`` on the same normalisation, 0.12 % of the
      ground-truth optimum ``J* = 0.849``), and ``output_noise_std``, the std of
      white position-sensor noise in m, added to the quantised measurement; it
      feeds back and enters the metrics.
    * ``plant`` (:class:`LinearMotorPlant`): ``gain, inertia, damping`` of
      ``G(s) = gain / (inertia s^2 + damping s)`` (``damping=0`` gives the
      authors' bare nominal model) and the input ``delay`` in s.
    * ``drive`` (:class:`LinearMotorDrive`): the ``current_limit`` in A (``None``:
      no limit) and the position sensor's ``sensor_resolution`` in m (``None``:
      ideal sensor).
    * ``effects``: further effect blocks, ``{name: {param: value}}``
      (:func:`gbo_envs.physics.effects.build_effects`), applied after the
      current limit and the sensor quantisation; an entry named
      ``"saturation"`` or ``"quantization"`` replaces the built-in one.
    * ``out_of_bounds``, ``unstable_cost``, ``normalizers``, ``expectation_draws``, ``expectation_seed``,
      ``constraints``: as every motor env takes them (:class:`~gbo_envs.envs.motor_env.MotorEnv`).

    ## Version History

    * v0: initial version.
    """

    output_unit = "m"
    input_unit = "A"

    #: The env's calibration (:data:`LINEAR_MOTOR`; a variant of the loop changes its feasible set and length).
    calibration = LINEAR_MOTOR
    #: Whether the drive's current limit clips the plant input (``saturation``), not the controller's output.
    limit_in_plant = True

    plant_factory = staticmethod(linear_motor_plant)

    def __init__(self, *, plant: LinearMotorPlant = LinearMotorPlant(), drive: LinearMotorDrive = LinearMotorDrive(),
                 **kwargs) -> None:
        super().__init__(options={"plant": plant, "drive": drive}, **kwargs)

    def _effects(self, options: dict, effects) -> tuple:
        """The drive's current limit (unless the controller limits its output), the sensor's quantisation, then
        ``effects`` (:func:`linear_motor_effects`, kept as ``effects_spec``)."""
        drive = options["drive"]
        self.effects_spec = linear_motor_effects(drive.current_limit if self.limit_in_plant else None,
                                                 drive.sensor_resolution, effects)
        return super()._effects(options, self.effects_spec)

    def _controller(self, options: dict):
        """The loop's controller: the PDT1 of eq. (LM_Controller) (the drive limits the plant input)."""
        return PDT1Controller(filter_time=LINEAR_MOTOR["filter_time"])

    @staticmethod
    def _reference_gains(low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """Gains whose mean metrics normalise the cost: the four vertices of the feasible set."""
        return vertex_gains(low, high)


def vertex_gains(low, high) -> np.ndarray:
    """The four vertices ``(Kp_min, Kd_min), (Kp_min, Kd_max), (Kp_max, Kd_min), (Kp_max, Kd_max)``, shape (4, 2)."""
    (kp0, kd0), (kp1, kd1) = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    return np.array([[kp0, kd0], [kp0, kd1], [kp1, kd0], [kp1, kd1]])


def linear_motor_effects(current_limit: float | None, sensor_resolution: float | None,
                         effects: dict[str, dict[str, Any]] | None = None) -> dict[str, dict[str, Any]]:
    """Effect spec of the linear motor: the drive's current limit, the sensor's resolution, then ``effects``.

    An entry of ``effects`` with the name of a built-in block replaces it
    (keeping its place in the chain); the others follow in their given order.
    """
    spec: dict[str, dict[str, Any]] = {}
    if current_limit is not None:
        spec["saturation"] = {"limit": float(current_limit)}
    if sensor_resolution is not None:
        spec["quantization"] = {"step": float(sensor_resolution)}
    if effects:
        if not isinstance(effects, dict):
            raise ValueError(f"effects: expected a dict {{name: {{param: value}}}}, got {effects!r}")
        spec.update(effects)
    return spec
