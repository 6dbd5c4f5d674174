"""``gbo twin``: compare a twin with measured data, analyse its residuals, diagnose the missing effect, report.

::

    gbo twin compare  DATA.csv [--effects saturation,coulomb_friction] [--out DIR] [--json]
    gbo twin resid    DATA.csv [--effects ...] [--out DIR] [--json]
    gbo twin diagnose DATA.csv [--effects ...] [--json]
    gbo twin report   DATA.csv --out DIR [--effects ...] [--max-steps N]

Every command also takes ``--y-unit``/``--u-unit`` (units in the printout) and
``--quiet`` (no progress bar; without it a bar goes to stderr when stderr is a
terminal). ``DATA.csv`` has the header ``experiment,t,r,u,y`` (extra columns
allowed; experiments numbered from 1); see :mod:`agents.twin.csvio`.
``compare`` writes its plot to ``out/twin/<data name>/`` unless ``--out`` says
where, and prints the path. ``diagnose --json`` prints exactly one JSON object
on stdout. Bad data exits with status 2 and one line naming the file, and the
row and column, or the experiment, where one is at fault.

The commands' arguments are declared in :mod:`evaluation.twin_parser`; this module runs them.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import warnings
from pathlib import Path

from agents.jsonable import to_json
from agents.run_display import progress_bar
from agents.twin.csvio import read_csv
from agents.twin.fits import fit_structure
from agents.twin.identify import check_orders
from agents.twin.ladder_text import advice, number, unobservable_lines
from agents.twin.model import ModelSpec, effect_items
from agents.twin.ranking import ORDER_RULE
from agents.twin.record_checks import NonCausalRecordWarning, check_poles
from agents.twin.records import Batch
from agents.twin.report import compare_figure, residual_figure, write_report
from agents.twin.static_map import MAP_NAMES
from agents.twin.workbench import compare, diagnose, error_ladder, residuals
from evaluation.figures import save
from gbo_envs.physics import EFFECT_NAMES

__all__ = ["default_out"]


def _progress(args):
    """The ``progress`` of the library calls: off under ``--quiet``, else on when stderr is a terminal."""
    return False if args.quiet else None


def _units(args) -> dict:
    return {key: value for key, value in (("y", args.y_unit), ("u", args.u_unit)) if value}


def _y_unit(args) -> str:
    """Unit of ``y`` in printouts and on plots: ``--y-unit``, else "units of y" (a CSV does not say)."""
    return args.y_unit or "units of y"


def _u_unit(args) -> str:
    """Unit of ``u`` in printouts and on plots: ``--u-unit``, else "input units"."""
    return args.u_unit or "input units"


def _load(args):
    records = read_csv(args.data)
    data = Batch.from_records(records, initial=args.initial)  # experiment index = the CSV's experiment id
    spec = ModelSpec(args.poles, args.zeros, args.integrators, args.output)
    effects = [e.strip() for e in args.effects.split(",") if e.strip()]
    return data, spec, effects


def _fit(data, spec, effects):
    """The grey-box fit of ``spec``'s linear part plus ``effects``: what :class:`agents.twin.GreyBoxTwin` fits
    (:func:`agents.twin.fits.fit_structure`), without loading scikit-learn."""
    check_orders(spec.n_poles, spec.n_zeros, spec.n_integrators)
    return fit_structure(data, effects, spec)


def _run(handler):
    """The handler without the fitting's numerical warnings; bad input ends in :func:`evaluation.cli.main`.

    ``--effects`` and ``--poles`` are checked first, so that every ``ValueError`` after them is about the
    data: it is raised again naming the file (:func:`_naming_the_file`). A warning that the records are
    not causal (:class:`~agents.twin.record_checks.NonCausalRecordWarning`) is printed on stderr.
    """
    def wrapped(args: argparse.Namespace) -> int:
        _check_effects(args.effects)
        check_poles(args.poles)  # an argument's error, not the file's
        try:
            with warnings.catch_warnings(record=True) as caught, _naming_the_file(args.data):
                warnings.simplefilter("ignore")
                warnings.simplefilter("always", NonCausalRecordWarning)  # about the data: said, on stderr
                return handler(args)
        finally:
            for text in dict.fromkeys(str(w.message).removeprefix("records: ") for w in caught
                                      if issubclass(w.category, NonCausalRecordWarning)):
                print(f"gbo twin {args.twin_command}: warning: {args.data}: {text}", file=sys.stderr)

    return wrapped


def _check_effects(effects: str) -> None:
    names = [e.partition(":")[0].strip() for e in effects.split(",") if e.strip()]
    unknown = [e for e in names if e not in EFFECT_NAMES and e not in MAP_NAMES]
    if unknown:
        raise ValueError(f"--effects: unknown effect {unknown[0]!r}; the catalogue is {', '.join(EFFECT_NAMES)}; "
                         f"the static maps are {', '.join(MAP_NAMES)}")
    twice = [e for i, e in enumerate(names) if e in names[:i]]
    if twice:
        raise ValueError(f"--effects: {twice[0]!r} is named twice; each catalogue effect may be in the model once")
    try:
        effect_items(effects)  # the variants (coulomb_friction:smooth)
    except ValueError as error:
        raise ValueError(f"--effects: {str(error).removeprefix('effects: ')}") from None


@contextlib.contextmanager
def _naming_the_file(path: str):
    """A ``ValueError`` of the data (the records, their fit) raised again as ``PATH: message``.

    The CSV reader names the file, row and column itself; the twin's checks of the records
    ("records: the input u is constant in every experiment ...") do not know the file.
    """
    try:
        yield
    except UnicodeDecodeError:
        raise  # the reader's: evaluation.cli_args.error_message names the codec and the byte
    except ValueError as exc:
        text = str(exc)
        if text.startswith(str(path)):
            raise
        text = text.removeprefix("records: ")  # the records are the file's
        raise ValueError(f"{path}: {text}") from exc


def _print_unobservable(result) -> None:
    """The effects ``result`` (a diagnosis) finds unobservable, one line each, if any."""
    lines = unobservable_lines(result)
    if lines:
        print("not observable in this data:")
        for line in lines:
            print(f"  {line}")


def default_out(data_path: str) -> Path:
    """Where ``gbo twin compare`` writes its plots without ``--out``: ``out/twin/<data file name>``."""
    return Path("out") / "twin" / Path(data_path).stem


def _load_and_fit(args, bar):
    """Read the data and fit the model, one step of ``bar`` each; returns ``(data, fit)``."""
    bar.set_postfix_str("reading the data")
    data, spec, effects = _load(args)
    bar.update(1)
    bar.set_postfix_str("fitting " + "+".join([spec.label, *effects]))
    fit = _fit(data, spec, effects)
    bar.update(1)
    return data, fit


@_run
def _compare(args) -> int:
    bar = progress_bar(3, "twin compare", _progress(args), unit="step")
    try:
        data, fit = _load_and_fit(args, bar)
        res = compare(data, fit)  # experiments numbered from 1, as in the CSV
        bar.set_postfix_str("plotting")
        out = Path(args.out) if args.out else default_out(args.data)
        plot = save(compare_figure(data, [fit], y_unit=_y_unit(args)), out / "compare.png", dpi=100)  # atomic
        bar.update(1)
    finally:
        bar.close()
    if args.json:
        payload = res.to_dict()
        payload["params"] = fit.effect_params
        payload["plots"] = [str(plot)]
        print(to_json(payload, finite=True, sort_keys=False))
        return 0
    y = _y_unit(args)
    print(f"model {res.model}: fit {res.fit_percent_all:.2f} %, RMSE {res.rmse_all:.5g} {y}")
    if fit.effect_params:
        print("effect parameters: " + json.dumps(fit.effect_params))
    print(f"{'experiment':>10} {'fit %':>8} {'RMSE':>10}")
    for e, f, r in zip(res.experiments, res.fit_percent, res.rmse):
        print(f"{e:>10d} {f:8.2f} {r:10.4g}")
    print(f"plots: {plot}")
    return 0


@_run
def _resid(args) -> int:
    bar = progress_bar(3, "twin resid", _progress(args), unit="step")
    try:
        data, fit = _load_and_fit(args, bar)
        bar.set_postfix_str("residual analysis")
        ra = residuals(data, fit)
        if args.out:
            save(residual_figure(ra, fit.spec.label, y_unit=_y_unit(args), u_unit=_u_unit(args)),
                 Path(args.out) / "residuals.png", dpi=100)
        bar.update(1)
    finally:
        bar.close()
    if args.json:
        payload = ra.to_dict()
        payload["model"] = fit.spec.label
        print(to_json(payload, finite=True, sort_keys=False))
        return 0
    print(f"model {fit.spec.label}: RMSE {fit.rmse:.5g} {_y_unit(args)}; 99 % band +-{ra.band:.3g}")
    outside = float((abs(ra.acf[1:]) > ra.band).mean())
    print(f"whiteness: {'white' if ra.white else 'NOT white'} ({100 * outside:.0f} % of acf lags outside)")
    peak = int(ra.ccf_lags[abs(ra.ccf).argmax()])
    print(f"input cross-correlation: {'independent' if ra.independent else 'correlated'} "
          f"(peak {ra.ccf[abs(ra.ccf).argmax()]:.3f} at lag {peak})")
    for key, label in (("time", "time in experiment"), ("experiment", "experiment number"), ("input", "input level"),
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
    data, spec, effects = _load(args)
    result = diagnose(data, effects=effects, spec=spec, n_folds=args.folds, progress=_progress(args),
                      n_jobs=args.jobs)
    units = _units(args)
    step = result.step(result.best, units) if result.best is not None else None
    following = advice(result, result.current.spec.effect_labels, args.data, units=units)
    payload = result.to_dict()
    payload["best_step"] = step
    payload["next"] = following
    if args.json:
        print(to_json(payload, finite=True, sort_keys=False))
        return 0
    y = _y_unit(args)
    noise = payload["noise_rmse"]
    print(f"model {payload['model']}: RMSE {payload['rmse']:.4g} {y}, fit {payload['fit_percent']:.2f} % "
          f"(fit to all data); held-out RMSE {payload['heldout_rmse']:.4g} {y}")
    for line in data.initial.describe(data.numbers):
        print(f"starts: {line}")
    print(f"{result.noise_label}: {number(noise)} {y}")
    print(f"ranking ({payload['validation']}); {ORDER_RULE}:")
    width = max(len("verdict"), *(len(c["verdict"]) for c in payload["candidates"]))
    print(f"{'effect':>18} {'verdict':<{width}} {'held-out RMSE':>14} {'delta BIC':>10}  evidence")
    print(f"{'':>18} {'':<{width}} {f'({y})':>14} {'(-)':>10}")
    for c in payload["candidates"]:
        print(f"{c['effect']:>18} {c['verdict']:<{width}} {number(c['rmse'], 5):>14} {c['delta_bic']:10.1f}  "
              f"{c['evidence']}")
    print(f"best: {step['text']}" if step else "best: none (no effect improves the held-out error beyond its "
                                               "complexity cost)")
    if result.not_tried:
        print(result.not_tried)
    _print_unobservable(result)
    for a, b in payload["indistinguishable"]:
        print(f"indistinguishable on this data: {a} and {b}")
    if payload["suggested_experiment"]:
        print(f"suggested experiment: {payload['suggested_experiment']}")
    print(following)
    return 0


@_run
def _report(args) -> int:
    data, spec, effects = _load(args)
    rungs, diagnoses = error_ladder(data, effects=effects, spec=spec, max_steps=args.max_steps,
                                    progress=_progress(args), units=_units(args), n_jobs=args.jobs)
    fits = [diagnoses[0].current] + ([diagnoses[-1].current] if len(diagnoses) > 1 else [])
    analyses = [residuals(data, f) for f in fits]
    path = write_report(args.out, data, rungs, diagnoses, analyses, source=str(args.data), y_unit=_y_unit(args),
                        u_unit=_u_unit(args))
    last = diagnoses[-1]
    y = _y_unit(args)
    print("error ladder (RMSE and fit % of the fit to all data; held-out RMSE ranks the effects):")
    for r in rungs:
        print(f"  {r['text']}; held-out RMSE {r['heldout_rmse']:.4g} {y}")
    print(f"{last.noise_label}: {number(last.noise_rmse)} {y}")
    _print_unobservable(last)
    print(advice(last, last.current.spec.effect_labels, args.data,
                 stopped_at_max=last.best is not None, units=_units(args)))
    print(f"report: {path}")
    return 0
