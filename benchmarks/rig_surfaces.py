"""Ground-truth surfaces of the registered envs: heat maps, connectivity, optimum stability and timing (issue 14).

For each env, on the ``--resolution``-point grid of its feasible set
(``gbo_envs.ground_truth``, ``J`` = expected cost over the measurement noise):

* the time ``ground_truth`` takes (all cores; from the shipped table where one fits,
  ``benchmarks/ground_truth_tables.py`` times the live computation);
* the near-optimal set ``{J <= 1.1 J*}``: its number of 4-connected regions
  (``scipy.ndimage.label``) and the share of its cells in the largest;
* the shares of the box within 1.01, 1.05 and 1.1 of ``J*`` and the median ratio;
* for envs with measurement noise: the optimum's move in grid cells between
  two independent sets of ``K`` draws (``expectation_seed`` 0 and 1; the second
  set on the cells within 1.2 J* of the first), and the standard error of ``J*``
  from 4096 single-draw experiments at the optimum, with a bootstrap 95 % interval;
* a heat map ``docs/images/<env>.png`` of ``J / J*`` with ``J*`` marked.

Writes ``benchmarks/results/rig_surfaces.json`` and prints a Markdown table::

    python benchmarks/rig_surfaces.py                    # every registered env, about 3 minutes on 2 cores
    python benchmarks/rig_surfaces.py --env gbo_envs/DCMotorRig-v0
    python benchmarks/rig_surfaces.py --env gbo_envs/LinearMotorRig-v0 --draws-sweep 16 64 256

``--draws-sweep`` only measures the optimum's move between two draw sets for
each ``K`` on full live grids, into ``benchmarks/results/rig_draws_sweep.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from scipy import ndimage, stats

import gbo_envs
from gbo_envs import ground_truth
from gbo_envs.ground_truth_tables import load_table
from gbo_envs.lazy_pyplot import pyplot
from gbo_envs.plotting import axis_label, legend_outside, style

ROOT = Path(__file__).resolve().parents[1]
IMAGES = ROOT / "docs" / "images"
RESULTS = ROOT / "benchmarks" / "results" / "rig_surfaces.json"
SWEEPS = ROOT / "benchmarks" / "results" / "rig_draws_sweep.json"


def connectivity(costs: np.ndarray, optimum: float, ratio: float = 1.1) -> tuple[int, float, int]:
    """Regions (4-connected), share of cells in the largest and cells of ``{J <= ratio J*}``."""
    inside = costs <= ratio * optimum
    labels, regions = ndimage.label(inside)  # the default structure is 4-connectivity in 2-D
    sizes = np.bincount(labels.ravel())[1:]
    return int(regions), float(sizes.max() / inside.sum()), int(inside.sum())


def single_draw_error(env_id: str, gains: np.ndarray, optimum: float, draws: int = 4096) -> tuple[float, float, float]:
    """Standard deviation of one experiment's cost at ``gains`` over the measurement noise, relative to ``J*``.

    The distribution has a heavy tail on the DC rig (a few per cent of the experiments settle a second
    time, later), so ``draws`` is large and the 95 % interval is a bootstrap one (``scipy.stats.bootstrap``).
    Returns the estimate and its interval.
    """
    env = gym.make(env_id, noise=False).unwrapped
    response = env.loop.simulate(np.repeat(gains[None, :], draws, axis=0), rng=np.random.default_rng(12345),
                                 draws=np.arange(draws))
    costs = env._cost_or_unstable(env.loop.metrics(response), response.unstable) / optimum
    interval = stats.bootstrap((costs,), lambda c, axis=-1: np.std(c, ddof=1, axis=axis), n_resamples=999,
                               random_state=0).confidence_interval
    return float(costs.std(ddof=1)), float(interval.low), float(interval.high)


def optimum_move(env_id: str, truth, seed: int = 1, within: float = 1.2) -> tuple[int, float, float]:
    """The optimum under a second, independent set of ``K`` draws (``expectation_seed=seed``).

    The second set is evaluated on the cells with ``J <= within J*`` under the first: a cell above that
    would need an error of ``within - 1`` of ``J*``, about a hundred standard errors of a cell, to become the
    optimum. Returns the move in grid cells (Chebyshev), the second set's minimum and the cost difference
    of the two optima under the first set in % of ``J*``.
    """
    other = gym.make(env_id, noise=False, expectation_seed=seed).unwrapped
    cells = np.argwhere(truth.costs <= within * truth.cost)
    gains = np.column_stack([axis[cells[:, i]] for i, axis in enumerate(truth.axes)])
    costs = other.evaluate(gains, experiment_index=0)[1]
    first = np.unravel_index(np.argmin(truth.costs), truth.costs.shape)
    second = tuple(cells[int(np.argmin(costs))])
    gap = 100 * (truth.costs[second] - truth.cost) / truth.cost
    return int(np.max(np.abs(np.subtract(first, second)))), float(costs.min()), float(gap)


def draws_sweep(env_id: str, draws: list[int], resolution: int) -> list[dict]:
    """The optimum's move between two independent draw sets for each ``K`` (full live grids of both sets)."""
    rows = []
    for k in draws:
        start = time.process_time()
        a, b = (ground_truth(env_id, resolution=resolution, n_jobs=1, use_table=False, expectation_draws=k,
                             expectation_seed=seed) for seed in (0, 1))
        first = np.unravel_index(np.argmin(a.costs), a.costs.shape)
        second = np.unravel_index(np.argmin(b.costs), b.costs.shape)
        rows.append({"expectation_draws": k, "optimum_move_cells": int(np.max(np.abs(np.subtract(first, second)))),
                     "optima_cells": [list(map(int, first)), list(map(int, second))],
                     "J*": [a.cost, b.cost],
                     # how far apart the two optima are in cost, under each set, in % of its J*
                     "gap_pct": [100 * (a.costs[second] - a.cost) / a.cost, 100 * (b.costs[first] - b.cost) / b.cost],
                     "cpu_s": round(time.process_time() - start, 1)})
        print(json.dumps(rows[-1]), flush=True)
    return rows


def heat_map(truth, name: str, path: Path) -> None:
    """Optimality ratio J/J* (-) over the two gains (in their units), J* and the 1.1 J* contour marked."""
    plt = pyplot()
    ratio = truth.costs.T / truth.cost
    with style():
        fig, ax = plt.subplots(figsize=(7, 5))
        mesh = ax.pcolormesh(truth.axes[0], truth.axes[1], ratio, shading="nearest", cmap="viridis",
                             vmin=1.0, vmax=min(3.0, float(ratio.max())))
        fig.colorbar(mesh, ax=ax, label=axis_label("optimality ratio J/J*", "-"))
        ax.grid(False)
        ax.contour(truth.axes[0], truth.axes[1], ratio, levels=[1.1], colors="w", linewidths=0.8)
        ax.plot(*truth.gains, "*", color="tab:red", mec="w", ms=15,
                label=f"J* = {truth.cost:.4f} at ({truth.gains[0]:.4g}, {truth.gains[1]:.4g})")
        ax.set_xlabel(axis_label(f"gain {truth.gain_names[0]}", truth.gain_units[0]))
        ax.set_ylabel(axis_label(f"gain {truth.gain_names[1]}", truth.gain_units[1]))
        ax.set_title(f"{name} (white line: J = 1.1 J*)")
        legend_outside(ax, below=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def survey(env_id: str, resolution: int) -> dict:
    name = env_id.split("/")[-1]
    env = gym.make(env_id, noise=False).unwrapped
    start = time.perf_counter()
    truth = ground_truth(env_id, resolution=resolution, noise=False)
    seconds = time.perf_counter() - start
    regions, largest, cells = connectivity(truth.costs, truth.cost)
    ratios = truth.costs / truth.cost
    row = {"env": name, "ground_truth_s": round(seconds, 2),
           "table": load_table(gym.make(env_id), resolution) is not None,
           "optimum": truth.gains.tolist(), "J*": truth.cost,
           "regions_1.1": regions, "largest_share_1.1": round(largest, 4), "cells_1.1": cells,
           **{f"share_{r}": float(np.mean(ratios <= r)) for r in (1.01, 1.05, 1.1)},
           "median_ratio": float(np.median(ratios)), "stochastic": env.loop.stochastic}
    if env.loop.stochastic:
        move, other, gap = optimum_move(env_id, truth)
        row["optimum_move_cells"] = move
        row["J*_other_draws"] = other
        row["optimum_gap_pct"] = round(gap, 4)
        row["expectation_draws"] = env.expectation_draws
        spread, low, high = single_draw_error(env_id, truth.gains, truth.cost)
        root = np.sqrt(env.expectation_draws)
        row["single_draw_std_pct"] = round(100 * spread, 3)
        row["single_draw_std_ci95_pct"] = [round(100 * low, 3), round(100 * high, 3)]
        row["standard_error_pct"] = round(100 * spread / root, 3)
        row["standard_error_ci95_pct"] = [round(100 * low / root, 3), round(100 * high / root, 3)]
    IMAGES.mkdir(parents=True, exist_ok=True)
    heat_map(truth, name, IMAGES / f"{name}.png")
    return row


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", action="append", help="env id (repeatable; default: every registered env)")
    parser.add_argument("--resolution", type=int, default=100)
    parser.add_argument("--draws-sweep", type=int, nargs="+", metavar="K",
                        help="only the optimum's move between two draw sets for each K (full live grids)")
    args = parser.parse_args(argv)
    if args.draws_sweep:
        sweeps = {env_id.split("/")[-1]: draws_sweep(env_id, args.draws_sweep, args.resolution)
                  for env_id in (args.env or gbo_envs.ENV_IDS)}
        previous = json.loads(SWEEPS.read_text()) if SWEEPS.exists() else {}
        SWEEPS.write_text(json.dumps(previous | sweeps, indent=1) + "\n")
        return [row for rows in sweeps.values() for row in rows]
    rows = [survey(env_id, args.resolution) for env_id in (args.env or gbo_envs.ENV_IDS)]
    previous = json.loads(RESULTS.read_text()) if RESULTS.exists() else []
    merged = {r["env"]: r for r in previous} | {r["env"]: r for r in rows}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(list(merged.values()), indent=1) + "\n")
    print("| env | ground_truth (s) | regions of J <= 1.1 J* | largest region | cells | share <= 1.01 / 1.05 / 1.1 "
          "| median J/J* | optimum move (cells) | SE of J* (K) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        move = r.get("optimum_move_cells", "-")
        error = f"{r['standard_error_pct']:.3f} % ({r['expectation_draws']})" if r["stochastic"] else "0 (noise-free)"
        print(f"| {r['env']} | {r['ground_truth_s']:.2f} | {r['regions_1.1']} | {100 * r['largest_share_1.1']:.1f} % "
              f"| {r['cells_1.1']} | {100 * r['share_1.01']:.2f} / {100 * r['share_1.05']:.2f} / "
              f"{100 * r['share_1.1']:.2f} % | {r['median_ratio']:.3f} | {move} | {error} |")
    return rows


if __name__ == "__main__":
    main()
