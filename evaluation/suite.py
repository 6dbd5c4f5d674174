"""``gbo bench suite``: one tuner on the benchmark suite, ranked against the shipped references.

The suite is the study ``evaluation/studies/suite.toml``: every registered env, the
effect plants of the guided-BO ablation and the time-varying envs, each at its target
optimality ratio (1.05 on the DC motors and the loops of 3 and 4 gains, 1.01 on the 2-gain
linear motors), 30 seeds, the env's episode length as budget; ``quick`` is its ``[suite]`` subset (3 plants, 3
seeds). :func:`run_suite` runs a tuner on it through the study engine
(:func:`evaluation.study_runner.run_study`: every finished run saved at once, a rerun
skips it, joblib or Dask), reads the reference tuners' shipped runs on the same plants
and seeds (:mod:`evaluation.references`; none is rerun) and writes the leaderboard
(:mod:`evaluation.leaderboard`).

Output (``OUT``, default ``out/suite``)::

    OUT/<tuner label>/results/*.parquet    the tuner's runs (one file per plant and seed)
    OUT/leaderboard.md, .csv, .html        the leaderboard; leaderboard_ecdf*.png its figures
    OUT/leaderboard.json                   what it was made from (suite, tuner, references' commits)
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import pandas as pd

from evaluation.curves import change_at, load_curves
from evaluation.leaderboard import Leaderboard, PlantTarget, write_leaderboard
from evaluation.references import REFERENCES_DIR, ReferenceSet, describe, load_references, suite_optima
from evaluation.study import Study, TunerEntry, load_study, slugify
from evaluation.study_runner import StudyRun, plan_batches, run_study

__all__ = ["SUITES", "SuiteResult", "load_suite", "plant_targets", "run_suite", "study_leaderboard", "tuner_study"]

#: The suites: the standard one and its quick subset.
SUITES = ("standard", "quick")
SUITE_STUDY = "suite"


def load_suite(suite: str = "standard") -> Study:
    """The suite study with its reference tuners: ``"standard"`` or ``"quick"`` (the ``[suite]`` subset)."""
    if suite not in SUITES:
        raise ValueError(f"--suite: expected one of {', '.join(SUITES)}, got {suite!r}")
    study = load_study(SUITE_STUDY)
    if suite == "quick":
        study = study.subset(plants=study.suite["quick_plants"], batches=study.suite["quick_batches"],
                             name=f"{study.name}-quick")
    return study


def tuner_study(suite: Study, tuner: str | TunerEntry, seeds: int | None = None, imports=()) -> Study:
    """The suite with one tuner entry (a registry name, or an entry with its label and kwargs) on all its plants,
    ``seeds`` seeds."""
    entry = tuner if isinstance(tuner, TunerEntry) else TunerEntry(name=tuner, label=tuner)
    entry = replace(entry, params=dict(entry.params), group=entry.label)
    study = suite.subset(tuners=(entry,), batches=seeds)
    return replace(study, imports=tuple(imports), name=f"{suite.name}-{slugify(entry.label)}")


def plant_targets(study: Study, budgets: dict[str, int]) -> list[PlantTarget]:
    """Each plant's target (its first threshold), budget and first counted experiment."""
    targets = []
    for plant in study.plants:
        thresholds = study.plant_thresholds(plant)
        if not thresholds or thresholds[0].ratio is None:
            raise ValueError(f"plants '{plant.label}': a suite plant needs a ratio as its first threshold")
        start = change_at(plant.env_id, plant.env_kwargs) or 0 if plant.phase == "after-change" else 0
        targets.append(PlantTarget(label=plant.label, target=thresholds[0].ratio, budget=budgets[plant.label],
                                   start=int(start)))
    return targets


@dataclass
class SuiteResult:
    """What :func:`run_suite` did.

    Attributes
    ----------
    run : StudyRun or None
        The tuner's runs (None with ``report_only``).
    leaderboard : Leaderboard or None
        None when the runs were interrupted or failed.
    references : ReferenceSet or None
    paths : dict
        The leaderboard's files.
    label : str
        The tuner's label in the leaderboard.
    """

    run: StudyRun | None
    leaderboard: Leaderboard | None = None
    references: ReferenceSet | None = None
    paths: dict = field(default_factory=dict)
    label: str = ""


def run_suite(tuner: str | TunerEntry, *, suite: str | Study = "standard", seeds: int | None = None, imports=(),
              out: Path | str = Path("out") / "suite", backend: str = "local", address: str | None = None,
              workers: int | None = None, progress: bool | None = False, references: Path | str = REFERENCES_DIR,
              report_only: bool = False, log=None) -> SuiteResult:
    """Run ``tuner`` on the suite (resuming its finished runs) and write the leaderboard with the references.

    Parameters
    ----------
    tuner : str or TunerEntry
        Registry name (:func:`agents.make`; a tuner of your own module once ``imports`` registered it), its
        leaderboard label too; or a :class:`~evaluation.study.TunerEntry` with the name, the label and the
        constructor keyword arguments (``TunerEntry(name="bo", label="bo n0=3", params={"n_initial": 3})``).
    suite : {"standard", "quick"} or Study
        The suite, or a study of several plants with its reference tuners in the suite's format (some of the
        suite's plants: ``load_suite("standard").subset(plants=["DCMotorPID-v0"])``).
    seeds : int, optional
        Seeds per plant (default: the suite's, 30 or 3).
    imports : sequence of str
        Modules imported first, in this process and in every worker (found as ``python -m`` finds them).
    out : Path
        Output folder.
    backend, address, workers, progress, log
        As :func:`evaluation.study_runner.run_study`.
    references : Path
        Folder of the reference results.
    report_only : bool
        Only write the leaderboard from the runs already saved.

    Returns
    -------
    SuiteResult
    """
    log = log or (lambda message: print(message, file=sys.stderr))
    out = Path(out)
    base = suite if isinstance(suite, Study) else load_suite(suite)
    suite = base.name if isinstance(suite, Study) else suite
    study = tuner_study(base, tuner, seeds, imports)
    entry = study.tuners[0]
    try:
        tasks = plan_batches(study)
    except ValueError as exc:
        raise ValueError(f"--tuner {entry.name} / --tuner-kwargs: {exc}") from None
    folder = out / slugify(entry.label)
    run = None
    if not report_only:
        run = run_study(study, folder, backend=backend, address=address, workers=workers, progress=progress,
                        log=log)
        if run.interrupted or run.failed:
            return SuiteResult(run=run, label=entry.label)
    budgets = {task.plant: task.budget for task in tasks}
    optima = suite_optima(study, budgets, references, out / "optima.json", progress=progress)
    mine = load_curves(folder, study, optima=optima)
    batches = min(study.batches, base.batches)
    refs = load_references(base, optima, references, batches=batches)
    reference_labels = base.labels
    curves = refs.curves.copy()
    if entry.label in reference_labels:  # e.g. --tuner bo: the reference keeps its row, renamed
        renamed = f"{entry.label} (reference)"
        curves["tuner"] = curves["tuner"].replace(entry.label, renamed)
        reference_labels = [renamed if name == entry.label else name for name in reference_labels]
        refs.stale = {((renamed if t == entry.label else t), p): r for (t, p), r in refs.stale.items()}
        refs.missing = [((renamed if t == entry.label else t), p) for t, p in refs.missing]
    reference = "bo (reference)" if entry.label == "bo" else "bo"
    combined = pd.concat([frame for frame in (mine, curves) if len(frame)], ignore_index=True)
    status = {key: "stale" for key in refs.stale}
    status.update({key: "missing" for key in refs.missing if key not in status})
    targets = plant_targets(study, budgets)
    board = Leaderboard(reference=reference).fit(combined, targets, status=status,
                                                 order=[entry.label, *reference_labels])
    notes = describe(refs)
    if study.batches > base.batches:
        notes.append(f"{entry.label} ran {study.batches} seeds per plant, the references {base.batches}: its "
                     f"ratio to {reference} is on the seeds both ran")
    intro = [f"Suite `{suite}`: {len(study.plants)} plants ({', '.join(p.label for p in study.plants)}), seeds "
             f"{study.seed}-{study.seed + study.batches - 1}, the env's episode length as budget. Your tuner: "
             f"`{entry.label}` (`{entry.name}`, kwargs `{entry.params}`), {len(mine)} runs from `{folder}`. "
             f"References: {', '.join(f'`{name}`' for name in reference_labels)} from `{references}` (not rerun).",
             "", base.description.strip()]
    meta = {"suite": suite, "tuner": {"label": entry.label, "name": entry.name, "params": entry.params,
                                      "imports": list(imports), "runs": len(mine)},
            "seeds": study.batches, "references": _commits(refs), "stale": [list(k) for k in refs.stale],
            "missing": [list(k) for k in refs.missing]}
    paths = write_leaderboard(board, out, title=f"Leaderboard: {base.title} ({suite})", intro=intro, notes=notes,
                              highlight=entry.label, meta=meta)
    return SuiteResult(run=run, leaderboard=board, references=refs, paths=paths, label=entry.label)


def _commits(refs: ReferenceSet) -> dict:
    """Reference label -> the commits its runs came from, with their counts."""
    if not len(refs.curves) or "commit" not in refs.curves:
        return {}
    counts = refs.curves.groupby(["tuner", "commit"]).size()
    out: dict = {}
    for (tuner, commit), n in counts.items():
        out.setdefault(tuner, {})[str(commit)] = int(n)
    return out


def study_leaderboard(study: Study, out: Path | str) -> dict[str, Path]:
    """The leaderboard of every tuner of a ``[[plants]]`` study from its runs under ``out``
    (``gbo bench suite.toml`` runs every reference tuner on the suite)."""
    out = Path(out)
    tasks = plan_batches(study)
    budgets = {task.plant: task.budget for task in tasks}
    optima = suite_optima(study, budgets, cache=out / "optima.json")
    curves = load_curves(out, study, optima=optima)
    reference = study.report.get("reference", study.labels[0])
    board = Leaderboard(reference=reference).fit(curves, plant_targets(study, budgets), order=study.labels)
    return write_leaderboard(board, out, title=f"Leaderboard: {study.title}", intro=[study.description.strip()])
