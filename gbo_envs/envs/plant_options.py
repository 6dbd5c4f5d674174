"""The built-in motor envs' settings that belong together, as keyword-only option objects, and their flat names.

:class:`MeasurementNoise` is the noise of an experiment; each family's module holds its plant
(:class:`~gbo_envs.envs.dc_motor.DCMotorPlant`, :class:`~gbo_envs.envs.linear_motor.LinearMotorPlant`) and
drive (:class:`~gbo_envs.envs.linear_motor.LinearMotorDrive`,
:class:`~gbo_envs.envs.linear_motor_cascade.CascadeDrive`). Each is frozen and checked when made
(:func:`checked_fields`: a bad field raises ``ValueError`` naming it). Their field names are the env kwargs
they group, so ``gym.make(id, gain=10.0)`` still means ``plant=DCMotorPlant(gain=10.0)`` (:func:`grouped`),
and a ground-truth fingerprint reads either the same (:func:`gbo_envs.ground_truth_tables.fingerprint`).
"""

from __future__ import annotations

import dataclasses
import numbers
from dataclasses import dataclass

import numpy as np

__all__ = ["ENV_NOISE", "MeasurementNoise", "checked_fields", "grouped"]


def _real(name: str, value, allow_none: bool = False, low: float | None = None) -> float | None:
    """``value`` as a finite float (``>= low`` when given), or ``None`` if allowed; else ``ValueError`` naming it."""
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not np.isfinite(value) \
            or (low is not None and value < low):
        bound = "" if low is None else f" >= {low:g}"
        raise ValueError(f"{name}: must be a finite number{bound}{' or None' if allow_none else ''}, got {value!r}")
    return float(value)


def checked_fields(option, **rules) -> None:
    """Convert each field of a frozen ``option`` to a finite float, by ``rules[field]`` (``allow_none``: ``None``
    allowed, ``low``: the least value); a bad one raises ``ValueError`` naming the field."""
    for name, rule in rules.items():
        object.__setattr__(option, name, _real(name, getattr(option, name), **rule))


@dataclass(frozen=True)
class MeasurementNoise:
    """The noise of one experiment: additive cost noise and white output-sensor noise.

    Parameters
    ----------
    cost_noise_std : float, optional
        Std of the additive cost noise ``epsilon`` of the paper's ``J = J_hat + epsilon``, dimensionless,
        ``>= 0`` (default: the env's).
    output_noise_std : float, optional
        Std of white noise on the measured output, in its units, ``>= 0``; it feeds back and enters the
        metrics (default: the env's).
    """

    cost_noise_std: float | None = None
    output_noise_std: float | None = None

    def __post_init__(self) -> None:
        checked_fields(self, cost_noise_std={"allow_none": True, "low": 0.0},
                 output_noise_std={"allow_none": True, "low": 0.0})

    def levels(self, defaults, noise: bool) -> tuple[float, float]:
        """``(cost_noise_std, output_noise_std)``: these, the ``defaults`` mapping's where ``None``, 0 without noise."""
        if not noise:
            return 0.0, 0.0
        return tuple(float(defaults[name]) if getattr(self, name) is None else getattr(self, name)
                     for name in ("cost_noise_std", "output_noise_std"))


#: The env's own noise levels (every field ``None``): the default of the built-in envs' ``measurement_noise``.
ENV_NOISE = MeasurementNoise()


def grouped(owner: str, settings: dict, **options) -> dict:
    """The option objects ``options`` (name -> option) with the flat ``settings`` (field -> value) applied.

    A flat setting names a field of one of the options (``gain=10.0`` for ``plant=DCMotorPlant(gain=10.0)``).

    Raises
    ------
    TypeError
        A setting that is no field of any option, naming ``owner`` and the fields it takes.
    """
    fields = {field.name: name for name, option in options.items() for field in dataclasses.fields(option)}
    unknown = sorted(set(settings) - set(fields))
    if unknown:
        raise TypeError(f"{owner}: unexpected keyword argument(s) {unknown}; the settings are its parameters and "
                        f"the fields of {', '.join(f'{n}={type(o).__name__}' for n, o in options.items())}: "
                        f"{sorted(fields)}")
    out = dict(options)
    for name in options:
        given = {field: value for field, value in settings.items() if fields[field] == name}
        if given:
            out[name] = dataclasses.replace(options[name], **given)
    return out
