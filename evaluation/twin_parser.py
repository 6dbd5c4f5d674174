"""The arguments of ``gbo twin compare|resid|diagnose|report`` (see :mod:`evaluation.twin_cli`).

The handlers, named here and imported when their command runs (:class:`evaluation.cli_args.Handler`), are
those of :mod:`evaluation.twin_cli`.
"""

from __future__ import annotations

import argparse

from evaluation.cli_args import Handler, int_at_least, job_count, positive_int

__all__ = ["add_parser"]


def add_parser(subparsers) -> None:
    """Add ``twin`` with its sub-commands to the ``gbo`` sub-command parsers."""
    raw = argparse.RawDescriptionHelpFormatter
    twin = subparsers.add_parser("twin", help="twin workbench: compare, residuals, diagnose, report",
                                 description="Compare a digital twin with measured closed-loop data "
                                             "(CSV: experiment,t,r,u,y), see where it fails and which physical "
                                             "effect it misses.",
                                 epilog="Examples:\n  gbo twin compare data.csv\n  gbo twin diagnose data.csv\n"
                                        "  gbo twin report data.csv --out out/twin/report",
                                 formatter_class=raw)
    sub = twin.add_subparsers(dest="twin_command", required=True)

    def common(p):
        p.add_argument("data", help="CSV with the columns experiment,t,r,u,y (experiments numbered from 1)")
        p.add_argument("--effects", default="", help="effects of the current model, comma-separated catalogue "
                                                      "names (default: the linear model alone)")
        p.add_argument("--poles", type=positive_int, default=2, help="poles of the linear part (default 2)")
        p.add_argument("--zeros", type=int_at_least(0), default=0, help="zeros of the linear part (default 0)")
        p.add_argument("--integrators", type=int_at_least(0), default=0,
                       help="poles at s = 0 (default 0; 1 for a position loop)")
        p.add_argument("--output", choices=("speed", "position"), default="speed",
                       help="what y measures (friction acts on y or on dy/dt; default speed)")
        p.add_argument("--initial", choices=("auto", "rest", "zero", "steady"), default="auto",
                       help="how the experiments start: auto (default) detects it per experiment (at a rest the "
                            "data show, pinned; from standstill with the drive just on; or at an unshown rest, "
                            "estimated); rest: at the rest of the first sample; zero: at rest with u = 0 before "
                            "the record; steady: estimate every rest level and rest input")
        p.add_argument("--y-unit", default=None, help="unit of y for the printout, e.g. rad/s (default: units of y)")
        p.add_argument("--u-unit", default=None, help="unit of u for the printout, e.g. V (default: input units)")
        p.add_argument("--quiet", action="store_true",
                       help="no progress bar (without it, a bar on stderr when stderr is a terminal)")

    def jobs(p) -> None:
        p.add_argument("--jobs", type=job_count, default=-1,
                       help="worker processes for the fits (default -1: one per core; 1: none; the result is the "
                            "same)")

    def command(name: str, handler: str, out: str | None = None, json: str | None = "print JSON", **texts):
        """A subcommand with the common arguments, ``--out`` and ``--json`` (when ``out`` and ``json`` give their
        help), run by ``evaluation.twin_cli.<handler>``."""
        p = sub.add_parser(name, formatter_class=raw, **texts)
        common(p)
        if out is not None:
            p.add_argument("--out", default=None, help=out)
        if json is not None:
            p.add_argument("--json", action="store_true", help=json)
        p.set_defaults(handler=Handler(f"evaluation.twin_cli:{handler}"))
        return p

    p = command("compare", "_compare", help="fit %% and RMSE per experiment, overlay plots",
                description="Fit the model to the data and print fit %% and RMSE per experiment; the "
                            "overlay plot goes to out/twin/<data name>/compare.png unless --out says where.",
                epilog="Example:\n  gbo twin compare data.csv --effects saturation --out out/twin/sat",
                out="folder for compare.png (default: out/twin/<data name>)")
    p = command("resid", "_resid", help="residual whiteness, input cross-correlation and where the model fails",
                description="Residual analysis of the fitted model: whiteness, cross-correlation with the "
                            "input, residual RMS by time, experiment, input and output level.",
                epilog="Example:\n  gbo twin resid data.csv --effects saturation --out out/twin/sat",
                out="folder for residuals.png")
    p = command("diagnose", "_diagnose", help="rank every catalogued effect as an addition to the model",
                description="Try every catalogued effect as an addition to the model, rank them on held-out "
                            "experiments, list what the data cannot show, and say what to do next.",
                epilog="Examples:\n  gbo twin diagnose data.csv --y-unit rad/s --u-unit V\n"
                       "  gbo twin diagnose data.csv --effects saturation   # look for a second effect",
                json="print exactly one JSON object")
    p.add_argument("--folds", type=int_at_least(2), default=None,
                   help="folds of the cross-validation over experiments, 2 to the number of experiments "
                        "(default: 4, or one per experiment when there are fewer)")
    jobs(p)
    p = command("report", "_report", help="self-contained HTML report with the error ladder",
                description="Build the error ladder (add the best effect, diagnose again, until nothing "
                            "helps), print each step in words, and write one self-contained HTML page.",
                epilog="Example:\n  gbo twin report data.csv --out out/twin/report --y-unit rad/s --u-unit V",
                json=None)
    p.add_argument("--out", required=True, help="output folder (index.html)")
    p.add_argument("--max-steps", type=positive_int, default=3, help="effects added at most (default 3)")
    jobs(p)
