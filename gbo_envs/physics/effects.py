"""The catalogue of physical effects, building blocks from specs and describing their parameters.

Effects compose into any plant through ``gym.make`` kwargs::

    gym.make("gbo_envs/DCMotor-v0",
             effects={"saturation": {"limit": 150.0}, "coulomb_friction": {"torque": 20.0}})

Actuator blocks act in the order given, from the controller to the plant
(here: the drive limit first, then friction); sensor blocks in the order
given from the plant to the measurement.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from gbo_envs.physics.actuator import Backlash, Cogging, DeadZone, Offset, Saturation
from gbo_envs.physics.block import EffectBlock, EffectParameter
from gbo_envs.physics.compliance import Compliance
from gbo_envs.physics.friction import CoulombFriction, Stiction, ViscousFriction
from gbo_envs.physics.plant_effects import Drift, TimeDelay
from gbo_envs.physics.sensor import Quantization
from gbo_envs.physics.static_map import STATIC_MAPS

__all__ = ["EFFECTS", "EFFECT_NAMES", "build_effect", "build_effects", "describe_effect"]

#: Catalogue name -> block class (docs/design.md, "Effects catalogue"; the names are public API).
EFFECTS: dict[str, type[EffectBlock]] = {
    cls.name: cls
    for cls in (TimeDelay, Saturation, DeadZone, CoulombFriction, ViscousFriction, Stiction, Backlash,
                Quantization, Drift, Offset, Cogging, Compliance)
}

#: The catalogue names in the order of docs/design.md, "Effects catalogue".
EFFECT_NAMES: tuple[str, ...] = tuple(EFFECTS)


def _effect_class(name: Any) -> type[EffectBlock]:
    """The block class of a catalogue effect or of a static map (:data:`gbo_envs.physics.static_map.STATIC_MAPS`)."""
    if isinstance(name, str) and name in STATIC_MAPS:
        return STATIC_MAPS[name]
    if not isinstance(name, str) or name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; the catalogue is {EFFECT_NAMES} (and the static maps "
                         f"{tuple(STATIC_MAPS)})")
    return EFFECTS[name]


def build_effect(name: str, params: Mapping[str, Any] | None = None) -> EffectBlock:
    """One block from its catalogue name (or a static map's, ``"input_map"``, ``"output_map"``) and
    ``{parameter: value}``.

    Raises
    ------
    ValueError
        Unknown effect (the message lists the catalogue), unknown parameter,
        missing required parameter, or a value of the wrong type or out of
        range (the message names the effect, the parameter and the allowed values).
    """
    cls = _effect_class(name)
    if params is not None and not isinstance(params, Mapping):
        raise ValueError(f"{name}: parameters must be a dict {{parameter: value}}, got {params!r}")
    return cls.from_params(dict(params or {}))


def build_effects(spec) -> tuple[EffectBlock, ...]:
    """Effect blocks from a spec, in application order.

    Parameters
    ----------
    spec : dict, sequence or None
        ``{name: {parameter: value}}`` (insertion order is the order of
        application; a value may also be a built block, its key then only
        labels it), a sequence whose items are ``(name, {parameter: value})``
        pairs or built :class:`~gbo_envs.physics.block.EffectBlock` objects (a
        sequence allows the same effect twice), a single block, or ``None``.

    Returns
    -------
    tuple of EffectBlock

    Examples
    --------
    >>> build_effects({"saturation": {"limit": 150.0}, "coulomb_friction": {"torque": 20.0}})
    (Saturation(limit=150.0), CoulombFriction(torque=20.0, smoothing=0.0, asymmetry=0.0))
    """
    if spec is None:
        return ()
    if isinstance(spec, EffectBlock):
        return (spec,)
    if isinstance(spec, Mapping):
        return tuple(params if isinstance(params, EffectBlock) else build_effect(name, params)
                     for name, params in spec.items())
    if isinstance(spec, (str, bytes)) or not hasattr(spec, "__iter__"):
        raise ValueError(f"effects: expected a dict {{name: {{parameter: value}}}}, a list of (name, params) "
                         f"pairs or effect blocks, got {spec!r}; the catalogue is {EFFECT_NAMES}")
    blocks = []
    for item in spec:
        if isinstance(item, EffectBlock):
            blocks.append(item)
        elif isinstance(item, (tuple, list)) and len(item) == 2:
            blocks.append(build_effect(item[0], item[1]))
        elif isinstance(item, str):
            raise ValueError(f"effects: item {item!r} needs its parameters, as ({item!r}, {{parameter: value}})")
        else:
            raise ValueError(f"effects: each item must be a (name, params) pair or an effect block, got {item!r}")
    return tuple(blocks)


def describe_effect(effect: str | EffectBlock | type[EffectBlock]) -> tuple[EffectParameter, ...]:
    """The numeric parameters of an effect: name, unit, allowed range, default and zero value.

    Parameters
    ----------
    effect : str, EffectBlock or EffectBlock subclass
        A catalogue name, a block or a block class.

    Returns
    -------
    tuple of EffectParameter
        What a digital twin may fit; non-numeric settings are in the class's
        ``options`` (``{option: allowed values}``).
    """
    if isinstance(effect, EffectBlock):
        return type(effect).parameters
    if isinstance(effect, type) and issubclass(effect, EffectBlock):
        return effect.parameters
    return _effect_class(effect).parameters
