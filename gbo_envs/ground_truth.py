"""Ground-truth optimum of a plant by exhaustive grid search over its feasible set."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

__all__ = ["GroundTruth", "ground_truth"]


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Result of :func:`ground_truth`.

    Attributes
    ----------
    gains : ndarray of shape (n_gains,)
        Optimal gains ``theta*`` on the grid, in the env's units.
    cost : float
        Their noise-free cost ``J(theta*)``.
    gain_names : tuple of str
    axes : tuple of ndarray
        Grid values of each gain, each of shape (resolution,).
    costs : ndarray of shape (resolution,) * n_gains
        Noise-free cost on the grid (``indexing="ij"``).
    """

    gains: np.ndarray
    cost: float
    gain_names: tuple[str, ...]
    axes: tuple[np.ndarray, ...]
    costs: np.ndarray

    def optimality_ratio(self, cost) -> np.ndarray:
        """``phi = J / J(theta*)`` (paper, Sec. V)."""
        return np.asarray(cost, dtype=float) / self.cost

    def plot(self, ax=None, **kwargs):
        """Filled contour of the cost surface with the optimum marked (2 gains only)."""
        from gbo_envs.plotting import cost_surface

        return cost_surface(self, ax=ax, **kwargs)


def ground_truth(env_or_id, resolution: int = 100, chunk: int = 1000, **make_kwargs) -> GroundTruth:
    """Noise-free cost on a ``resolution``-point-per-gain grid of the feasible set and its minimum.

    Parameters
    ----------
    env_or_id : gymnasium.Env or str
        A plant env (wrappers allowed) or a registered id such as
        ``"gbo_envs/DCMotor-v0"``.
    resolution : int, default 100
        Grid points per gain, ``>= 2`` (100 gives the paper's dense grid).
    chunk : int, default 1000
        Gains simulated per vectorised call (bounds memory to about
        ``chunk * n_steps * 16`` bytes).
    **make_kwargs
        Passed to ``gym.make`` when an id is given.

    Returns
    -------
    GroundTruth
    """
    if int(resolution) < 2:
        raise ValueError(f"resolution: must be an integer >= 2, got {resolution}")
    env = gym.make(env_or_id, **make_kwargs) if isinstance(env_or_id, str) else env_or_id
    plant_env = env.unwrapped
    low, high = plant_env.action_space.low, plant_env.action_space.high
    axes = tuple(np.linspace(lo, hi, int(resolution)) for lo, hi in zip(low, high))
    mesh = np.meshgrid(*axes, indexing="ij")
    grid = np.column_stack([m.ravel() for m in mesh])
    costs = np.concatenate([plant_env.evaluate(part, experiment_index=0)[1]
                            for part in np.array_split(grid, max(1, grid.shape[0] // chunk))])
    best = int(np.argmin(costs))
    return GroundTruth(gains=grid[best].copy(), cost=float(costs[best]), gain_names=plant_env.gain_names,
                       axes=axes, costs=costs.reshape(mesh[0].shape))
