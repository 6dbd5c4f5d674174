"""The twins' scikit-learn estimator base: parameters checked by :mod:`agents.parameters`, fitted in ``plant_``."""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

from sklearn.base import BaseEstimator

from agents.parameters import validate_params

__all__ = ["TwinEstimator"]


class TwinEstimator(BaseEstimator):
    """A twin estimator (scikit-learn's conventions: ``__init__`` only stores, ``fit`` returns ``self``).

    Subclasses declare ``_parameter_constraints`` in the forms of :mod:`agents.parameters`, the
    tuners' validation system; :meth:`_validate_params` checks the stored parameters at ``fit``.
    A parameter that is an option object (a frozen dataclass, e.g. ``options=IdentifyOptions(...)``)
    shows its fields as nested parameters, as scikit-learn shows a nested estimator's:
    ``get_params()["options__n_poles"]``, ``set_params(options__n_zeros=1)`` (a copy with the field
    replaced, :func:`dataclasses.replace`), and an option object within it (a group) its own:
    ``set_params(options__solver__n_samples=100)``.
    """

    _parameter_constraints: ClassVar[dict[str, list]] = {}

    def _validate_params(self) -> dict[str, Any]:
        """The parameters (``get_params(deep=False)``) checked and converted (ints to ``int``, reals to ``float``).

        Raises
        ------
        ValueError
            Naming the first parameter outside its allowed values and what it allows,
            e.g. ``n_poles: must be an int in [1, inf), got 0``.
        """
        return validate_params(self._parameter_constraints, self.get_params(deep=False))

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """The constructor's parameters; with ``deep``, also ``<option>__<field>`` of each option object, and
        ``<option>__<group>__<field>`` of each option object within it."""
        params = super().get_params(deep=False)
        if deep:
            for name, value in list(params.items()):
                params.update(_fields(name, value))
        return params

    def set_params(self, **params) -> TwinEstimator:
        """Set parameters; ``<option>__<field>=value`` replaces one field of an option object (and
        ``<option>__<group>__<field>=value`` one field of a group within it).

        Raises
        ------
        ValueError
            For a name that is not a parameter, or a field the option object does not have.
        """
        nested: dict[str, dict[str, Any]] = {}
        for key in [key for key in params if "__" in key]:
            name, field = key.split("__", 1)
            nested.setdefault(name, {})[field] = params.pop(key)
        for name, changes in nested.items():
            params[name] = _replaced(name, params.get(name, getattr(self, name, None)), changes, type(self).__name__)
        return super().set_params(**params)

    def __sklearn_is_fitted__(self) -> bool:
        return hasattr(self, "plant_")


def _is_option(value) -> bool:
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def _fields(name: str, value) -> dict[str, Any]:
    """``{name__field: value}`` of an option object, its groups' fields included (``name__group__field``)."""
    if not _is_option(value):
        return {}
    out: dict[str, Any] = {}
    for f in dataclasses.fields(value):
        out[f"{name}__{f.name}"] = getattr(value, f.name)
        out.update(_fields(f"{name}__{f.name}", getattr(value, f.name)))
    return out


def _replaced(name: str, option, changes: dict[str, Any], owner: str):
    """``option`` with ``changes`` (``field`` or ``group__field`` keys) applied: a whole field first, then a
    group's fields (:func:`dataclasses.replace`).

    Raises
    ------
    ValueError
        Naming the parameter, for an option that is no option object or a field it does not have.
    """
    if not _is_option(option):
        raise ValueError(f"{name}__{next(iter(changes))}: {name} is not an option object of {owner} (got {option!r})")
    own = {f.name for f in dataclasses.fields(option)}
    unknown = sorted({key.split("__", 1)[0] for key in changes} - own)
    if unknown:
        raise ValueError(f"{name}__{unknown[0]}: {type(option).__name__} has no field {unknown[0]!r}")
    groups: dict[str, dict[str, Any]] = {}
    for key in [key for key in changes if "__" in key]:
        field, rest = key.split("__", 1)
        groups.setdefault(field, {})[rest] = changes[key]
    option = dataclasses.replace(option, **{key: value for key, value in changes.items() if "__" not in key})
    if not groups:
        return option
    return dataclasses.replace(option, **{field: _replaced(f"{name}__{field}", getattr(option, field), group,
                                                           type(option).__name__)
                                          for field, group in groups.items()})
