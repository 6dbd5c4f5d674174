"""Which part of guided BO buys what: the twin's guidance (prior mean or Algorithm 1) and the twin (issue 16).

Every variant is ``agents.make("guided-bo", **kwargs)`` (one is a BO option) against the default BO
(``agents.make("bo")``), over the same seeds, with the env's episode length as
budget:

* ``guided-bo``: the default, the diagnosed twin's metrics as the prior mean of the
  default BO's metric GPs (``guidance="prior"``, ``twin="auto"``);
* ``prior, linear twin``: the same with the paper's linear SRIVC twin;
* ``iterations, auto twin``: the paper's twin iterations (Algorithm 1) on one cost GP,
  with the diagnosed twin (the guided BO of issue 15);
* ``iterations, linear twin``: the paper's Algorithm 1 as published;
* ``wrong user twin``: the default given a deliberately wrong fitted twin
  (:func:`wrong_twin`), which must not make it worse than BO (issue 15);
* ``bo, envelope settling``: not guided BO but ``agents.make("bo",
  settling_model="envelope")``, the BO option that needs fewer experiments than the
  default BO on the DC motors: guided BO against the strongest BO we ship.

Per plant and variant: the mean real experiments until the best evaluated gains
reach each optimality ratio ``J / J*`` (``J``: the env's expected cost; ``J*``:
the ground-truth grid's minimum), with a 95 % Student-t interval and the misses
(a run that never reaches counts as ``budget + 1``), and the ratio to BO's mean.
On the DC motors two thresholds are the paper's nominal controllers,
``agents.make("nominal", phase_margin_deg=60)`` and ``=75`` (PGM at 46 dB, (0.855,
1.070) and (0.855, 0.890)): their ratios on the noise-free env.

The plants are those of ``effect_aware_guided_bo.py``. Finished runs are appended
to ``benchmarks/results/guided_bo_ablation_runs.jsonl`` and skipped when the
command is run again (an interrupted study resumes). Writes
``benchmarks/results/guided_bo_ablation.md`` and, with ``--traces``, the
optimality-ratio traces of the runs one variant missed next to another's on the
same seeds (``guided_bo_misses.png``)::

    python benchmarks/guided_bo_ablation.py --plants DCMotor-v0 --seeds 50
    python benchmarks/guided_bo_ablation.py --plants DC+saturation --variants bo guided-bo "prior, linear twin"
    python benchmarks/guided_bo_ablation.py --summary --traces "iterations, auto twin" guided-bo
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import numpy as np
from effect_aware_guided_bo import (
    PLANTS,
    count_cell,
    effects_column,
    optimum,
    study_arguments,
    study_runs,
    thresholds,
    timed_run,
)

RESULTS = Path(__file__).resolve().parent / "results"
RUNS = RESULTS / "guided_bo_ablation_runs.jsonl"


def wrong_twin():
    """A fitted :class:`~agents.twin.LinearTwin` of another plant: DCMotor-v0 behind a 60 ms dead time and a
    120-unit drive limit, identified from two experiments (its optimum costs DCMotor-v0 over 1.5 J*)."""
    from agents.twin import LinearTwin

    other = gym.make("gbo_envs/DCMotor-v0", effects={"time_delay": {"delay": 0.06}, "saturation": {"limit": 120.0}})
    other.reset(seed=0)
    records = [other.step(np.array(gains))[4] for gains in ([0.5, 1.2], [0.9, 1.6])]
    return LinearTwin(n_samples=100).fit(records)


#: label -> (registered tuner, keyword arguments; a callable value is called in the run, e.g. the wrong twin)
VARIANTS: dict[str, tuple[str, dict]] = {
    "bo": ("bo", {}),
    "guided-bo": ("guided-bo", {}),
    "prior, linear twin": ("guided-bo", {"twin": "linear"}),
    "iterations, auto twin": ("guided-bo", {"guidance": "iterations"}),
    "iterations, linear twin": ("guided-bo", {"guidance": "iterations", "twin": "linear"}),
    "wrong user twin": ("guided-bo", {"twin": wrong_twin}),
    "bo, envelope settling": ("bo", {"settling_model": "envelope"}),
}

#: Phase margins (deg) of the paper's nominal PGM controllers (Table nominal_ctl_specs), used on the DC motors.
NOMINAL_PHASE_MARGINS = (60.0, 75.0)


def nominal_ratio(label: str, best: float, phase_margin_deg: float) -> float | None:
    """``J(nominal) / J*`` of the nominal PGM controller on the noise-free plant, or ``None`` off the DC motors."""
    import agents

    if not label.startswith("DC"):
        return None
    env_id, kwargs = PLANTS[label]
    env = gym.make(env_id, noise=False, **kwargs)
    nominal = agents.make("nominal", phase_margin_deg=phase_margin_deg).run(env, budget=1, seed=0, progress=False)
    return float(nominal.min_true_cost_curve()[0]) / best


def run_one(label: str, variant: str, seed: int, best: float) -> dict:
    """One tuning run of ``variant`` (:func:`effect_aware_guided_bo.timed_run`)."""
    import agents

    name, tuner_kwargs = VARIANTS[variant]
    tuner_kwargs = {key: value() if callable(value) else value for key, value in tuner_kwargs.items()}
    return {"plant": label, "variant": variant, "seed": seed,
            **timed_run(label, agents.make(name, **tuner_kwargs), seed, best)}


def summarise(runs: list[dict]) -> str:
    """The Markdown table: per plant, threshold and variant, its runs and BO's on the same seeds."""
    lines = ["| plant | threshold | variant | seeds | variant: real experiments | bo, same seeds | variant / bo | "
             "s/run | tuner CPU s/run | activations | twin effects at the end (runs) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for label in PLANTS:
        mine = {v: {r["seed"]: r for r in runs if r["plant"] == label and r["variant"] == v} for v in VARIANTS}
        if not mine["bo"]:
            continue
        best = optimum(label)["cost"]
        levels = [(f"ratio {t}", t) for t in thresholds(label)]
        if label.startswith("DC"):
            levels = [("ratio 1.1", 1.1), *levels]
            for phase in NOMINAL_PHASE_MARGINS:
                nominal = nominal_ratio(label, best, phase)
                levels.append((f"nominal PGM {phase:g} deg (ratio {nominal:.3f})", nominal))
        for name, level in levels:
            for variant in VARIANTS:
                seeds = sorted(set(mine[variant]) & set(mine["bo"]))
                if variant == "bo" or len(seeds) < 2:
                    continue
                cells, means = [], []
                for runs_of in (mine[variant], mine["bo"]):
                    mean, cell = count_cell([runs_of[s] for s in seeds], level)
                    cells.append(cell)
                    means.append(mean)
                ran = [mine[variant][s] for s in seeds]
                lines.append(f"| {label} | {name} | {variant} | {len(seeds)} | {cells[0]} | {cells[1]} | "
                             f"{means[0] / means[1]:.2f} | {np.mean([r['seconds'] for r in ran]):.1f} | "
                             f"{tuner_cpu(ran)} | {mean_of(ran, 'activations')} | {twin_effects(ran)} |")
    return "\n".join(lines)


def tuner_cpu(runs: list[dict]) -> str:
    """``"mean [min, max]"`` of the tuner's CPU seconds per run (the run's minus the plant steps'), if logged."""
    if not all("cpu_seconds" in r for r in runs):
        return "-"
    cpu = np.array([r["cpu_seconds"] - r["plant_cpu_seconds"] for r in runs])
    return f"{cpu.mean():.1f} [{cpu.min():.1f}, {cpu.max():.1f}]"


def mean_of(runs: list[dict], key: str) -> str:
    """Mean of a logged count over the runs, ``"-"`` where a run has none."""
    values = [r.get(key) for r in runs]
    return "-" if any(v is None for v in values) else f"{np.mean(values):.1f}"


def twin_effects(runs: list[dict]) -> str:
    """The twin's effects at the end of each run (``linear`` for none), with their counts, if logged
    (``-`` for a tuner without a twin, which reports no activations)."""
    if not all("effects" in r and r.get("activations") is not None for r in runs):
        return "-"
    return effects_column("+".join(r["effects"]) or "linear" for r in runs)


def plot_traces(runs: list[dict], before: str, after: str, level: float = 1.05) -> Path | None:
    """Ratio traces of the runs ``before`` missed at ``level``, with ``after``'s runs on the same plant and seeds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    missed = [r for r in runs if r["variant"] == before and min(r["ratios"]) > level]
    if not missed:
        return None
    by_key = {(r["plant"], r["variant"], r["seed"]): r for r in runs}
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, variant in zip(axes, (before, after)):
        for r in missed:
            run = by_key.get((r["plant"], variant, r["seed"]))
            if run is not None:
                ax.plot(np.arange(1, len(run["ratios"]) + 1), run["ratios"], label=f"{r['plant']} seed {r['seed']}")
        ax.axhline(level, color="k", ls="--", lw=0.8)
        ax.set(title=variant, xlabel="real experiments (-)", ylim=(0.98, 1.6))
    axes[0].set_ylabel("best optimality ratio J / J* (-)")
    axes[1].legend(fontsize=7)
    fig.suptitle(f"Runs that '{before}' missed at ratio {level}, and '{after}' on the same seeds")
    path = RESULTS / "guided_bo_misses.png"
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    study_arguments(parser, VARIANTS, ["DCMotor-v0"], seeds=30, workers=2)
    parser.add_argument("--traces", nargs=2, metavar=("BEFORE", "AFTER"), choices=list(VARIANTS),
                        help="plot the runs BEFORE missed at ratio 1.05 next to AFTER's on the same seeds")
    args = parser.parse_args()
    runs = study_runs(RUNS, run_one, args)
    table = summarise(runs)
    (RESULTS / "guided_bo_ablation.md").write_text(
        "Real experiments to each optimality ratio, mean [95 % CI] (misses; a miss counts as budget + 1), "
        "each variant against bo on the seeds both ran (benchmarks/guided_bo_ablation.py).\n\n" + table + "\n")
    print(table)
    if args.traces:
        print(plot_traces(runs, *args.traces) or f"'{args.traces[0]}' missed no run")


if __name__ == "__main__":
    main()
