"""Limits an experiment must keep: upper bounds on metrics, on the peak command, or on any function of the record.

``gym.make(id, constraints={"overshoot_pct": 2.0, "peak_u": 140.0})`` gives the env a
:class:`Constraints` set; every ``step`` then reports, besides the cost,

* ``info["constraints"]``: name -> ``value - limit`` (Optuna's ``constraints_func``
  convention: ``<= 0`` is feasible, the size of a positive entry is the violation);
* ``info["feasible"]``: every entry ``<= 0`` and the loop stable (a diverging experiment
  is infeasible whatever its values; a failed one, without a record, too). An entry within
  floating-point noise above zero (:data:`LIMIT_RTOL` of the limit, or of 1) keeps its limit:
  two counts of a 5 um encoder beyond a 10 mm target are an overshoot of 0.1000000000000334 %,
  and a limit of 0.1 % is kept by them.

A constraint names one of

* a metric of ``info["metrics"]`` (:data:`~gbo_envs.metrics.METRIC_NAMES`: ``overshoot_pct`` in %,
  ``settling_time`` and ``rise_time`` in s, ``itae`` in output units x s);
* ``peak_u``, the largest ``|u|`` of the record (the plant input's units);
* its own name, with a callable of the record: ``{"name": (function, limit)}``, where
  ``function(record) -> float`` gets the :class:`~gbo_envs.experiment.Experiment`
  (``gains, t, r, u, y, cost, metrics``).

Every limit is an upper bound (state a lower bound ``x >= a`` as ``-x <= -a`` with a callable).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from gbo_envs.experiment import Experiment
from gbo_envs.metrics import METRIC_NAMES

__all__ = ["BUILTIN", "Constraint", "Constraints", "LIMIT_RTOL", "PEAK_U", "keeps"]

#: The signal-derived constraint: the largest ``|u|`` of the record.
PEAK_U = "peak_u"
#: Names a constraint may take without a function of its own.
BUILTIN = (*METRIC_NAMES, PEAK_U)
#: Relative floating-point noise of a value at its limit (of ``max(|limit|, 1)``) that still keeps the limit.
LIMIT_RTOL = 1e-9


def keeps(slacks, limits) -> np.ndarray:
    """Whether each ``value - limit`` keeps its limit: ``slack <= LIMIT_RTOL max(|limit|, 1)`` (NaN: not kept).

    Parameters
    ----------
    slacks, limits : array_like of the same shape
        ``value - limit`` and the limits, in the values' units.
    """
    limits = np.asarray(limits, dtype=float)
    return np.asarray(slacks, dtype=float) <= LIMIT_RTOL * np.maximum(np.abs(limits), 1.0)


@dataclass(frozen=True)
class Constraint:
    """One upper limit ``value(record) <= limit``.

    Attributes
    ----------
    name : str
        A metric name, ``"peak_u"``, or the user's name of ``function``.
    limit : float
        The upper limit, finite, in the value's units.
    function : callable or None
        ``function(record) -> float`` for a user constraint; ``None`` for a built-in one.
    """

    name: str
    limit: float
    function: Callable[[Experiment], float] | None = None

    @property
    def metric(self) -> int | None:
        """Index of the metric in :data:`~gbo_envs.metrics.METRIC_NAMES` this constraint bounds, else ``None``."""
        return METRIC_NAMES.index(self.name) if self.function is None and self.name in METRIC_NAMES else None

    def value(self, record: Experiment) -> float:
        """The constrained quantity of one record (NaN when the record cannot give it)."""
        if self.function is not None:
            return float(self.function(record))
        if self.name == PEAK_U:
            return peak_u(record.u) if record.has_signals else math.nan
        return float(record.metrics.get(self.name, math.nan))


def peak_u(u) -> float:
    """Largest ``|u|`` of a record's command, ``inf`` if it is not finite."""
    u = np.asarray(u, dtype=float)
    peak = float(np.max(np.abs(u))) if u.size else math.nan
    return peak if math.isfinite(peak) else math.inf


class Constraints:
    """The limits of an env, parsed and checked from what ``gym.make(..., constraints=...)`` got.

    Parameters
    ----------
    spec : mapping or None
        ``{name: limit}`` for a metric or ``"peak_u"``, ``{name: (function, limit)}`` for a user
        callable of the record, or ``{name: Constraint(...)}``. ``None`` or ``{}``: no constraint.

    Raises
    ------
    ValueError
        A limit that is not a finite number, or a name that is neither a metric nor ``"peak_u"``
        and has no function (the message names it and lists the allowed names).
    TypeError
        ``spec`` is not a mapping, or a function is not callable.
    """

    def __init__(self, spec: Mapping | None = None) -> None:
        if spec is None:
            spec = {}
        if isinstance(spec, Constraints):
            spec = {c.name: c for c in spec}
        if not isinstance(spec, Mapping):
            raise TypeError(f"constraints: expected a mapping name -> limit, got {type(spec).__name__} {spec!r}")
        self._items = tuple(_parse(name, value) for name, value in spec.items())

    # -- the set ----------------------------------------------------------------------------------
    def __iter__(self) -> Iterator[Constraint]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __bool__(self) -> bool:
        return bool(self._items)

    def __getitem__(self, name: str) -> Constraint:
        for item in self._items:
            if item.name == name:
                return item
        raise KeyError(name)

    @property
    def names(self) -> tuple[str, ...]:
        """The constraint names, in the order given."""
        return tuple(c.name for c in self._items)

    @property
    def limits(self) -> np.ndarray:
        """The limits, shape (n_constraints,)."""
        return np.array([c.limit for c in self._items], dtype=float)

    def to_spec(self) -> dict[str, float]:
        """``{name: limit}`` of the built-in constraints (for result files); user functions appear as their limit."""
        return {c.name: c.limit for c in self._items}

    def __repr__(self) -> str:
        parts = [f"{c.name} <= {c.limit:g}" + ("" if c.function is None else " (function)") for c in self._items]
        return f"Constraints({', '.join(parts)})"

    # -- judging experiments -------------------------------------------------------------------------
    def slacks(self, record: Experiment) -> dict[str, float]:
        """``value - limit`` of every constraint on one record (``<= 0``: kept; NaN: not measurable)."""
        return {c.name: c.value(record) - c.limit for c in self._items}

    def judge(self, record: Experiment | None, unstable: bool = False) -> dict:
        """The entries ``constraints`` and ``feasible`` of a step's ``info``.

        Parameters
        ----------
        record : Experiment or None
            The experiment (``None``: a failed experiment; every value is NaN).
        unstable : bool
            A diverging experiment is infeasible whatever its values.
        """
        slacks = {c.name: math.nan for c in self._items} if record is None else self.slacks(record)
        kept = bool(np.all(keeps([slacks[c.name] for c in self._items], self.limits)))
        return {"constraints": slacks, "feasible": bool(record is not None and not unstable and kept)}

    def batch_slacks(self, metrics: np.ndarray, u: np.ndarray | None, records=None) -> np.ndarray:
        """``value - limit`` of many experiments at once, shape (batch, n_constraints).

        Parameters
        ----------
        metrics : ndarray of shape (batch, 4)
            Their metrics, in :data:`~gbo_envs.metrics.METRIC_NAMES` order.
        u : ndarray of shape (batch, n_steps) or None
            Their commands (needed for ``peak_u``).
        records : callable ``i -> Experiment``, optional
            The record of experiment ``i`` (needed for user functions).
        """
        metrics = np.atleast_2d(np.asarray(metrics, dtype=float))
        out = np.empty((metrics.shape[0], len(self._items)))
        for j, c in enumerate(self._items):
            if c.metric is not None:
                out[:, j] = metrics[:, c.metric]
            elif c.function is None:  # peak_u
                if u is None:
                    raise ValueError("batch_slacks: peak_u needs the commands u")
                peak = np.max(np.abs(np.asarray(u, dtype=float)), axis=1)
                out[:, j] = np.where(np.isfinite(peak), peak, np.inf)
            else:
                if records is None:
                    raise ValueError(f"batch_slacks: the constraint {c.name!r} is a function of the record; "
                                     "pass records")
                out[:, j] = [float(c.function(records(i))) for i in range(metrics.shape[0])]
            out[:, j] -= c.limit
        return out


def _parse(name, value) -> Constraint:
    """One entry of a constraints mapping as a checked :class:`Constraint`."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"constraints: a name must be a non-empty string, got {name!r}")
    if isinstance(value, Constraint):
        function, limit = value.function, value.limit
    elif isinstance(value, tuple | list) and len(value) == 2 and callable(value[0]):
        function, limit = value
    elif callable(value):
        raise ValueError(f"constraints[{name!r}]: a function needs its limit, pass (function, limit)")
    else:
        function, limit = None, value
    if function is None and name not in BUILTIN:
        raise ValueError(f"constraints: {name!r} is neither a metric nor a signal of the record; allowed names: "
                         f"{', '.join(BUILTIN)}, or any name with (function, limit) for a function of the record")
    if function is not None and not callable(function):
        raise TypeError(f"constraints[{name!r}]: the function must be callable, got {function!r}")
    if isinstance(limit, bool):
        raise ValueError(f"constraints[{name!r}]: the limit must be a finite number, got {limit!r}")
    try:
        limit = float(limit)
    except (TypeError, ValueError):
        raise ValueError(f"constraints[{name!r}]: the limit must be a finite number, got {limit!r}") from None
    if not math.isfinite(limit):
        raise ValueError(f"constraints[{name!r}]: the limit must be a finite number, got {limit}")
    return Constraint(name=name, limit=limit, function=function)
