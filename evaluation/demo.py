"""The main job on an embedded default: ``gbo demo`` (and ``make demo``).

1. Ground truth of DCMotor-v0 by grid search, printed beside the paper's optimum.
2. PNGs of the optimal step response and of the cost surface.
3. When the tuners are installed: BO and guided BO on seeds 0, 1 and 2, their
   best gains beside the ground truth, and a convergence plot (mean over the seeds, 95 % band).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import agents
import gbo_envs
from evaluation.figures import save
from gbo_envs.plotting import convergence_figure, response_figure

__all__ = ["demo_command", "run_demo"]

PAPER_OPTIMUM = {"Kp": 0.54, "Ki": 1.16, "cost": 0.79}
PAPER_NOMINAL = {"Kp": 0.85, "Ki": 1.07}


def run_demo(out: Path, env_id: str = "gbo_envs/DCMotor-v0", seed: int = 0, budget: int = 20,
             tuners: bool = True, progress: bool | None = False, seeds: int = 3) -> dict:
    """Run the demo and write its figures into ``out``; returns the figures printed.

    Parameters
    ----------
    out : Path
        Output folder (created).
    env_id : str
        Plant to tune.
    seed : int
        Seed of the first tuning run of each tuner.
    budget : int
        Plant experiments per tuner.
    tuners : bool
        Also run the tuners (BO, guided BO) when they are available.
    progress : bool or None, default False
        A progress bar per tuning run on stderr; ``None``: only when stderr is a terminal.
    seeds : int, default 3
        Tuning runs per tuner (seeds ``seed, seed + 1, ...``): the convergence figure
        shows their mean with a 95 % confidence band.
    """
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise ValueError(f"seeds: must be an integer >= 1, got {seeds!r}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    summary: dict = {}

    start = time.perf_counter()
    truth = gbo_envs.ground_truth(env_id, resolution=100, noise=False)
    elapsed = time.perf_counter() - start
    names = truth.gain_names
    print(f"Ground truth on {env_id} (100 x 100 grid, {elapsed:.2f} s):")
    print(f"  {'':12s}" + "".join(f"{n:>8s}" for n in names) + f"{'cost':>8s}")
    print("  ours        " + "".join(f"{g:8.3f}" for g in truth.gains) + f"{truth.cost:8.3f}")
    if env_id == "gbo_envs/DCMotor-v0":
        print("  paper       " + "".join(f"{PAPER_OPTIMUM[n]:8.3f}" for n in names) + f"{PAPER_OPTIMUM['cost']:8.3f}")
        print("  (the paper's cost has another normalisation scale; the gains are what must agree)")
    summary["ground_truth"] = {"gains": dict(zip(names, truth.gains.tolist())), "cost": truth.cost,
                               "seconds": elapsed}

    env = gym.make(env_id, noise=False).unwrapped
    gains = [truth.gains]
    labels = [f"optimum {_fmt(names, truth.gains)}"]
    if env_id == "gbo_envs/DCMotor-v0":
        nominal = np.array([PAPER_NOMINAL[n] for n in names])
        gains.append(nominal)
        labels.append(f"paper's nominal PGM {_fmt(names, nominal)}")
    response = env.loop.simulate(np.array(gains), rng=np.random.default_rng(0))
    fig = response_figure(env.loop, response, labels=labels, title=f"{env_id}: step responses",
                          output_unit=env.output_unit, input_unit=env.input_unit)
    save(fig, out / "optimal_step_response.png", dpi=120)

    ax = truth.plot()
    ax.set_title(f"{env_id}: noise-free cost surface")
    save(ax.figure, out / "cost_surface.png", dpi=120)
    print(f"Wrote {out / 'optimal_step_response.png'} and {out / 'cost_surface.png'}")

    if tuners:
        summary["tuners"] = _run_tuners(out, env_id, truth, range(seed, seed + seeds), budget, progress)
    return summary


def demo_command(args: argparse.Namespace) -> int:
    """Handler of ``gbo demo`` (its arguments: :func:`evaluation.cli.build_parser`); returns the exit status."""
    run_demo(Path(args.out), env_id=args.env, seed=args.seed, budget=args.budget, tuners=not args.no_tuners,
             progress=False if args.quiet else None, seeds=args.seeds)
    return 0


def _run_tuners(out: Path, env_id: str, truth, seeds: range, budget: int, progress: bool | None) -> dict:
    available = [name for name in ("bo", "guided-bo") if name in agents.registered_names()]
    if not available:
        return {}
    results = []
    rows = {}
    print(f"\nTuning {env_id} with {', '.join(available)} (seeds {seeds.start}-{seeds.stop - 1}, {budget} plant "
          "experiments each):")
    for name in available:
        for seed in seeds:
            result = agents.make(name).run(gym.make(env_id), budget=budget, seed=seed, progress=progress)
            results.append(result)
            ratio = result.min_true_cost_curve() / truth.cost
            best = result.best_gains
            rows[f"{name}, seed {seed}"] = {"gains": dict(zip(truth.gain_names, best.tolist())),
                                            "final_ratio": float(ratio[-1]),
                                            "twin_evaluations": result.twin_evaluations}
            print(f"  {name:10s} seed {seed}: best {_fmt(truth.gain_names, best)}  optimality ratio {ratio[-1]:.3f}"
                  f"  twin evaluations {result.twin_evaluations}")
    fig = convergence_figure(results, optimum=truth.cost,
                             title=f"{env_id}: {len(seeds)} seeds, mean and 95 % confidence band")
    save(fig, out / "tuner_convergence.png", dpi=120)
    print(f"Wrote {out / 'tuner_convergence.png'}")
    return rows


def _fmt(names, gains) -> str:
    return "(" + ", ".join(f"{n}={g:.3g}" for n, g in zip(names, gains)) + ")"
