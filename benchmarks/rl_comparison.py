"""RL (on the plant and trained on the nominal model) against BO and guided BO, in real experiments.

Reports, per env and method, the plant experiments needed to reach optimality
ratio 1.1 and 1.05 (``phi = J_true(best measured gains) / J(theta*)``); a run
that never gets there is counted as ``budget + 1`` and the table says so.
Prints the Markdown table, then the whole study as one JSON line (last line).

Usage::

    python benchmarks/rl_comparison.py --seeds 3 --budget 50
    python benchmarks/rl_comparison.py --seeds 10 --budget 50 --rl-budget 100 --checkpoint out/rl_runs.jsonl

Ctrl-C stops it and prints what finished; ``--checkpoint`` resumes later.
"""

from __future__ import annotations

import argparse
import json

from agents.rl.study import STUDY_ENV_IDS, default_methods, markdown_table, rl_comparison


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="*", default=list(STUDY_ENV_IDS), help="env ids (unregistered are skipped)")
    parser.add_argument("--seeds", type=int, default=3, help="seeds 0 .. N-1")
    parser.add_argument("--budget", type=int, default=50, help="plant experiments per BO / guided-BO run")
    parser.add_argument("--rl-budget", type=int, default=None, help="plant experiments per RL run (default: --budget)")
    parser.add_argument("--pretrain-steps", type=int, default=2000, help="model experiments of train-on-twin RL")
    parser.add_argument("--ppo", action="store_true", help="add PPO (plant mode)")
    parser.add_argument("--checkpoint", default=None, help="JSON-lines file of finished runs (resume)")
    parser.add_argument("--resolution", type=int, default=100, help="ground-truth grid points per gain")
    args = parser.parse_args(argv)
    methods = default_methods(budget=args.budget, rl_budget=args.rl_budget, pretrain_steps=args.pretrain_steps,
                              include_ppo=args.ppo)
    study = rl_comparison(env_ids=args.envs, seeds=range(args.seeds), methods=methods, checkpoint=args.checkpoint,
                          ground_truth_resolution=args.resolution)
    print(markdown_table(study))
    print(json.dumps(study))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
