"""A shipped suite reference against a study's kept runs of the same tuner, on the seeds both hold.

The suite's references (``evaluation/references/<tuner>.parquet``) and a study's committed curves
(``docs/reports/<study>/curves.parquet``) hold runs of the same tuner on the same plant, seed, budget
and target when the plant labels agree. After a rebuild of the reference on new code this says
whether the study's figures still hold: per plant the real experiments to the target (1.01 on the
linear motors, else 1.05), mean with a 95 % Student-t interval and the misses, for the kept runs and
the reference's, the paired difference (reference - study) with its 95 % interval, the runs whose
curves agree within 1e-9 relative, and the tuner CPU per run (run CPU minus the plant's steps) of
both where the curves record it::

    python benchmarks/reference_vs_study.py --tuner guided-bo
    python benchmarks/reference_vs_study.py --tuner bo --study guided_bo_ablation

``--runs FOLDER`` takes the runs of a study's output folder (``gbo bench SPEC --out FOLDER``, with the
``study.toml`` it writes there) in place of the reference: a rerun of a few plants on new code::

    python benchmarks/reference_vs_study.py --tuner guided-bo --runs out/lin_probe
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from evaluation.curves import CURVES_FILE, experiments_to_target, load_curves, read_curves
from evaluation.leaderboard import mean_interval
from evaluation.study import load_study

REPO = Path(__file__).resolve().parents[1]


def _cpu(runs) -> str:
    cpu = (runs["cpu_seconds"] - runs["plant_cpu_seconds"]).to_numpy(dtype=float)
    return "-" if np.isnan(cpu).all() else f"{np.nanmean(cpu):.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tuner", required=True, help="the tuner's label in both (e.g. guided-bo, bo)")
    parser.add_argument("--study", default="guided_bo_ablation", help="a study folder under docs/reports")
    parser.add_argument("--runs", type=Path, help="a study's output folder whose runs replace the reference")
    args = parser.parse_args()
    kept = read_curves(REPO / "docs" / "reports" / args.study / CURVES_FILE)
    kept = kept[kept["tuner"] == args.tuner]
    if args.runs is None:
        reference = read_curves(REPO / "evaluation" / "references" / f"{args.tuner}.parquet")
    else:
        reference = load_curves(args.runs, load_study(args.runs / "study.toml"))
        reference = reference[reference["tuner"] == args.tuner]
    print(f"| plant | target | seeds | {args.study} | reference | paired | same curve | tuner CPU s/run: study, "
          "reference |")
    print("|---|---|---|---|---|---|---|---|")
    for plant in kept["plant"].unique():
        old = kept[kept["plant"] == plant].set_index("seed")
        new = reference[reference["plant"] == plant].set_index("seed")
        seeds = sorted(set(old.index) & set(new.index))
        if len(seeds) < 2:
            continue
        target = 1.01 if "Linear" in plant else 1.05
        budget = int(old.loc[seeds[0], "budget"])
        counts = [np.array([experiments_to_target(runs.loc[s, "curve"], target) for s in seeds], dtype=float)
                  for runs in (old, new)]
        cells = []
        for x in counts:
            mean, low, high = mean_interval(x)
            cells.append(f"{mean:.1f} [{low:.1f}, {high:.1f}] ({int((x > budget).sum())})")
        diff, _, high = mean_interval(counts[1] - counts[0])
        half = high - diff
        same = sum(np.allclose(new.loc[s, "curve"], old.loc[s, "curve"], rtol=1e-9, atol=0.0) for s in seeds)
        print(f"| {plant} | {target} | {len(seeds)} | {cells[0]} | {cells[1]} | {diff:+.2f} +- {half:.2f} | {same} | "
              f"{_cpu(old.loc[seeds])}, {_cpu(new.loc[seeds])} |")


if __name__ == "__main__":
    main()
