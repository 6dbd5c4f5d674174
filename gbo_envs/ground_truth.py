"""Ground-truth optimum of a plant: exhaustive grid search of its expected cost over the feasible set."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from joblib import Parallel, delayed
from tqdm.auto import tqdm

from gbo_envs.gain_grid import grid_axes, grid_points
from gbo_envs.ground_truth_tables import load_table

__all__ = ["GroundTruth", "ground_truth"]


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Result of :func:`ground_truth`.

    Attributes
    ----------
    gains : ndarray of shape (n_gains,)
        Optimal gains ``theta*`` on the grid, in the env's units.
    cost : float
        Their cost ``J(theta*)`` (expected over the measurement noise).
    gain_names : tuple of str
    axes : tuple of ndarray
        Grid values of each gain, each of shape (resolution,).
    costs : ndarray of shape (resolution,) * n_gains
        ``J`` on the grid (``indexing="ij"``).
    gain_units : tuple of str
        Unit of each gain.
    """

    gains: np.ndarray
    cost: float
    gain_names: tuple[str, ...]
    axes: tuple[np.ndarray, ...]
    costs: np.ndarray
    gain_units: tuple[str, ...] = ()

    def optimality_ratio(self, cost) -> np.ndarray:
        """``phi = J / J(theta*)`` (paper, Sec. V)."""
        return np.asarray(cost, dtype=float) / self.cost

    def plot(self, ax=None, **kwargs):
        """Filled contour of the cost surface with the optimum marked (2 gains only)."""
        from gbo_envs.plotting import cost_surface

        return cost_surface(self, ax=ax, **kwargs)


def ground_truth(env_or_id, resolution: int = 100, chunk: int = 1000, n_jobs: int = -1, progress: bool = False,
                 use_table: bool = True, **make_kwargs) -> GroundTruth:
    """Ground-truth cost ``J(theta)`` on a ``resolution``-point-per-gain grid of the feasible set and its minimum.

    ``J(theta)`` is the expected cost over the measurement noise, computed by
    the env's :meth:`~gbo_envs.ControllerTuningEnv.evaluate` (for a noisy
    loop: the mean over its ``expectation_draws`` fixed draws), so each grid
    cell equals ``gym.make(id, noise=False).step(theta)`` at the same gains.

    The rigs' default grids (``DCMotorRig-v0`` and ``LinearMotorRig-v0`` at
    ``resolution=100``, whose live computation takes a minute or more of CPU)
    are precomputed by
    ``benchmarks/ground_truth_tables.py`` and shipped with the package
    (:mod:`gbo_envs.ground_truth_tables`); the table equals the live
    expectation (tested on sampled cells). It is used only when the env was
    made from its registered id with its default kwargs (those that do not
    enter the expected cost, such as ``noise``, aside), the same
    ``expectation_draws`` and ``expectation_seed``, and ``resolution``
    equals the table's; any other request is computed live.

    Parameters
    ----------
    env_or_id : gymnasium.Env or str
        A plant env (wrappers allowed) or a registered id such as
        ``"gbo_envs/DCMotor-v0"``.
    resolution : int, default 100
        Grid points per gain, ``>= 2`` (100 gives the paper's dense grid).
    chunk : int, default 1000
        Gains per task (each task simulates at most 4096 rows at once).
    n_jobs : int, default -1
        Worker processes over which the tasks run (joblib; ``-1``: one per
        core, ``1``: in this process).
    progress : bool, default False
        Show a tqdm progress bar over the tasks of a live computation.
    use_table : bool, default True
        ``False`` computes live even where a shipped table fits (what
        ``benchmarks/ground_truth_tables.py`` and the tests that check the
        tables do).
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
    table = load_table(env, int(resolution)) if use_table else None
    if table is not None:
        axes, costs = table
    else:
        low, high = plant_env.action_space.low, plant_env.action_space.high
        axes = grid_axes(low, high, int(resolution))
        grid = grid_points(axes)
        parts = np.array_split(grid, max(1, grid.shape[0] // max(1, int(chunk))))
        tasks = Parallel(n_jobs=n_jobs, return_as="generator")(delayed(_evaluate_part)(plant_env, part)
                                                               for part in parts)
        costs = np.concatenate(list(tqdm(tasks, total=len(parts), desc="ground truth", unit="task",
                                         disable=not progress)))
        costs = costs.reshape([axis.size for axis in axes])
    best = np.unravel_index(int(np.argmin(costs)), costs.shape)
    return GroundTruth(gains=np.array([axis[i] for axis, i in zip(axes, best)]), cost=float(costs[best]),
                       gain_names=plant_env.gain_names, axes=tuple(axes), costs=costs,
                       gain_units=plant_env.gain_units)


def _evaluate_part(env, gains: np.ndarray) -> np.ndarray:
    """``J`` at ``gains`` for one task (module level so that worker processes can run it)."""
    return env.evaluate(gains, experiment_index=0)[1]
