"""Ground-truth optimum of a plant: its expected cost minimised over the feasible set.

Up to two gains by exhaustive search of a dense grid; from three gains up by the
certified search of :mod:`gbo_envs.optimum_search` (Sobol points, multistart local
search, a second independent search that must agree within a stated tolerance).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from joblib import Parallel, delayed
from tqdm.auto import tqdm

from gbo_envs.constraints import Constraints
from gbo_envs.gain_grid import grid_axes, grid_points
from gbo_envs.ground_truth_tables import load_search_table, load_table
from gbo_envs.optimum_search import SearchDisagreement, certified_minimum, default_points
from gbo_envs.plotting import cost_surface

__all__ = ["FeasibleSet", "feasible_set", "GRID_MAX_GAINS", "GroundTruth", "METHODS", "ground_truth", "search_settings"]

#: ``method`` of :func:`ground_truth`: ``"auto"`` (the grid up to :data:`GRID_MAX_GAINS` gains, the search
#: above), ``"grid"`` or ``"search"``.
METHODS = ("auto", "grid", "search")
#: With ``method="auto"``: the most gains whose ground truth is a grid.
GRID_MAX_GAINS = 2


@dataclass(frozen=True, eq=False)
class FeasibleSet:
    """The gains of a grid that keep every constraint: the result of :func:`feasible_set`.

    Attributes
    ----------
    constraints : dict
        ``{name: limit}`` (:class:`~gbo_envs.constraints.Constraints`).
    axes : tuple of ndarray
        Grid values of each gain, each of shape (resolution,).
    costs : ndarray of shape (resolution,) * n_gains
        ``J`` on the grid (``indexing="ij"``), every cell.
    cells : ndarray of bool of shape (resolution,) * n_gains
        Which cells keep every limit and are stable, each judged on its noise-free experiment.
    gain_names, gain_units : tuple of str
    """

    constraints: dict
    axes: tuple[np.ndarray, ...]
    costs: np.ndarray
    cells: np.ndarray
    gain_names: tuple[str, ...]
    gain_units: tuple[str, ...] = ()

    @property
    def share(self) -> float:
        """The share of the grid's cells that keep every limit (dimensionless, in [0, 1])."""
        return float(np.mean(self.cells))

    @property
    def best(self) -> GroundTruth:
        """The best feasible cell as a :class:`GroundTruth` (its ``costs``: the whole grid).

        Raises
        ------
        ValueError
            No cell is feasible.
        """
        if not self.cells.any():
            raise ValueError(f"constraints: no gain of the {self.costs.shape[0]}-point grid keeps "
                             f"{self.constraints}; loosen a limit")
        best = np.unravel_index(int(np.argmin(np.where(self.cells, self.costs, np.inf))), self.costs.shape)
        return GroundTruth(gains=np.array([axis[i] for axis, i in zip(self.axes, best)]),
                           cost=float(self.costs[best]), gain_names=self.gain_names, axes=self.axes,
                           costs=self.costs, gain_units=self.gain_units)


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Result of :func:`ground_truth`.

    Attributes
    ----------
    gains : ndarray of shape (n_gains,)
        Optimal gains ``theta*`` (on the grid, or found by the search), in the env's units.
    cost : float
        Their cost ``J(theta*)`` (expected over the measurement noise).
    gain_names : tuple of str
    axes : tuple of ndarray
        Grid values of each gain, each of shape (resolution,); ``()`` for a search.
    costs : ndarray of shape (resolution,) * n_gains or None
        ``J`` on the grid (``indexing="ij"``); ``None`` for a search.
    gain_units : tuple of str
        Unit of each gain.
    method : {"grid", "search"}
        How the optimum was found.
    tolerance : float or None
        Search: the relative cost difference within which the second, independent
        search must find the same minimum (:func:`gbo_envs.optimum_search.certified_minimum`).
    check_gains : ndarray of shape (n_gains,) or None
        Search: the other search's minimiser, in the env's units.
    check_cost : float or None
        Search: its cost, ``>= cost``.
    disagreement : float or None
        Search: ``(check_cost - cost) / cost``, certified when ``<= tolerance``.
    evaluations : int or None
        Search: cost evaluations of both searches.
    """

    gains: np.ndarray
    cost: float
    gain_names: tuple[str, ...]
    axes: tuple[np.ndarray, ...] = ()
    costs: np.ndarray | None = None
    gain_units: tuple[str, ...] = ()
    method: str = "grid"
    tolerance: float | None = None
    check_gains: np.ndarray | None = None
    check_cost: float | None = None
    disagreement: float | None = None
    evaluations: int | None = None
    @property
    def certified(self) -> bool | None:
        """Search: whether the two searches agree within :attr:`tolerance`; ``None`` for a grid."""
        return None if self.method == "grid" else bool(self.disagreement <= self.tolerance)

    def optimality_ratio(self, cost) -> np.ndarray:
        """``phi = J / J(theta*)`` (paper, Sec. V)."""
        return np.asarray(cost, dtype=float) / self.cost

    def plot(self, ax=None, env=None, pair: tuple[int, int] = (0, 1), resolution: int = 40, **kwargs):
        """Filled contour of the cost surface with the optimum marked.

        Two gains: the grid. More gains: the 2-D slice through the optimum over the gains
        ``pair`` (the others held at ``theta*``), simulated on ``env`` (:meth:`slice`).

        Parameters
        ----------
        ax : matplotlib Axes, optional
        env : gymnasium.Env, optional
            The env of this ground truth; needed for more than two gains.
        pair : (int, int), default (0, 1)
            The two gains of the slice (more than two gains).
        resolution : int, default 40
            Slice points per gain (more than two gains).
        **kwargs
            Passed to :func:`gbo_envs.plotting.cost_surface`.
        """
        if len(self.gain_names) > 2 or self.costs is None:
            if env is None:
                raise ValueError(f"env: the ground truth has {len(self.gain_names)} gains; pass the env to draw "
                                 f"the 2-D slice through the optimum (truth.plot(env=env, pair=(i, j)))")
            return cost_surface(self.slice(env, pair, resolution), ax=ax, **kwargs)
        return cost_surface(self, ax=ax, **kwargs)

    def slice(self, env, pair: tuple[int, int] = (0, 1), resolution: int = 40) -> GroundTruth:
        """The cost on a grid over two gains through the optimum, the other gains held at ``theta*``.

        Parameters
        ----------
        env : gymnasium.Env
            The env this ground truth was computed for (wrappers allowed).
        pair : (int, int), default (0, 1)
            Indices of the two gains, different, in ``[0, n_gains)``.
        resolution : int, default 40
            Points per gain, ``>= 2``.

        Returns
        -------
        GroundTruth
            Two-gain grid: ``gains`` and ``cost`` are ``theta*`` (projected on the pair) and ``J*``.
        """
        n = len(self.gain_names)
        i, j = (int(k) for k in pair)
        if not (0 <= i < n and 0 <= j < n and i != j):
            raise ValueError(f"pair: need two different gain indices in [0, {n}), got {pair}")
        if int(resolution) < 2:
            raise ValueError(f"resolution: must be an integer >= 2, got {resolution}")
        plant = env.unwrapped
        axes = grid_axes(plant.action_space.low[[i, j]], plant.action_space.high[[i, j]], int(resolution))
        gains = np.tile(np.asarray(self.gains, dtype=float), (int(resolution) ** 2, 1))
        gains[:, [i, j]] = grid_points(axes)
        costs = plant.evaluate(gains, experiment_index=0)[1].reshape(int(resolution), int(resolution))
        units = tuple(self.gain_units[k] for k in (i, j)) if self.gain_units else ()
        return GroundTruth(gains=np.asarray(self.gains)[[i, j]], cost=self.cost,
                           gain_names=(self.gain_names[i], self.gain_names[j]), axes=axes, costs=costs,
                           gain_units=units)


def _make(env_or_id, make_kwargs: dict):
    """The env: ``env_or_id`` itself, or ``gym.make(env_or_id, **make_kwargs)`` of a registered id.

    An unregistered id raises ``ValueError`` naming it, with the namespaced id where only the
    ``gbo_envs/`` namespace was left out (``"DCMotor-v0"`` for ``"gbo_envs/DCMotor-v0"``); a
    ``"module:id"`` is gymnasium's to import and resolve.
    """
    if not isinstance(env_or_id, str):
        return env_or_id
    if ":" not in env_or_id and env_or_id not in gym.registry:
        namespaced = f"gbo_envs/{env_or_id}"
        hint = f"did you mean {namespaced!r}?" if namespaced in gym.registry else \
            "the registered ids are gbo_envs.ENV_IDS (or an env instance)"
        raise ValueError(f"env_or_id: {env_or_id!r} is not a registered env id; {hint}")
    return gym.make(env_or_id, **make_kwargs)


def ground_truth(env_or_id, resolution: int = 100, chunk: int = 1000, n_jobs: int = -1, progress: bool = False,
                 use_table: bool = True, method: str = "auto", n_points: int | None = None, n_starts: int = 16,
                 tolerance: float = 1e-3, seeds: tuple[int, int] = (0, 1), constraints=None,
                 **make_kwargs) -> GroundTruth:
    """Ground-truth minimum of the cost ``J(theta)`` over the feasible set: a grid (two gains) or a search.

    Up to two gains (``method="auto"``): ``J`` on a ``resolution``-point-per-gain
    grid and its minimum. From three gains up: the certified search of
    :func:`gbo_envs.optimum_search.certified_minimum` on ``J``: ``n_points``
    scrambled Sobol points and L-BFGS-B from the best ``n_starts`` (seed
    ``seeds[0]``), and an independent second search (seed ``seeds[1]``,
    Nelder-Mead), every start ending with Nelder-Mead restarts, whose minimum
    must lie within ``tolerance`` (relative cost);
    the result carries both answers and their disagreement, and a
    :class:`~gbo_envs.optimum_search.SearchDisagreement` warning says when they
    do not agree.

    ``J(theta)`` is the expected cost over the measurement noise, computed by
    the env's :meth:`~gbo_envs.ControllerTuningEnv.evaluate` (for a noisy
    loop: the mean over its ``expectation_draws`` fixed draws), so each grid
    cell equals ``gym.make(id, noise=False).step(theta)`` at the same gains.

    The rigs' default grids (``DCMotorRig-v0`` and ``LinearMotorRig-v0`` at
    ``resolution=100``, whose live computation takes a minute or more of CPU),
    and the default searches of the envs with more gains, are precomputed by
    ``benchmarks/ground_truth_tables.py`` and shipped with the package
    (:mod:`gbo_envs.ground_truth_tables`); the table equals the live
    expectation (tested on sampled cells). It is used only when the env was
    made from its registered id with its default kwargs (those that do not
    enter the expected cost, such as ``noise``, aside), the same
    ``expectation_draws`` and ``expectation_seed``, and ``resolution`` (a grid)
    or ``n_points``, ``n_starts``, ``tolerance`` and ``seeds`` (a search)
    equal the table's; any other request is computed live.

    Parameters
    ----------
    env_or_id : gymnasium.Env or str
        A plant env (wrappers allowed) or a registered id such as
        ``"gbo_envs/DCMotor-v0"``.
    resolution : int, default 100
        Grid: points per gain, ``>= 2`` (100 gives the paper's dense grid).
    chunk : int, default 1000
        Gains per task of the grid, or per batch of the search's Sobol points.
    n_jobs : int, default -1
        Grid: worker processes over which the tasks run (joblib; ``-1``: one per
        core, ``1``: in this process). The search runs in this process.
    progress : bool, default False
        Show a tqdm progress bar over the tasks of a live computation.
    use_table : bool, default True
        ``False`` computes live even where a shipped table fits (what
        ``benchmarks/ground_truth_tables.py`` and the tests that check the
        tables do).
    method : {"auto", "grid", "search"}, default "auto"
        ``"auto"``: the grid for up to :data:`GRID_MAX_GAINS` gains, the search above.
    n_points : int, optional
        Search: Sobol points per search (default
        :func:`~gbo_envs.optimum_search.default_points`, ``2 ** (10 + n_gains)`` up to ``2 ** 16``).
    n_starts : int, default 16
        Search: local searches per search, ``>= 1``.
    tolerance : float, default 1e-3
        Search: largest admitted relative difference of the two searches' minima, ``> 0``.
    seeds : (int, int), default (0, 1)
        Search: the Sobol seeds of the two searches.
    constraints : mapping, optional
        Limits the optimum must keep (:class:`~gbo_envs.constraints.Constraints`); default: the
        env's own (``gym.make(id, constraints=...)``), ``{}`` for none. With constraints the grid
        is computed live and the result is its best feasible cell, each cell judged on the
        noise-free experiment (:func:`feasible_set`, which also gives the feasible cells).
        Needs the grid (``method="grid"`` from three gains up: ``resolution ** n_gains`` cells).
    **make_kwargs
        Passed to ``gym.make`` when an id is given.

    Returns
    -------
    GroundTruth

    Raises
    ------
    ValueError
        An id that is not registered; with constraints: no grid cell is feasible, or the method is the search.
    """
    if int(resolution) < 2:
        raise ValueError(f"resolution: must be an integer >= 2, got {resolution}")
    if method not in METHODS:
        raise ValueError(f"method: must be one of {METHODS}, got {method!r}")
    env = _make(env_or_id, make_kwargs)
    plant_env = env.unwrapped
    dim = plant_env.action_space.shape[0]
    limits = getattr(plant_env, "constraints", Constraints()) if constraints is None else Constraints(constraints)
    if limits:
        if method == "search" or (method == "auto" and dim > GRID_MAX_GAINS):
            raise ValueError(f"constraints: the certified search is unconstrained; for {dim} gains pass "
                             f"method='grid' (resolution ** {dim} cells)")
        return feasible_set(env, limits, int(resolution), int(chunk), n_jobs, progress).best
    if method == "search" or (method == "auto" and dim > GRID_MAX_GAINS):
        return _search(env, search_settings(dim, n_points, n_starts, tolerance, seeds), int(chunk), progress,
                       use_table)
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


def search_settings(dim: int, n_points: int | None = None, n_starts: int = 16, tolerance: float = 1e-3,
                    seeds: tuple[int, int] = (0, 1)) -> dict:
    """The settings of a ground-truth search of ``dim`` gains, as its table's fingerprint holds them.

    Parameters as :func:`ground_truth`'s (``n_points=None``: :func:`~gbo_envs.optimum_search.default_points`).

    Returns
    -------
    dict
        ``{"n_points", "n_starts", "tolerance", "seeds"}``.
    """
    return {"n_points": int(default_points(dim) if n_points is None else n_points), "n_starts": int(n_starts),
            "tolerance": float(tolerance), "seeds": [int(seed) for seed in seeds]}


def _search(env, search: dict, chunk: int, progress: bool, use_table: bool) -> GroundTruth:
    """The certified search of ``env`` with the settings ``search`` (from its shipped table where one fits)."""
    plant = env.unwrapped
    stored = load_search_table(env, search) if use_table else None
    if stored is not None and not stored["disagreement"] <= stored["tolerance"]:
        warnings.warn(f"ground_truth: the shipped search of this env is not certified: its two searches disagree "
                      f"by {stored['disagreement']:.3g} (relative cost), above the tolerance {stored['tolerance']:g}",
                      SearchDisagreement, stacklevel=3)
    if stored is None:
        box = plant.action_space
        best, other, disagreement = certified_minimum(
            lambda gains: _evaluate_part(plant, gains), box.low, box.high, n_points=search["n_points"],
            n_starts=search["n_starts"], seeds=tuple(search["seeds"]), tolerance=search["tolerance"], chunk=chunk,
            progress=progress)
        stored = {"gains": best.gains, "cost": best.cost, "check_gains": other.gains, "check_cost": other.cost,
                  "disagreement": disagreement, "evaluations": best.evaluations + other.evaluations}
    return GroundTruth(gains=np.asarray(stored["gains"], dtype=float), cost=float(stored["cost"]),
                       gain_names=plant.gain_names, gain_units=plant.gain_units, method="search",
                       tolerance=search["tolerance"], check_gains=np.asarray(stored["check_gains"], dtype=float),
                       check_cost=float(stored["check_cost"]), disagreement=float(stored["disagreement"]),
                       evaluations=int(stored["evaluations"]))


def feasible_set(env_or_id, constraints=None, resolution: int = 100, chunk: int = 1000, n_jobs: int = -1,
                 progress: bool = False, **make_kwargs) -> FeasibleSet:
    """The grid cells that keep ``constraints`` and their costs; ``.best`` is the constrained optimum.

    Each cell is judged on its noise-free experiment
    (:meth:`~gbo_envs.ControllerTuningEnv.evaluate_constraints`: the expected metrics,
    ``peak_u`` and user functions on the record of noise draw 0, unstable cells infeasible).
    Computed live (the shipped tables hold costs only), on ``resolution ** n_gains`` cells.

    Parameters
    ----------
    env_or_id : gymnasium.Env or str
        A plant env (wrappers allowed) or a registered id.
    constraints : mapping, optional
        The limits (:class:`~gbo_envs.constraints.Constraints`); default: the env's own.
    resolution : int, default 100
        Grid points per gain, ``>= 2``.
    chunk, n_jobs, progress
        As in :func:`ground_truth`.
    **make_kwargs
        Passed to ``gym.make`` when an id is given.

    Returns
    -------
    FeasibleSet

    Raises
    ------
    ValueError
        An id that is not registered; without constraints (none given and the env has none).
    """
    if int(resolution) < 2:
        raise ValueError(f"resolution: must be an integer >= 2, got {resolution}")
    env = _make(env_or_id, make_kwargs)
    plant = env.unwrapped
    limits = getattr(plant, "constraints", Constraints()) if constraints is None else Constraints(constraints)
    if not limits:
        raise ValueError("constraints: a feasible set needs constraints, e.g. {'overshoot_pct': 2.0}; "
                         "the env has none")
    axes = grid_axes(plant.action_space.low, plant.action_space.high, int(resolution))
    grid = grid_points(axes)
    parts = np.array_split(grid, max(1, grid.shape[0] // max(1, int(chunk))))
    tasks = Parallel(n_jobs=n_jobs, return_as="generator")(
        delayed(_constrained_part)(plant, limits, part) for part in parts)
    done = list(tqdm(tasks, total=len(parts), desc="feasible set", unit="task", disable=not progress))
    shape = [axis.size for axis in axes]
    return FeasibleSet(constraints=limits.to_spec(), axes=tuple(axes),
                       costs=np.concatenate([d[0] for d in done]).reshape(shape),
                       cells=np.concatenate([d[1] for d in done]).reshape(shape), gain_names=plant.gain_names,
                       gain_units=plant.gain_units)


def _constrained_part(env, limits: Constraints, gains: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``J`` and feasibility at ``gains`` for one task (module level for the worker processes)."""
    cost, _, feasible = env.evaluate_constraints(gains, experiment_index=0, constraints=limits)
    return cost, feasible


def _evaluate_part(env, gains: np.ndarray) -> np.ndarray:
    """``J`` at ``gains`` for one task (module level so that worker processes can run it)."""
    return env.evaluate(gains, experiment_index=0)[1]
