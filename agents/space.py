"""The feasible set of a tuning problem, read from an env's action space."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gbo_envs.gain_grid import grid_axes, grid_points

__all__ = ["GainSpace"]


@dataclass(frozen=True, eq=False)
class GainSpace:
    """Box-shaped feasible set ``Theta`` with named gains.

    Parameters
    ----------
    names : tuple of str
        Gain names as the env names them (``("Kp", "Ki")``).
    low, high : ndarray of shape (n_gains,)
        Bounds in physical units.
    units : tuple of str, optional
    """

    names: tuple[str, ...]
    low: np.ndarray
    high: np.ndarray
    units: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        low = np.asarray(self.low, dtype=float)
        high = np.asarray(self.high, dtype=float)
        if low.shape != (len(self.names),) or high.shape != low.shape or np.any(~(high > low)):
            raise ValueError(f"low, high: need {len(self.names)} finite bounds with low < high, got {low}, {high}")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)
        object.__setattr__(self, "names", tuple(self.names))

    @classmethod
    def from_env(cls, env) -> GainSpace:
        """Feasible set of a plant env (wrappers allowed): its action ``Box`` and gain names."""
        plant = env.unwrapped
        return cls.from_box(plant.action_space, names=getattr(plant, "gain_names", None),
                            units=tuple(getattr(plant, "gain_units", ())))

    @classmethod
    def from_box(cls, box, names=None, units: tuple[str, ...] = ()) -> GainSpace:
        """Feasible set of a one-dimensional ``gymnasium.spaces.Box`` of gains (named ``gain_0, ...`` without
        ``names``); anything else raises ``TypeError`` naming ``space``."""
        low, high = getattr(box, "low", None), getattr(box, "high", None)
        if low is None or high is None or np.ndim(low) != 1:
            raise TypeError(f"space: expected a GainSpace (GainSpace.from_env(env)) or an env's one-dimensional "
                            f"action_space Box, got {type(box).__name__}")
        names = tuple(names) if names is not None else tuple(f"gain_{i}" for i in range(np.size(low)))
        return cls(names=names, low=np.asarray(low, float), high=np.asarray(high, float), units=units)

    @property
    def dim(self) -> int:
        """Number of gains."""
        return len(self.names)

    def to_unit(self, gains: np.ndarray) -> np.ndarray:
        """Map gains of shape (..., n_gains) to the unit box ``[0, 1]^n``."""
        return (np.asarray(gains, dtype=float) - self.low) / (self.high - self.low)

    def from_unit(self, points: np.ndarray) -> np.ndarray:
        """Map unit-box points of shape (..., n_gains) to gains."""
        return self.low + np.asarray(points, dtype=float) * (self.high - self.low)

    def grid(self, points_per_gain: int) -> np.ndarray:
        """Regular grid of shape (points_per_gain ** n_gains, n_gains) over the box."""
        return grid_points(grid_axes(self.low, self.high, points_per_gain))

    def check(self, gains, name: str = "gains", atol: float = 1e-9) -> np.ndarray:
        """Validate gains: shape (n_gains,), finite, inside the box (within ``atol`` of the span).

        Returns
        -------
        ndarray of shape (n_gains,)
            The gains as floats, clipped onto the box where they were within tolerance.

        Raises
        ------
        ValueError
            Naming the offending gain and its allowed range.
        """
        try:
            array = np.asarray(gains, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name}: expected {self.dim} numbers {self.names}, got {gains!r}") from exc
        if array.shape != (self.dim,):
            raise ValueError(f"{name}: expected shape ({self.dim},) for {self.names}, got shape {array.shape}")
        span = self.high - self.low
        for gain, value, lo, hi, tol in zip(self.names, array, self.low, self.high, atol * span):
            if not np.isfinite(value):
                raise ValueError(f"{name}: {gain} must be finite, got {value}")
            if not lo - tol <= value <= hi + tol:
                raise ValueError(f"{name}: {gain} = {value:g} is outside the feasible set [{lo:g}, {hi:g}]")
        return np.clip(array, self.low, self.high)
