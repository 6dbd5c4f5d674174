"""The twins' scikit-learn estimator base: parameters checked by :mod:`agents.parameters`, fitted in ``plant_``."""

from __future__ import annotations

from typing import Any, ClassVar

from sklearn.base import BaseEstimator

from agents.parameters import validate_params

__all__ = ["TwinEstimator"]


class TwinEstimator(BaseEstimator):
    """A twin estimator (scikit-learn's conventions: ``__init__`` only stores, ``fit`` returns ``self``).

    Subclasses declare ``_parameter_constraints`` in the forms of :mod:`agents.parameters`, the
    tuners' validation system; :meth:`_validate_params` checks the stored parameters at ``fit``.
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

    def __sklearn_is_fitted__(self) -> bool:
        return hasattr(self, "plant_")
