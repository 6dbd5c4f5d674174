"""Static maps: a piecewise-linear input map (Hammerstein) or output map (Wiener) around the linear plant.

A general memoryless nonlinearity for what the catalogue's named effects do not express: a drive whose gain
falls with its level, a drive or sensor that works in one direction only, a sensor's curved characteristic.
The map is MATLAB's ``pwlinear`` (``nlhw``'s piecewise-linear estimator): straight lines between
breakpoints ``(k_i, v_i)``, ``i = 0..4``, continued beyond the outer breakpoints with the outer segments'
slopes,

.. math:: m(x) = v_i + \\frac{v_{i+1} - v_i}{k_{i+1} - k_i} (x - k_i), \\quad k_i \\le x \\le k_{i+1}

Blocks with these maps are not catalogue effects (:data:`gbo_envs.physics.EFFECT_NAMES`): they name no
physics, and a digital twin tries them after the catalogue (:mod:`agents.twin.static_map`). They build like
effects (:func:`gbo_envs.physics.build_effect`, ``"input_map"`` and ``"output_map"``), so an env can hide
one in its plant.
"""

from __future__ import annotations

import numpy as np

from gbo_envs.physics.block import MAGNITUDE_LIMIT, EffectBlock, EffectParameter

__all__ = ["N_KNOTS", "STATIC_MAPS", "InputMap", "OutputMap", "piecewise_linear"]

#: Breakpoints of a map (four segments).
N_KNOTS = 5


def piecewise_linear(x, knots: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The map through ``(knots[i], values[i])`` at ``x``, extended beyond the outer knots with the outer slopes.

    Parameters
    ----------
    x : array_like
        Where the map is taken (units of the knots).
    knots : ndarray of shape (n,)
        Strictly increasing breakpoints, ``n >= 2``.
    values : ndarray of shape (n,)
        The map's values there.
    """
    x = np.asarray(x, dtype=float)
    inside = np.interp(x, knots, values)
    low = values[0] + (values[1] - values[0]) / (knots[1] - knots[0]) * (x - knots[0])
    high = values[-1] + (values[-1] - values[-2]) / (knots[-1] - knots[-2]) * (x - knots[-1])
    return np.where(x < knots[0], low, np.where(x > knots[-1], high, inside))


def _parameters(unit: str) -> tuple[EffectParameter, ...]:
    knots = tuple(EffectParameter(f"k{i}", unit, -MAGNITUDE_LIMIT, MAGNITUDE_LIMIT, float(i), float("nan"),
                                  f"breakpoint {i} of the map (increasing)") for i in range(N_KNOTS))
    values = tuple(EffectParameter(f"v{i}", unit, -MAGNITUDE_LIMIT, MAGNITUDE_LIMIT, float(i),
                                   float("nan"), f"the map's value at breakpoint {i}") for i in range(N_KNOTS))
    weight = (EffectParameter("weight", "1", 0.0, 1.0, 1.0, 0.0,
                              "share of the map in effect: 0 is the identity, 1 the map through the breakpoints"),)
    return knots + values + weight


class _PiecewiseLinearMap(EffectBlock):
    """A piecewise-linear map ``x -> (1 - weight) x + weight m(x)`` (module docstring, :func:`piecewise_linear`)."""

    magnitude_param = "weight"

    def __init__(self, k0: float = 0.0, k1: float = 1.0, k2: float = 2.0, k3: float = 3.0, k4: float = 4.0,
                 v0: float = 0.0, v1: float | None = None, v2: float | None = None, v3: float | None = None,
                 v4: float | None = None, weight: float = 1.0) -> None:
        knots = (k0, k1, k2, k3, k4)
        values = [v0, v1, v2, v3, v4]
        values = [knots[i] if v is None else v for i, v in enumerate(values)]  # a value not given: the identity
        self._set_params(**{f"k{i}": knots[i] for i in range(N_KNOTS)}, **{f"v{i}": values[i] for i in range(N_KNOTS)},
                         weight=weight)
        if np.any(np.diff(self.knots) <= 0.0):
            raise ValueError(f"{self.name}: parameters 'k0'..'k4' (breakpoints) must increase strictly, got "
                             f"{self.knots.tolist()}")

    @property
    def knots(self) -> np.ndarray:
        """The breakpoints ``k0 .. k4``, read from the parameters (a copy whose parameters became per-row arrays,
        as a simulation merges blocks, reads its own; the numpy map then refuses them)."""
        return np.array([getattr(self, f"k{i}") for i in range(N_KNOTS)])

    @property
    def values(self) -> np.ndarray:
        """The map's values ``v0 .. v4`` at the breakpoints, read from the parameters."""
        return np.array([getattr(self, f"v{i}") for i in range(N_KNOTS)])

    def map(self, x) -> np.ndarray:
        """The map at ``x`` (shape of ``x``)."""
        x = np.asarray(x, dtype=float)
        knots, values = self.knots, self.values
        if knots.ndim != 1:  # per-row breakpoints (a merged copy): np.interp takes one map
            raise ValueError(f"{self.name}: one map per block; per-row breakpoints are not supported")
        if self.weight == 0.0:
            return x
        return (1.0 - self.weight) * x + self.weight * piecewise_linear(x, knots, values)

    def inverse(self, target) -> np.ndarray:
        """An ``x`` whose map is ``target``, on the map made non-decreasing: on a flat segment (a one-way drive's
        or sensor's zero) the point of that segment nearest to zero."""
        target = np.asarray(target, dtype=float)
        knots = self.knots
        span = knots[-1] - knots[0]
        grid = np.concatenate([[knots[0] - 1e3 * span], knots, [knots[-1] + 1e3 * span]])
        mapped = np.maximum.accumulate(self.map(grid))
        rises = np.diff(mapped) > 0.0
        first = np.concatenate([[True], rises])  # the lower end of each run of equal values
        last = np.concatenate([rises, [True]])  # its upper end
        if first.sum() < 2:
            return np.full_like(target, 0.0)
        low = np.interp(target, mapped[first], grid[first])
        high = np.interp(target, mapped[last], grid[last])
        return np.clip(0.0, low, high)


class InputMap(_PiecewiseLinearMap):
    """A static map of the commanded input (Hammerstein): the plant gets ``m(u)``.

    Parameters
    ----------
    k0 .. k4 : float
        Breakpoints in input units, strictly increasing.
    v0 .. v4 : float
        The plant input at each breakpoint (input units; not given: the breakpoint itself, the identity).
    weight : float, default 1
        ``0``: the identity (the block off); ``1``: the map.
    """

    name = "input_map"
    side = "actuator"
    parameters = _parameters("input units")

    def actuate(self, u, speed):
        return self.map(u)

    def command_for(self, u_applied, speed):
        return self.inverse(u_applied)


class OutputMap(_PiecewiseLinearMap):
    """A static map of the plant output (Wiener): the measurement is ``m(y)``.

    Parameters
    ----------
    k0 .. k4 : float
        Breakpoints in output units, strictly increasing.
    v0 .. v4 : float
        The measurement at each breakpoint (output units; not given: the breakpoint itself, the identity).
    weight : float, default 1
        ``0``: the identity (the block off); ``1``: the map.
    """

    name = "output_map"
    side = "sensor"
    parameters = _parameters("output units")

    def measure(self, y):
        return self.map(y)

    def level_for(self, y_measured):
        return self.inverse(y_measured)


#: Name -> block class of the static maps (built like effects, not in the catalogue).
STATIC_MAPS: dict[str, type[EffectBlock]] = {cls.name: cls for cls in (InputMap, OutputMap)}
