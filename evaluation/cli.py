"""The ``gbo`` command line: ``gbo demo``, and the sub-commands of later modules.

Each sub-command lives in its own module with an ``add_parser(subparsers)``
function; this file only wires them together.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

__all__ = ["main"]

#: Modules that contribute sub-commands through ``add_parser(subparsers)``.
SUBCOMMAND_MODULES: tuple[str, ...] = ("evaluation.bench_cli", "evaluation.tune_cli", "evaluation.twin_cli")


def _demo(args: argparse.Namespace) -> int:
    from evaluation.demo import run_demo

    run_demo(Path(args.out), env_id=args.env, seed=args.seed, budget=args.budget, tuners=not args.no_tuners,
             progress=False if args.quiet else None)
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``gbo`` argument parser with every available sub-command."""
    parser = argparse.ArgumentParser(prog="gbo", description="Data-efficient controller tuning with guided BO.",
                                     epilog="Example:\n  gbo demo\n  gbo tune --budget 20 && gbo export --csv "
                                            "out/run.csv && gbo twin diagnose out/run.csv",
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="ground truth, figures and a short tuning run on the default plant",
                          description="Compute the ground-truth cost surface of a plant, plot it, and tune it "
                                      "briefly with each available tuner.",
                          epilog="Example:\n  gbo demo --out out/demo --budget 10",
                          formatter_class=argparse.RawDescriptionHelpFormatter)
    demo.add_argument("--out", default="out/demo", help="output folder for the PNGs (default: out/demo)")
    demo.add_argument("--env", default="gbo_envs/DCMotor-v0", help="env id (default: gbo_envs/DCMotor-v0)")
    demo.add_argument("--seed", type=int, default=0, help="seed of the tuning runs (default: 0)")
    demo.add_argument("--budget", type=int, default=20, help="plant experiments per tuner (default: 20)")
    demo.add_argument("--no-tuners", action="store_true", help="only the ground truth and its figures")
    demo.add_argument("--quiet", action="store_true", help="no progress bars (default: on stderr when a terminal)")
    demo.set_defaults(handler=_demo)
    for module in SUBCOMMAND_MODULES:
        try:
            importlib.import_module(module).add_parser(sub)
        except ImportError as exc:  # an optional extra is missing: say so instead of hiding the command
            sub.add_parser(module.rsplit(".", 1)[-1], help=f"unavailable: {exc}")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``gbo`` script."""
    import gbo_envs  # noqa: F401  (registers the envs)

    args = build_parser().parse_args(argv)
    if not hasattr(args, "handler"):
        print(f"gbo {args.command}: this command needs an optional extra; see README", file=sys.stderr)
        return 2
    return int(args.handler(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
