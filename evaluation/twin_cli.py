"""``gbo twin``: compare a twin with measured data, analyse its residuals, diagnose the missing effect, report.

::

    gbo twin compare  DATA.csv [--effects saturation,coulomb_friction] [--out DIR] [--json]
    gbo twin resid    DATA.csv [--effects ...] [--out DIR] [--json]
    gbo twin diagnose DATA.csv [--effects ...] [--json]
    gbo twin report   DATA.csv --out DIR [--effects ...]

``DATA.csv`` has the header ``experiment,t,r,u,y`` (extra columns allowed);
see :mod:`agents.twin.csvio`. ``diagnose --json`` prints exactly one JSON
object on stdout. Bad data exits with status 2 and a message naming the row
and the column.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

__all__ = ["add_parser"]


def add_parser(subparsers) -> None:
    """Add ``twin`` with its sub-commands to the ``gbo`` sub-command parsers."""
    twin = subparsers.add_parser("twin", help="twin workbench: compare, residuals, diagnose, report",
                                 description="Compare a digital twin with measured closed-loop data "
                                             "(CSV: experiment,t,r,u,y), see where it fails and which physical "
                                             "effect it misses.")
    sub = twin.add_subparsers(dest="twin_command", required=True)

    def common(p):
        p.add_argument("data", help="CSV with the columns experiment,t,r,u,y")
        p.add_argument("--effects", default="", help="effects of the current model, comma-separated catalogue "
                                                      "names (default: the linear model alone)")
        p.add_argument("--poles", type=int, default=2, help="poles of the linear part (default 2)")
        p.add_argument("--zeros", type=int, default=0, help="zeros of the linear part (default 0)")
        p.add_argument("--integrators", type=int, default=0, help="poles at s = 0 (default 0; 1 for a position loop)")
        p.add_argument("--output", choices=("speed", "position"), default="speed",
                       help="what y measures (friction acts on y or on dy/dt; default speed)")

    p = sub.add_parser("compare", help="fit %% and RMSE per experiment, overlay plots")
    common(p)
    p.add_argument("--out", default=None, help="folder for compare.png")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(handler=_compare)
    p = sub.add_parser("resid", help="residual whiteness, input cross-correlation and where the model fails")
    common(p)
    p.add_argument("--out", default=None, help="folder for residuals.png")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(handler=_resid)
    p = sub.add_parser("diagnose", help="rank every catalogued effect as an addition to the model")
    common(p)
    p.add_argument("--json", action="store_true", help="print exactly one JSON object")
    p.add_argument("--folds", type=int, default=4, help="folds of the cross-validation over experiments")
    p.set_defaults(handler=_diagnose)
    p = sub.add_parser("report", help="self-contained HTML report with the error ladder")
    common(p)
    p.add_argument("--out", required=True, help="output folder (index.html)")
    p.add_argument("--max-steps", type=int, default=3, help="effects added at most (default 3)")
    p.set_defaults(handler=_report)


def _load(args):
    from agents.twin.csvio import read_csv
    from agents.twin.greybox import GreyData, ModelSpec

    records = read_csv(args.data)
    data = GreyData.from_records(records)  # experiment index = the CSV's experiment id
    ids = [r.index for r in records]  # the records themselves are not kept: GreyData holds their signals
    spec = ModelSpec(args.poles, args.zeros, args.integrators, args.output)
    effects = [e.strip() for e in args.effects.split(",") if e.strip()]
    return ids, data, spec, effects


def _fit(data, spec, effects):
    """The grey-box fit (:class:`agents.twin.GreyBoxTwin`) of ``spec``'s linear part plus ``effects``."""
    from agents.twin.workbench import GreyBoxTwin

    twin = GreyBoxTwin(effects=effects, n_poles=spec.n_poles, n_zeros=spec.n_zeros, n_integrators=spec.n_integrators,
                       output=spec.output)
    return twin.fit(data).greybox_


def _run(handler):
    def wrapped(args: argparse.Namespace) -> int:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                return handler(args)
            except (ValueError, FileNotFoundError) as exc:
                print(f"gbo twin {args.twin_command}: error: {exc}", file=sys.stderr)
                return 2

    return wrapped


@_run
def _compare(args) -> int:
    from agents.jsonable import to_json
    from agents.twin.workbench import compare

    ids, data, spec, effects = _load(args)
    fit = _fit(data, spec, effects)
    res = compare(data, fit, experiments=ids)
    if args.out:
        from agents.twin.report import compare_figure

        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        compare_figure(data, [fit]).savefig(out / "compare.png", dpi=100)
    if args.json:
        payload = res.to_dict()
        payload["params"] = fit.effect_params
        print(to_json(payload, finite=True, sort_keys=False))
        return 0
    print(f"model {res.model}: fit {res.fit_percent_all:.2f} %, RMSE {res.rmse_all:.5g} (units of y)")
    if fit.effect_params:
        print("effect parameters: " + json.dumps(fit.effect_params))
    print(f"{'experiment':>10} {'fit %':>8} {'RMSE':>10}")
    for e, f, r in zip(res.experiments, res.fit_percent, res.rmse):
        print(f"{e:>10d} {f:8.2f} {r:10.4g}")
    return 0


@_run
def _resid(args) -> int:
    from agents.jsonable import to_json
    from agents.twin.workbench import residuals

    _, data, spec, effects = _load(args)
    fit = _fit(data, spec, effects)
    ra = residuals(data, fit)
    if args.out:
        from agents.twin.report import residual_figure

        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        residual_figure(ra, fit.spec.label).savefig(out / "residuals.png", dpi=100)
    if args.json:
        payload = ra.to_dict()
        payload["model"] = fit.spec.label
        print(to_json(payload, finite=True, sort_keys=False))
        return 0
    print(f"model {fit.spec.label}: RMSE {fit.rmse:.5g}; 99 % band +-{ra.band:.3g}")
    outside = float((abs(ra.acf[1:]) > ra.band).mean())
    print(f"whiteness: {'white' if ra.white else 'NOT white'} ({100 * outside:.0f} % of acf lags outside)")
    peak = int(ra.ccf_lags[abs(ra.ccf).argmax()])
    print(f"input cross-correlation: {'independent' if ra.independent else 'correlated'} "
          f"(peak {ra.ccf[abs(ra.ccf).argmax()]:.3f} at lag {peak})")
    for key, label in (("time", "time in experiment"), ("experiment", "experiment index"), ("input", "input level"),
                       ("output", "output level"), ("velocity_sign", "sign of velocity")):
        b = ra.bins[key]
        cells = ", ".join(f"{c:.4g}: {r:.3g}" for c, r in zip(b["centers"], b["rms"]))
        print(f"residual rms vs {label}: {cells}")
    print("worst segments:")
    for w in ra.worst:
        print(f"  experiment {w['experiment']}, t = {w['t_start']:.4g}..{w['t_end']:.4g} s: rms {w['rms']:.4g}, "
              f"mean {w['mean']:.4g}")
    return 0


@_run
def _diagnose(args) -> int:
    from agents.jsonable import to_json
    from agents.twin.workbench import diagnose

    _, data, spec, effects = _load(args)
    result = diagnose(data, effects=effects, spec=spec, n_folds=args.folds)
    payload = result.to_dict()
    if args.json:
        print(to_json(payload, finite=True, sort_keys=False))
        return 0
    noise = payload["noise_rmse"]
    print(f"model {payload['model']}: RMSE {payload['rmse']:.5g}, fit {payload['fit_percent']:.2f} %, "
          f"held-out RMSE {payload['heldout_rmse']:.5g}; noise floor {'n/a' if noise is None else f'{noise:.4g}'}")
    print(f"ranking ({payload['validation']}):")
    print(f"{'effect':>18} {'held-out RMSE':>14} {'delta BIC':>12}  evidence")
    for c in payload["candidates"]:
        print(f"{c['effect']:>18} {c['rmse']:14.5g} {c['delta_bic']:12.1f}  {c['evidence']}")
    print(f"best: {payload['best']}" + ("" if payload["best"] is None else
                                         f" with {json.dumps(payload['candidates'][0]['params'])}"))
    for a, b in payload["indistinguishable"]:
        print(f"indistinguishable on this data: {a} and {b}")
    if payload["suggested_experiment"]:
        print(f"suggested experiment: {payload['suggested_experiment']}")
    return 0


@_run
def _report(args) -> int:
    from agents.twin.report import write_report
    from agents.twin.workbench import error_ladder, residuals

    _, data, spec, effects = _load(args)
    rungs, diagnoses = error_ladder(data, effects=effects, spec=spec, max_steps=args.max_steps)
    fits = [diagnoses[0].current] + ([diagnoses[-1].current] if len(diagnoses) > 1 else [])
    analyses = [residuals(data, f) for f in fits]
    path = write_report(args.out, data, rungs, diagnoses, analyses, source=str(args.data))
    for r in rungs:
        print(f"{r['model']:>40}: RMSE {r['rmse']:.5g} (held-out {r['heldout_rmse']:.5g})")
    print(f"report: {path}")
    return 0
