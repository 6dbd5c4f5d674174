"""The error ladder: the linear model, then the best effect added, then the next, until nothing helps.

Each rung is a :func:`~agents.twin.diagnose.diagnose` of the model of the rung before, and
records the model, the effect added, the RMSE, fit %, held-out RMSE and the fitted
parameters, in numbers and in words (:mod:`agents.twin.ladder_text`).
"""

from __future__ import annotations

from collections.abc import Mapping

from agents.jsonable import jsonable
from agents.run_display import progress_bar
from agents.twin.diagnose import Diagnosis, as_step, diagnose
from agents.twin.fits import fit_structure
from agents.twin.ladder_text import rung_text
from agents.twin.model import ModelSpec
from agents.twin.records import Batch

__all__ = ["error_ladder"]


def error_ladder(data: Batch, effects=None, spec: ModelSpec | None = None, max_steps: int = 3,
                 progress: bool | None = False, units: Mapping[str, str] | None = None,
                 **kwargs) -> tuple[list[dict], list[Diagnosis]]:
    """RMSE of the linear model, then with the best effect added, then the next, until nothing helps.

    Parameters
    ----------
    data : Batch
    effects : names or ``{name: {parameter: value}}``, optional
        Effects of the first model (default: the linear model alone).
    spec : ModelSpec, optional
    max_steps : int, default 3
        Effects added at most.
    progress : bool or None, default False
        Progress bars on stderr (the rungs, and each diagnosis nested in it); ``None``: only on a terminal.
    units : mapping, optional
        ``{"y": ..., "u": ...}``, the units of the output and input, for the ``text`` of each rung.
    **kwargs
        Passed to :func:`diagnose`.

    Returns
    -------
    rungs : list of dict
        Per rung: ``"model", "added", "rmse", "fit_percent", "heldout_rmse", "params"``; from the
        second rung on also ``"before"`` (the previous rung's ``model, rmse, fit_percent,
        heldout_rmse``), ``"rmse_fall_percent"`` (``100 (1 - rmse / before rmse)``), ``"rmse_factor"``
        (``before rmse / rmse``) and ``"added_params"`` (the added effect's parameters with
        their standard errors, 95 % intervals and units, :func:`effect_intervals`); and ``"text"``,
        the rung in words (:func:`agents.twin.ladder_text.rung_text`). RMSE and fit % are those of
        the fit to all data, in units of ``y`` and %.
    diagnoses : list of Diagnosis
        The diagnosis made at each rung.
    """
    spec = ModelSpec() if spec is None else spec
    current = fit_structure(data, effects, spec)
    rungs, diagnoses = [], []
    added = None
    bar = progress_bar(max_steps + 1, "error ladder", progress, unit="rung")
    try:
        for _ in range(max_steps + 1):
            bar.set_postfix_str(current.spec.label)
            d = diagnose(data, current=current, progress=progress, _nested=True, **kwargs)
            diagnoses.append(d)
            rung = {"model": d.current.spec.label, "added": added, "rmse": float(d.current.rmse),
                    "fit_percent": float(d.fit_percent), "heldout_rmse": float(d.heldout_rmse),
                    "params": jsonable(d.current.effect_params, finite=True)}
            if rungs:
                before = {key: rungs[-1][key] for key in ("model", "rmse", "fit_percent", "heldout_rmse")}
                intervals = next(c["intervals"] for c in diagnoses[-2].candidates if c["effect"] == added)
                rung = as_step(rung, before, added, intervals, units, d.current.spec.output)
            else:
                rung["text"] = rung_text(rung, units, d.current.spec.output)
            rungs.append(rung)
            bar.update(1)
            if d.best is None or len(rungs) > max_steps:
                bar.total = len(rungs)  # nothing more to add: the ladder is complete
                bar.refresh()
                break
            added, current = d.best, d.fits[d.best]
    finally:
        bar.close()
    return rungs, diagnoses
