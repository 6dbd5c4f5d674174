"""Plant dynamics and the physical effect blocks (the single source of physics).

* :mod:`~gbo_envs.physics.lti`: continuous LTI plants with delay, exact ZOH discretisation;
* :mod:`~gbo_envs.physics.block`: the effect-block base class and parameter descriptions;
* :mod:`~gbo_envs.physics.actuator`: saturation, dead zone, backlash, offset, cogging;
* :mod:`~gbo_envs.physics.friction`: Coulomb and viscous friction, stiction;
* :mod:`~gbo_envs.physics.sensor`: quantization;
* :mod:`~gbo_envs.physics.plant_effects`: time delay, drift;
* :mod:`~gbo_envs.physics.compliance`: a flexible coupling (the two-mass resonance);
* :mod:`~gbo_envs.physics.effects`: the catalogue ``EFFECTS`` and ``build_effects``.
"""

from __future__ import annotations

from gbo_envs.physics.actuator import Backlash, Cogging, DeadZone, Offset, Saturation
from gbo_envs.physics.block import SIDES, EffectBlock, EffectParameter
from gbo_envs.physics.compliance import Compliance
from gbo_envs.physics.effects import EFFECT_NAMES, EFFECTS, build_effect, build_effects, describe_effect
from gbo_envs.physics.friction import CoulombFriction, Stiction, ViscousFriction
from gbo_envs.physics.lti import ContinuousPlant, DiscretePlant
from gbo_envs.physics.plant_effects import DRIFT_MODES, Drift, TimeDelay, plant_parameter
from gbo_envs.physics.sensor import Quantization

__all__ = [
    "Backlash",
    "Cogging",
    "Compliance",
    "ContinuousPlant",
    "CoulombFriction",
    "DRIFT_MODES",
    "DeadZone",
    "DiscretePlant",
    "Drift",
    "EFFECTS",
    "EFFECT_NAMES",
    "EffectBlock",
    "EffectParameter",
    "Offset",
    "Quantization",
    "SIDES",
    "Saturation",
    "Stiction",
    "TimeDelay",
    "ViscousFriction",
    "build_effect",
    "build_effects",
    "describe_effect",
    "plant_parameter",
]
