"""Precomputed ground truths shipped with the package, and when :func:`~gbo_envs.ground_truth` may use one.

The rigs average their cost over ``expectation_draws`` noise draws, so their
100 x 100 ground truth takes a minute or more of CPU to simulate, and the
certified search of an env with three or more gains simulates tens of
thousands of gains. Their defaults are computed once by
``benchmarks/ground_truth_tables.py`` and shipped as
``gbo_envs/data/ground_truth/<env>.npz``. A table holds the env's normalisers,
a *fingerprint* of what it was computed for (the env id, the env's effective
constructor kwargs -- its defaults updated with the kwargs it was made with, so
``expectation_draws`` and ``expectation_seed`` included, an option object as its fields -- and the grid
resolution or the search's settings) and either

* a grid (:func:`save_table`): the cost grid and its gain axes, or
* a search (:func:`save_search_table`): the optimum's gains and cost, the
  search's tolerance, the second search's gains and cost, their disagreement
  and the evaluations both searches took.

A table is used only when the fingerprint of the request equals it exactly and
the env's normalisers equal the stored ones; anything else is computed live.
The tests check that sampled cells of each grid, and each search's optimum,
equal the live expectation, so a change of the physics that makes a table
stale fails CI.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
from pathlib import Path

import gymnasium as gym
import numpy as np

from gbo_envs.atomic_write import atomic_write
from gbo_envs.gain_grid import grid_axes

__all__ = ["TABLE_DIR", "IGNORED_KWARGS", "fingerprint", "load_search_table", "load_table", "save_search_table",
           "save_table", "search_fingerprint", "table_path"]

#: Folder of the shipped tables (package data).
TABLE_DIR = Path(__file__).resolve().parent / "data" / "ground_truth"
#: Constructor kwargs that do not enter :meth:`~gbo_envs.ControllerTuningEnv.evaluate` (the expected cost):
#: the additive cost noise has zero mean, and rendering, the out-of-bounds policy and the episode length
#: act on experiments, not on the grid, as do the ``constraints`` (they judge an experiment's record, not
#: its expected cost). ``noise`` only switches those experiments to the expectation (for a loop with
#: output noise it also removes that noise, which changes the normalisers and so bypasses the table).
IGNORED_KWARGS = ("noise", "cost_noise_std", "render_mode", "out_of_bounds", "max_experiments", "constraints")
#: Relative tolerance on the normalisers (bit-equal on one platform; this allows another BLAS's rounding).
NORMALIZER_RTOL = 1e-9


def search_fingerprint(env: gym.Env, search: dict) -> dict | None:
    """What a ground-truth search of ``env`` depends on, or ``None`` for an env not made from a registered id.

    Parameters
    ----------
    env : gymnasium.Env
        An env made by ``gym.make`` (wrappers allowed).
    search : dict
        The search's settings: ``n_points``, ``n_starts``, ``tolerance`` and ``seeds``.

    Returns
    -------
    dict or None
        ``{"env_id", "kwargs", "search"}``, ``kwargs`` as in :func:`fingerprint`.
    """
    stamp = fingerprint(env, 0)
    if stamp is None:
        return None
    del stamp["resolution"]
    stamp["search"] = json.loads(json.dumps(search, sort_keys=True))
    return stamp


def fingerprint(env: gym.Env, resolution: int) -> dict | None:
    """What a ground-truth grid of ``env`` depends on, or ``None`` for an env not made from a registered id.

    Parameters
    ----------
    env : gymnasium.Env
        An env made by ``gym.make`` (wrappers allowed).
    resolution : int
        Grid points per gain.

    Returns
    -------
    dict or None
        ``{"env_id", "kwargs", "resolution"}``: ``kwargs`` are the defaults
        of the env class's constructor chain updated with the kwargs it was
        made with, minus :data:`IGNORED_KWARGS`, plus the env's actual
        ``expectation_draws`` and ``expectation_seed``, in JSON form.
    """
    plant_env = env.unwrapped
    spec = getattr(plant_env, "spec", None) or getattr(env, "spec", None)
    if spec is None or spec.id is None:
        return None
    kwargs: dict = {}
    for cls in reversed(type(plant_env).__mro__):  # a subclass's default wins over its base's
        init = cls.__dict__.get("__init__")
        if init is None:
            continue
        for name, parameter in inspect.signature(init).parameters.items():
            if parameter.default is not inspect.Parameter.empty:
                kwargs.update(_settings(name, parameter.default))
    for name, value in (spec.kwargs or {}).items():
        kwargs.update(_settings(name, value))
    kwargs = {name: value for name, value in kwargs.items() if name not in IGNORED_KWARGS}
    kwargs["expectation_draws"] = int(plant_env.expectation_draws)
    kwargs["expectation_seed"] = int(plant_env.expectation_seed)
    return {"env_id": spec.id, "kwargs": json.loads(json.dumps(kwargs, sort_keys=True, default=repr)),
            "resolution": int(resolution)}


def _settings(name: str, value) -> dict:
    """A kwarg as the settings it stands for: an option object (a dataclass instance such as
    :class:`~gbo_envs.envs.plant_options.DCMotorPlant`) as its fields, by the names the env also takes them by."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {field.name: getattr(value, field.name) for field in dataclasses.fields(value)}
    return {name: value}


def table_path(env_id: str) -> Path:
    """Where the table of ``env_id`` is shipped (``gbo_envs/DCMotorRig-v0`` -> ``.../DCMotorRig-v0.npz``)."""
    return TABLE_DIR / f"{env_id.split('/')[-1]}.npz"


def load_table(env: gym.Env, resolution: int) -> tuple[tuple[np.ndarray, ...], np.ndarray] | None:
    """The shipped grid of ``env`` at ``resolution``, or ``None`` when there is none that fits exactly.

    Returns
    -------
    (axes, costs) or None
        ``axes``: one array of shape (resolution,) per gain; ``costs`` of
        shape ``(resolution,) * n_gains`` (``indexing="ij"``).
    """
    wanted = fingerprint(env, resolution)
    if wanted is None:
        return None
    path = table_path(wanted["env_id"])
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as data:
        if json.loads(str(data["fingerprint"])) != wanted:
            return None
        if not np.allclose(data["normalizers"], env.unwrapped.normalizers, rtol=NORMALIZER_RTOL, atol=0.0):
            return None
        axes = tuple(data[f"axis_{i}"] for i in range(int(data["n_gains"])))
        costs = data["costs"]
    box = env.unwrapped.action_space
    if not all(np.array_equal(a, b) for a, b in zip(axes, grid_axes(box.low, box.high, resolution), strict=True)):
        return None
    return axes, costs


def save_table(env: gym.Env, axes: tuple[np.ndarray, ...], costs: np.ndarray, path: Path | None = None) -> Path:
    """Write the grid ``costs`` over ``axes`` of ``env`` with its fingerprint (``benchmarks/ground_truth_tables.py``).

    Returns
    -------
    pathlib.Path
        The file written (default: :func:`table_path` of the env's id).
    """
    resolution = int(axes[0].size)
    stamp = fingerprint(env, resolution)
    if stamp is None:
        raise ValueError("env: a table needs an env made by gym.make from a registered id")
    path = Path(path) if path is not None else table_path(stamp["env_id"])
    arrays = {f"axis_{i}": np.asarray(axis, dtype=float) for i, axis in enumerate(axes)}
    with atomic_write(path, "wb", encoding=None) as handle:  # a reader sees the whole old or the whole new table
        np.savez_compressed(handle, fingerprint=np.array(json.dumps(stamp, sort_keys=True)), n_gains=len(axes),
                            costs=np.asarray(costs, dtype=float), normalizers=env.unwrapped.normalizers, **arrays)
    return path


#: Arrays of a search table beside its fingerprint and normalisers.
SEARCH_FIELDS = ("gains", "cost", "tolerance", "check_gains", "check_cost", "disagreement", "evaluations")


def load_search_table(env: gym.Env, search: dict) -> dict | None:
    """The shipped search result of ``env`` with the settings ``search``, or ``None`` when none fits exactly.

    Returns
    -------
    dict or None
        :data:`SEARCH_FIELDS` -> values (gains in the env's units, costs, the tolerance and
        disagreement as relative costs, the evaluations of both searches).
    """
    wanted = search_fingerprint(env, search)
    if wanted is None:
        return None
    path = table_path(wanted["env_id"])
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as data:
        if json.loads(str(data["fingerprint"])) != wanted or "check_gains" not in data:
            return None
        if not np.allclose(data["normalizers"], env.unwrapped.normalizers, rtol=NORMALIZER_RTOL, atol=0.0):
            return None
        return {name: data[name] if data[name].ndim else data[name].item() for name in SEARCH_FIELDS}


def save_search_table(env: gym.Env, search: dict, result: dict, path: Path | None = None) -> Path:
    """Write the search ``result`` (:data:`SEARCH_FIELDS`) of ``env`` with the settings ``search``.

    Returns
    -------
    pathlib.Path
        The file written (default: :func:`table_path` of the env's id).
    """
    stamp = search_fingerprint(env, search)
    if stamp is None:
        raise ValueError("env: a table needs an env made by gym.make from a registered id")
    missing = [name for name in SEARCH_FIELDS if name not in result]
    if missing:
        raise ValueError(f"result: missing {missing}; a search table holds {SEARCH_FIELDS}")
    path = Path(path) if path is not None else table_path(stamp["env_id"])
    arrays = {name: np.asarray(result[name], dtype=int if name == "evaluations" else float) for name in SEARCH_FIELDS}
    with atomic_write(path, "wb", encoding=None) as handle:  # a reader sees the whole old or the whole new table
        np.savez_compressed(handle, fingerprint=np.array(json.dumps(stamp, sort_keys=True)),
                            n_gains=np.size(arrays["gains"]), normalizers=env.unwrapped.normalizers, **arrays)
    return path
