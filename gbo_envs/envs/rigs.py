"""Rig stand-ins: the identified plants plus the effects a real rig has and the identified model lacks.

A tuner or a digital twin developed on ``DCMotor-v0`` / ``LinearMotor-v0``
meets, on the hardware, nonlinear effects their linear models leave out. These
envs put such effects in on purpose, with documented magnitudes, so that
tuners and twins can be tested against a plant that is *not* their model. Each
rig computes its cost normalisers on itself (as the paper measured them on its
hardware), so its cost surface is that of the rig.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gbo_envs.envs.dc_motor import DCMotorEnv
from gbo_envs.envs.linear_motor import LinearMotorEnv

__all__ = ["DCMotorRigEnv", "LinearMotorRigEnv", "DC_RIG", "LINEAR_RIG"]

#: Effects of the DC motor rig stand-in (input units are the controller's output units).
DC_RIG = {
    "command_limit": 160.0,  # input units; holding 306 rad/s takes 134.6 (+5 friction)
    "friction": 5.0,  # input units of Coulomb friction, 4.6 % of the 107.8 that hold 245 rad/s
    "encoder_lines": 2048,  # increments per revolution
    "dt": 0.002,  # s, speed is the increment count over one sample
}
#: Speed resolution of the DC motor rig's encoder in rad/s, 2 pi / (2048 * 0.002) = 1.534.
DC_ENCODER_STEP = 2.0 * np.pi / (DC_RIG["encoder_lines"] * DC_RIG["dt"])

#: Effects of the linear motor rig stand-in beyond ``LinearMotor-v0``'s 7 A limit and 5 um sensor.
LINEAR_RIG = {
    "friction": 0.5,  # A of Coulomb friction of the guide, 7 % of the 7 A limit
}


class DCMotorRigEnv(DCMotorEnv):
    """Stand-in for the paper's DC motor rig: ``DCMotor-v0`` plus friction, a command limit and an encoder.

    ## Description

    The identified model of ``gbo_envs/DCMotor-v0`` (same ``G(s)``, PI
    controller, 2 ms sampling, 245 -> 306 rad/s step over 5 s) with three
    effects a real rig has and the model lacks, in this order:

    1. ``saturation``, ``limit = 160`` input units: the drive's command limit.
       Holding 245 rad/s takes 107.8 units and 306 rad/s 134.6 units (plus the
       friction below), so the limit leaves 15-20 % headroom: it clips the
       transient of the high-gain half of the feasible set (the linear model
       asks up to 190 units there) and winds up the PI integrator, which
       raises the largest overshoot over the set from 35 % to 43 %.
    2. ``coulomb_friction``, ``torque = 5`` input units (4.6 % of the input
       that holds 245 rad/s): dry friction of brushes and bearings opposing
       the rotation. The motor always turns forward in the experiment, so it
       acts as a constant load the PI integrator absorbs; it shifts the
       commanded input ``u`` by 5 units.
    3. ``quantization``, ``step = 2 pi / (2048 * 0.002) = 1.534 rad/s``,
       ``mode = "floor"``: the speed is the number of whole increments of a
       2048-line encoder counted over one 2 ms sample. The step is 2.5 % of
       the 61 rad/s reference step, so the measured speed chatters by one
       step around the set point, which enters the settling time and ITAE.

    Cost normalisers are the rig's own mean metrics over the 5 reference
    gains of ``DCMotor-v0``.

    ## Action Space, Observation Space, Rewards, Episode End

    As ``DCMotor-v0`` (the action table, the 9 observations, ``-J`` and 35
    experiments per session); ``info["y"]`` is the quantised speed in rad/s.

    ## Arguments

    Those of ``DCMotor-v0``, plus:

    * ``command_limit``: drive command limit in input units (default 160).
    * ``friction``: Coulomb friction in input units (default 5).
    * ``encoder_lines``: encoder increments per revolution (default 2048);
      the speed step is ``2 pi / (encoder_lines * 0.002)`` rad/s.
    * ``effects``: further effects ``{name: {param: value}}``, after these
      three; an entry named like one of them replaces it in place.

    ## Version History

    * v0: initial version.
    """

    def __init__(
        self,
        command_limit: float = DC_RIG["command_limit"],
        friction: float = DC_RIG["friction"],
        encoder_lines: int = DC_RIG["encoder_lines"],
        effects: dict[str, dict[str, Any]] | None = None,
        **kwargs,
    ) -> None:
        if isinstance(encoder_lines, bool) or not isinstance(encoder_lines, (int, np.integer)) or encoder_lines < 1:
            raise ValueError(f"encoder_lines: must be a positive integer, got {encoder_lines!r}")
        spec: dict[str, dict[str, Any]] = {
            "saturation": {"limit": command_limit},
            "coulomb_friction": {"torque": friction},
            "quantization": {"step": 2.0 * np.pi / (int(encoder_lines) * DC_RIG["dt"]), "mode": "floor"},
        }
        spec.update(_checked_effects(effects))
        super().__init__(effects=spec, **kwargs)
        self.effects_spec = spec


class LinearMotorRigEnv(LinearMotorEnv):
    """Stand-in for the paper's linear motor rig: ``LinearMotor-v0`` plus Coulomb friction of the guide.

    ## Description

    The plant of ``gbo_envs/LinearMotor-v0`` (calibrated
    ``G(s) = 0.44262 / (0.070983 s^2 + 0.8 s) e^{-0.001 s}``, PDT1 controller
    at 1 kHz, 30 -> 40 mm step over 0.30 s) with the effects of the rig, in
    this order:

    1. ``saturation``, ``limit = 7`` A: the drive's current limit (as in
       ``LinearMotor-v0``); at every gain of the feasible set the step is
       close to a bang-bang move: about 15 ms at +7 A, then 10-20 ms of
       braking at -7 A.
    2. ``coulomb_friction``, ``torque = 0.5`` A: dry friction of the slider's
       bearings and the module's guide, as the drive current that balances it
       (7 % of the 7 A limit; it decelerates a coasting slider at
       ``0.5 * 0.44262 / 0.070983 = 3.1 m/s^2``). It damps the approach (the
       largest overshoot over the set falls from 22 % to 16 %) and, as the PD
       controller has no integrator, leaves the slider up to 20 um (4 sensor
       steps, 0.2 % of the step) short of or past the target.
    3. ``quantization``, ``step = 5e-6`` m: the MS01 sensor's 5 um resolution
       (as in ``LinearMotor-v0``).

    Cost normalisers are the rig's own mean metrics over the four vertices of
    the feasible set.

    ## Action Space, Observation Space, Rewards, Episode End

    As ``LinearMotor-v0`` (the action table, the 9 observations, ``-J`` and
    25 experiments per session).

    ## Arguments

    Those of ``LinearMotor-v0``, plus:

    * ``friction``: Coulomb friction of the guide in A (default 0.5).
    * ``effects``: further effects ``{name: {param: value}}``, after these
      three; an entry named like one of them replaces it in place.

    ## Version History

    * v0: initial version.
    """

    def __init__(self, friction: float = LINEAR_RIG["friction"], effects: dict[str, dict[str, Any]] | None = None,
                 **kwargs) -> None:
        spec: dict[str, dict[str, Any]] = {"coulomb_friction": {"torque": friction}}
        spec.update(_checked_effects(effects))
        super().__init__(effects=spec, **kwargs)


def _checked_effects(effects) -> dict[str, dict[str, Any]]:
    if not effects:
        return {}
    if not isinstance(effects, dict):
        raise ValueError(f"effects: expected a dict {{name: {{param: value}}}}, got {effects!r}")
    return effects
