"""Ground-truth surfaces of the registered envs: heat maps, connectivity, optimum stability and timing (issue 14).

For each env, on the ``--resolution``-point grid of its feasible set
(``gbo_envs.ground_truth``, ``J`` = expected cost over the measurement noise):

* the time ``ground_truth`` takes (all cores);
* the near-optimal set ``{J <= 1.1 J*}``: its number of 4-connected regions
  (``scipy.ndimage.label``) and the share of its cells in the largest;
* the shares of the box within 1.01, 1.05 and 1.1 of ``J*`` and the median ratio;
* for envs with measurement noise: the optimum's move in grid cells between
  two independent sets of ``K`` draws (``expectation_seed`` 0 and 1), and the
  standard error of ``J*`` from 512 single-draw experiments at the optimum;
* a heat map ``docs/images/<env>.png`` of ``J / J*`` with ``J*`` marked.

Writes ``benchmarks/results/rig_surfaces.json`` and prints a Markdown table::

    python benchmarks/rig_surfaces.py                    # every registered env, about 3 minutes on 2 cores
    python benchmarks/rig_surfaces.py --env gbo_envs/DCMotorRig-v0
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from scipy import ndimage

import gbo_envs
from gbo_envs import ground_truth
from gbo_envs.lazy_pyplot import pyplot
from gbo_envs.plotting import axis_label, legend_outside, style

ROOT = Path(__file__).resolve().parents[1]
IMAGES = ROOT / "docs" / "images"
RESULTS = ROOT / "benchmarks" / "results" / "rig_surfaces.json"


def connectivity(costs: np.ndarray, optimum: float, ratio: float = 1.1) -> tuple[int, float, int]:
    """Regions (4-connected), share of cells in the largest and cells of ``{J <= ratio J*}``."""
    inside = costs <= ratio * optimum
    labels, regions = ndimage.label(inside)  # the default structure is 4-connectivity in 2-D
    sizes = np.bincount(labels.ravel())[1:]
    return int(regions), float(sizes.max() / inside.sum()), int(inside.sum())


def single_draw_error(env_id: str, gains: np.ndarray, optimum: float, draws: int = 512) -> float:
    """Standard deviation of one experiment's cost at ``gains`` over the measurement noise, relative to ``J*``."""
    env = gym.make(env_id, noise=False).unwrapped
    response = env.loop.simulate(np.repeat(gains[None, :], draws, axis=0), rng=np.random.default_rng(12345),
                                 draws=np.arange(draws))
    costs = env._cost_or_unstable(env.loop.metrics(response), response.unstable)
    return float(costs.std(ddof=1) / optimum)


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
    row = {"env": name, "ground_truth_s": round(seconds, 2), "optimum": truth.gains.tolist(), "J*": truth.cost,
           "regions_1.1": regions, "largest_share_1.1": round(largest, 4), "cells_1.1": cells,
           **{f"share_{r}": float(np.mean(ratios <= r)) for r in (1.01, 1.05, 1.1)},
           "median_ratio": float(np.median(ratios)), "stochastic": env.loop.stochastic}
    if env.loop.stochastic:
        other = ground_truth(env_id, resolution=resolution, noise=False, expectation_seed=1)
        first = np.unravel_index(np.argmin(truth.costs), truth.costs.shape)
        second = np.unravel_index(np.argmin(other.costs), other.costs.shape)
        row["optimum_move_cells"] = int(np.max(np.abs(np.subtract(first, second))))
        row["J*_other_draws"] = other.cost
        row["expectation_draws"] = env.expectation_draws
        spread = single_draw_error(env_id, truth.gains, truth.cost)
        row["single_draw_std_pct"] = round(100 * spread, 3)
        row["standard_error_pct"] = round(100 * spread / np.sqrt(env.expectation_draws), 3)
    IMAGES.mkdir(parents=True, exist_ok=True)
    heat_map(truth, name, IMAGES / f"{name}.png")
    return row


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", action="append", help="env id (repeatable; default: every registered env)")
    parser.add_argument("--resolution", type=int, default=100)
    args = parser.parse_args(argv)
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
