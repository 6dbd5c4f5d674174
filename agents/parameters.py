"""Parameter constraints of the tuners, the twin estimators and the option objects, checked in one place.

A class declares a class-level ``_parameter_constraints`` dict (scikit-learn's convention),
parameter name -> list of allowed forms (``None``, :class:`Interval`, :class:`Options`,
:class:`Boolean`, :class:`InstanceOf`, :class:`ArrayLike` or :class:`HasMethods`); a value is
valid when it meets any of them. :func:`validate_params` checks arguments against it and
raises :class:`ValueError` naming the parameter and what it allows, e.g.
``n_initial: must be an int in [1, inf), got 0``. :func:`check_fields` applies it to a
frozen dataclass of options.

The project's own module, on NumPy alone: importing it loads no scikit-learn (the workbench's
start-up path stays free of it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from numbers import Integral, Real
from typing import Any

import numpy as np

__all__ = ["ArrayLike", "Boolean", "HasMethods", "InstanceOf", "Interval", "Options", "check_fields",
           "validate_params"]


@dataclass(frozen=True)
class Interval:
    """Numbers in ``[low, high]`` (``None``: unbounded); ``closed`` says which ends belong to the interval.

    Parameters
    ----------
    kind : {int, float}
        ``int`` admits integers only (not ``bool``); ``float`` admits any real number but NaN.
    low, high : float or None
        Bounds, ``None`` for ``-inf`` / ``inf`` (an infinite value is then admitted, unless ``finite``).
    closed : {"both", "left", "right", "neither"}, default "both"
    finite : bool, default False
        Refuse ``-inf`` and ``inf`` also where a bound is ``None`` (e.g. a delay in ``[0, inf)`` s).
    """

    kind: type
    low: float | None
    high: float | None
    closed: str = "both"
    finite: bool = False

    def __post_init__(self) -> None:
        if self.kind not in (int, float):
            raise ValueError(f"kind: must be int or float, got {self.kind!r}")
        if self.closed not in ("both", "left", "right", "neither"):
            raise ValueError(f"closed: must be 'both', 'left', 'right' or 'neither', got {self.closed!r}")

    def admits(self, value: Any) -> bool:
        if isinstance(value, bool) or not isinstance(value, Integral if self.kind is int else Real):
            return False
        if math.isnan(value) or (self.finite and math.isinf(value)):
            return False
        if self.low is not None and (value < self.low or (value == self.low and self.closed in ("right", "neither"))):
            return False
        return self.high is None or value < self.high or (value == self.high and self.closed in ("both", "right"))

    def convert(self, value: Any) -> int | float:
        return int(value) if self.kind is int else float(value)

    def __str__(self) -> str:
        left = "[" if self.closed in ("both", "left") and self.low is not None else "("
        right = "]" if self.closed in ("both", "right") and self.high is not None else ")"
        low = "-inf" if self.low is None else f"{self.low:g}"
        high = "inf" if self.high is None else f"{self.high:g}"
        kind = "an int" if self.kind is int else "a finite float" if self.finite else "a float"
        return f"{kind} in {left}{low}, {high}{right}"


@dataclass(frozen=True)
class Options:
    """One of a fixed set of values (strings, in practice)."""

    values: tuple

    def admits(self, value: Any) -> bool:
        return isinstance(value, str) and value in self.values

    def convert(self, value: Any) -> Any:
        return value

    def __str__(self) -> str:
        return f"one of {self.values}"


@dataclass(frozen=True)
class Boolean:
    """``True`` or ``False`` (also NumPy's ``bool_``, converted to ``bool``); not ``0`` or ``1``."""

    def admits(self, value: Any) -> bool:
        return isinstance(value, (bool, np.bool_))

    def convert(self, value: Any) -> bool:
        return bool(value)

    def __str__(self) -> str:
        return "a bool"


@dataclass(frozen=True)
class InstanceOf:
    """An instance of one of ``types`` (e.g. ``(list, tuple, dict, str)``), passed unchanged."""

    types: tuple[type, ...]

    def admits(self, value: Any) -> bool:
        return isinstance(value, self.types)

    def convert(self, value: Any) -> Any:
        return value

    def __str__(self) -> str:
        return f"an instance of {' or '.join(t.__name__ for t in self.types)}"


@dataclass(frozen=True)
class ArrayLike:
    """A sequence or an array (anything with a length, a shape or ``__array__``, but no string or scalar)."""

    def admits(self, value: Any) -> bool:
        return (hasattr(value, "__len__") or hasattr(value, "shape") or hasattr(value, "__array__")) \
            and not isinstance(value, (str, bytes)) and not np.isscalar(value)

    def convert(self, value: Any) -> Any:
        return value

    def __str__(self) -> str:
        return "an array-like"


@dataclass(frozen=True)
class HasMethods:
    """An object with the named methods (e.g. an unfitted estimator with ``fit``)."""

    methods: tuple[str, ...]

    def admits(self, value: Any) -> bool:
        return all(callable(getattr(value, name, None)) for name in self.methods)

    def convert(self, value: Any) -> Any:
        return value

    def __str__(self) -> str:
        return f"an object with method(s) {', '.join(self.methods)}"


def validate_params(constraints: dict[str, list], params: dict[str, Any]) -> dict[str, Any]:
    """Check ``params`` against ``constraints`` and return them converted (ints to ``int``, reals to ``float``).

    Parameters
    ----------
    constraints : dict
        Parameter name -> list of allowed forms: ``None`` (the value ``None``),
        :class:`Interval`, :class:`Options`, :class:`Boolean`, :class:`InstanceOf`,
        :class:`ArrayLike` or :class:`HasMethods`.
    params : dict
        The arguments; every name must have a constraint.

    Returns
    -------
    dict
        ``params`` with each value converted by the first form it meets.

    Raises
    ------
    ValueError
        For the first parameter that meets none of its forms, e.g.
        ``grid_points: must be an int in [2, inf), got 1``.
    """
    checked = {}
    for name, value in params.items():
        if name not in constraints:
            raise ValueError(f"{name}: no constraint declared for this parameter")
        forms = constraints[name]
        if value is None and None in forms:
            checked[name] = None
            continue
        form = next((f for f in forms if f is not None and f.admits(value)), None)
        if form is None:
            allowed = " or ".join("None" if f is None else str(f) for f in forms)
            raise ValueError(f"{name}: must be {allowed}, got {value!r}")
        checked[name] = form.convert(value)
    return checked


def check_fields(options: Any) -> None:
    """Validate a frozen dataclass's fields against its class's ``_parameter_constraints``, in ``__post_init__``.

    Each field takes its converted value (ints to ``int``, reals to ``float``), so that equal
    settings make equal objects.

    Raises
    ------
    ValueError
        For the first field outside its allowed values, named as by :func:`validate_params`.
    """
    checked = validate_params(type(options)._parameter_constraints,
                              {f.name: getattr(options, f.name) for f in fields(options)})
    for name, value in checked.items():
        object.__setattr__(options, name, value)

