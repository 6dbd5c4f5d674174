"""The shipped reference results of the benchmark suite: curves of the reference tuners, with fingerprints.

The reference tuners are the ``[[tuners]]`` of ``evaluation/studies/suite.toml``
(``bo``, ``guided-bo``, ``mf-bo``, ``random``, ``nominal`` and the peer libraries).
Their runs on the standard suite ship in ``evaluation/references/``:

- ``<tuner>.parquet``: one row per run (plant, seed) as curves (:mod:`evaluation.curves`:
  the best-ratio curve and each experiment's ratio, not the signals), and per run what it
  was computed from: the git ``commit`` of the code, the hash of the tuner's source
  modules (``tuner_hash``) and of the plant's (``plant_hash``, with the env's shipped
  truth table), the env id and kwargs, the tuner's name and kwargs and ``J*``
  (``optimum``), i.e. its **fingerprint**;
- ``plants.json``: per plant of the suite its env, budget and ``J*_k`` per experiment
  (:func:`evaluation.curves.plant_optima`) with the plant hash they belong to, so the
  suite does not recompute ground truths while the plants are unchanged.

**Staleness rule**: a reference run is stale when the env id or kwargs, the tuner's name or
kwargs, or ``J*`` (relative difference above :data:`OPTIMUM_RTOL`, i.e. beyond floating-point
noise) differ from the current ones, or when the tuner's or the plant's code changed what it
does. The source hashes (:mod:`evaluation.fingerprint`) say whether the code changed at all;
where one differs, the behaviour fingerprint (:mod:`evaluation.behaviour`: the plant's responses
at fixed gains and seeds, the tuner's first proposals) decides, so that a refactor or a speed-up
that keeps every number leaves the references current. A run without a behaviour fingerprint is
stale when its source changed. The suite reports stale references and uses them with that mark;
``gbo bench suite --rebuild-references [--tuner NAME]`` stamps the current ones with the new
source hashes (:func:`restamp`) and reruns the stale and missing ones (:func:`rebuild`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from agents.jsonable import jsonable
from agents.run_display import progress_bar
from agents.thread_limits import blas_kernels
from evaluation import behaviour, fingerprint
from evaluation.curves import CURVE_COLUMNS, load_curves, plant_optima, read_curves
from evaluation.study import Study, slugify
from evaluation.study_runner import plan_batches, run_study
from gbo_envs.atomic_write import atomic_write

__all__ = ["OPTIMUM_RTOL", "REFERENCES_DIR", "FINGERPRINT_COLUMNS", "Fingerprint", "ReferenceSet",
           "REFERENCE_BLAS_KERNELS", "current_fingerprints", "describe", "kernel_warning", "load_references",
           "plant_hash", "plant_table", "rebuild", "restamp", "reference_file", "stale_reasons", "suite_optima",
           "write_references"]

#: The shipped references (package data).
REFERENCES_DIR = Path(__file__).resolve().parent / "references"
PLANTS_FILE = "plants.json"
#: Relative tolerance on ``J*`` below which two optima are the same (floating-point noise of the grid search).
OPTIMUM_RTOL = 1e-9
#: The OpenBLAS kernels the references are built and checked with. ``make`` pins them on x86-64
#: (``OPENBLAS_CORETYPE``, and the AVX-512 loops of numpy, torch and MKL off): with other
#: kernels a GP's last bits differ, and a run can part from its reference after a few experiments.
REFERENCE_BLAS_KERNELS = "Haswell"
#: Curves columns of a reference run beyond :data:`evaluation.curves.CURVE_COLUMNS`.
FINGERPRINT_COLUMNS = ["tuner_hash", "plant_hash", "tuner_behaviour", "plant_behaviour"]


@dataclass(frozen=True)
class Fingerprint:
    """What a run of one tuner on one plant depends on (see the module docstring).

    Attributes
    ----------
    env_id : str
    env_kwargs : str
        JSON, keys sorted.
    tuner_name : str
    params : str
        JSON, keys sorted.
    tuner_hash, plant_hash : str
        :func:`evaluation.fingerprint.source_hash` of the tuner's and the plant's modules (the plant's with
        its truth table).
    optimum : float
        ``J*`` of the plant at the first experiment.
    """

    env_id: str
    env_kwargs: str
    tuner_name: str
    params: str
    tuner_hash: str
    plant_hash: str
    optimum: float


def _canonical(value) -> str:
    if isinstance(value, str):
        value = json.loads(value) if value else {}
    return json.dumps(jsonable(value), sort_keys=True)


def stale_reasons(run, current: Fingerprint) -> list[str]:
    """Why a reference run (a curves row with fingerprint columns) no longer matches ``current``; empty if
    it is current.

    Where a source hash differs, the run's behaviour fingerprint is compared with the code's now
    (:mod:`evaluation.behaviour`, computed once per process): equal, the run is current.
    """
    reasons = []
    since = str(run.get("commit") or "?")[:10]
    if run["env_id"] != current.env_id or _canonical(run["env_kwargs"]) != current.env_kwargs:
        reasons.append("the plant's env or kwargs changed")
    if run["tuner_name"] != current.tuner_name or _canonical(run["params"]) != current.params:
        reasons.append("the tuner's name or kwargs changed")
    elif run.get("tuner_hash") != current.tuner_hash:
        stamped = _stamp(run.get("tuner_behaviour"))
        if stamped is None:
            reasons.append(f"the tuner's source changed since {since}")
        elif stamped != behaviour.tuner_behaviour(current.tuner_name, current.params):
            reasons.append(f"the tuner's behaviour changed since {since}")
    plant_changed = False
    if run.get("plant_hash") != current.plant_hash:
        stamped = _stamp(run.get("plant_behaviour"))
        if stamped is None:
            reasons.append(f"the plant's source or truth table changed since {since}")
            plant_changed = True
        elif stamped != behaviour.plant_behaviour(current.env_id, current.env_kwargs):
            reasons.append(f"the plant's behaviour or truth table changed since {since}")
            plant_changed = True
    if not plant_changed and not np.isclose(float(run["optimum"]), current.optimum, rtol=OPTIMUM_RTOL, atol=0.0):
        reasons.append(f"J* changed ({float(run['optimum']):.6g} -> {current.optimum:.6g})")
    return reasons


def _stamp(value) -> str | None:
    """A behaviour fingerprint as stored (``None`` where a run has none: a missing column or value)."""
    return value if isinstance(value, str) and value else None


# -- plants -------------------------------------------------------------------------------------------
def plant_hash(env_id: str, tree=None) -> str:
    """Hash of the plant's source modules and its shipped truth table (:mod:`evaluation.fingerprint`)."""
    table = fingerprint.truth_table_path(env_id)
    extra = {}
    if table is not None:
        if tree is not None and tree.commit is not None:
            blob = fingerprint._git_show(tree.commit, table)
        else:
            blob = (fingerprint.REPO_ROOT / table).read_bytes()
        extra[table] = blob if blob is not None else b"<missing>"
    return fingerprint.source_hash(fingerprint.plant_modules(env_id, tree), tree, extra)


def plant_table(folder: Path | str = REFERENCES_DIR) -> dict:
    """``plants.json`` of a references folder: plant label -> env, budget, resolution, hash and ``optima``."""
    path = Path(folder) / PLANTS_FILE
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}


def suite_optima(study: Study, budgets: dict[str, int], folder: Path | str = REFERENCES_DIR,
                 cache: Path | str | None = None, progress: bool | None = False) -> dict[str, np.ndarray]:
    """``J*_k`` per plant of ``study``: from the references' plant table while the plant is unchanged, else
    computed (:func:`evaluation.curves.plant_optima`, cached in ``cache``; a bar per plant with ``progress``)."""
    table = plant_table(folder)
    optima = {}
    bar = progress_bar(len(study.plants), "ground truths", progress, unit="plant")
    for plant in study.plants:
        bar.update(1)
        known = table.get(plant.label)
        budget = budgets[plant.label]
        if (known and known["env_id"] == plant.env_id
                and _canonical(known["env_kwargs"]) == _canonical(plant.env_kwargs)
                and known["resolution"] == study.resolution and len(known["optima"]) >= budget
                and _same_plant(known, plant)):
            optima[plant.label] = np.asarray(known["optima"][:budget], dtype=float)
        else:
            optima[plant.label] = plant_optima(plant.env_id, plant.env_kwargs, budget, study.resolution, cache)
    bar.close()
    return optima


def _same_plant(known: dict, plant) -> bool:
    """Whether a plant-table entry belongs to the plant as it is now: the same source hash, or else the same
    behaviour (:func:`evaluation.behaviour.plant_behaviour`)."""
    if known["plant_hash"] == plant_hash(plant.env_id):
        return True
    stamped = _stamp(known.get("plant_behaviour"))
    return stamped is not None and stamped == behaviour.plant_behaviour(plant.env_id, plant.env_kwargs)


def _write_plant_table(study: Study, budgets: dict[str, int], optima: dict[str, np.ndarray], folder: Path) -> None:
    table = plant_table(folder)
    for plant in study.plants:
        table[plant.label] = {"env_id": plant.env_id, "env_kwargs": jsonable(plant.env_kwargs),
                              "budget": budgets[plant.label], "resolution": study.resolution,
                              "plant_hash": plant_hash(plant.env_id),
                              "plant_behaviour": behaviour.plant_behaviour(plant.env_id, plant.env_kwargs),
                              "optima": [float(v) for v in optima[plant.label]]}
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_write(folder / PLANTS_FILE) as handle:
        json.dump(table, handle, indent=1)
        handle.write("\n")


# -- current fingerprints -----------------------------------------------------------------------------
def current_fingerprints(study: Study, optima: dict[str, np.ndarray]) -> dict[tuple[str, str], Fingerprint]:
    """``(tuner label, plant label)`` -> the fingerprint a run made now would have, for every entry and plant
    of ``study`` it runs on."""
    plant_hashes = {plant.label: plant_hash(plant.env_id) for plant in study.plants}
    out = {}
    for entry in study.tuners:
        try:
            tuner_hash = fingerprint.source_hash(fingerprint.tuner_modules(entry.name))
        except ValueError:
            tuner_hash = "<unknown tuner>"
        for plant in study.plants:
            if study.runs_on(entry, plant):
                out[(entry.label, plant.label)] = Fingerprint(
                    env_id=plant.env_id, env_kwargs=_canonical(plant.env_kwargs), tuner_name=entry.name,
                    params=_canonical(entry.params), tuner_hash=tuner_hash, plant_hash=plant_hashes[plant.label],
                    optimum=float(optima[plant.label][0]))
    return out


# -- loading ------------------------------------------------------------------------------------------
@dataclass
class ReferenceSet:
    """The reference runs of a suite, with their staleness.

    Attributes
    ----------
    curves : DataFrame
        Curves rows (:data:`evaluation.curves.CURVE_COLUMNS` + :data:`FINGERPRINT_COLUMNS`) of the suite's
        plants and seeds, ``tuner`` the reference label.
    stale : dict
        ``(tuner, plant)`` -> reasons (a list of str), for the references with at least one stale run.
    missing : list of (str, str)
        ``(tuner, plant)`` of the suite without any reference run, or with fewer seeds than the suite.
    """

    curves: pd.DataFrame
    stale: dict = field(default_factory=dict)
    missing: list = field(default_factory=list)

    def status(self, tuner: str, plant: str) -> str:
        """``"current"``, ``"stale"`` or ``"missing"``."""
        if (tuner, plant) in self.stale:
            return "stale"
        if (tuner, plant) in self.missing:
            return "missing"
        return "current"


def kernel_warning() -> str | None:
    """A warning when the loaded OpenBLAS kernels are not :data:`REFERENCE_BLAS_KERNELS`, else ``None``."""
    other = sorted(blas_kernels() - {REFERENCE_BLAS_KERNELS})
    if not other:
        return None
    return (f"OpenBLAS runs its {', '.join(other)} kernels here, the references {REFERENCE_BLAS_KERNELS}'s: runs can "
            "part from them after a few experiments; run through make, or set OPENBLAS_CORETYPE=Haswell and "
            'the other variables as the Makefile does')


def reference_file(label: str, folder: Path | str = REFERENCES_DIR) -> Path:
    """The curves file of the reference tuner ``label``."""
    return Path(folder) / f"{slugify(label)}.parquet"


def load_references(study: Study, optima: dict[str, np.ndarray], folder: Path | str = REFERENCES_DIR,
                    batches: int | None = None) -> ReferenceSet:
    """The reference runs of every tuner entry of ``study`` on its plants, seeds ``seed .. seed + batches - 1``.

    Parameters
    ----------
    study : Study
        The suite (its ``tuners`` are the references).
    optima : dict
        ``J*_k`` per plant (for the current fingerprints).
    folder : Path
        The references folder.
    batches : int, optional
        Seeds per plant (default: the study's).
    """
    batches = study.batches if batches is None else batches
    current = current_fingerprints(study, optima)
    parts, stale, missing = [], {}, []
    for entry in study.tuners:
        curves = read_curves(reference_file(entry.label, folder))
        for plant in study.plants:
            if not study.runs_on(entry, plant):
                continue
            wanted = min(batches, study.plant_batches(plant, entry))
            mine = curves[(curves["plant"] == plant.label) & (curves["batch"] < wanted)] if len(curves) else curves
            if len(mine) < wanted:
                missing.append((entry.label, plant.label))
            if not len(mine):
                continue
            reasons = sorted({reason for _, run in mine.iterrows()
                              for reason in stale_reasons(run, current[(entry.label, plant.label)])})
            if reasons:
                stale[(entry.label, plant.label)] = reasons
            parts.append(mine.assign(tuner=entry.label))
    frame = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=CURVE_COLUMNS + FINGERPRINT_COLUMNS)
    return ReferenceSet(curves=frame, stale=stale, missing=missing)


# -- rebuilding ---------------------------------------------------------------------------------------
def rebuild(study: Study, tuners: list[str] | None = None, out: Path | str = Path("out") / "references",
            folder: Path | str = REFERENCES_DIR, force: bool = False, plants: list[str] | None = None,
            backend: str = "local", address: str | None = None, workers: int | None = None,
            progress: bool | None = False, log=None) -> dict:
    """Restamp the current references of ``study`` (:func:`restamp`), then rerun the stale and missing ones and
    write them into ``folder``.

    Each reference tuner's plants that are stale or missing (all of them with ``force``) run through
    :func:`evaluation.study_runner.run_study` in ``out/<tuner>/<version>`` (``version`` hashes the
    sources: an interrupted rebuild goes on where it stopped, a rebuild of changed code starts anew),
    then replace that tuner's rows of those plants in its curves file, stamped with the current
    commit and hashes.

    Parameters
    ----------
    study : Study
        The suite with its reference tuners (``evaluation/studies/suite.toml``).
    tuners : list of str, optional
        Reference labels to rebuild (default: all).
    out : Path
        Working folder of the runs.
    folder : Path
        The references folder.
    force : bool
        Rebuild current references too.
    plants : list of str, optional
        Plant labels to rebuild on (default: every suite plant); the others are left as they are.
    backend, address, workers, progress, log
        As :func:`evaluation.study_runner.run_study`.

    Returns
    -------
    dict
        ``tuner label -> list of the plant labels rebuilt`` (empty lists for tuners that were current),
        and ``"interrupted"`` / ``"failed"`` (batch files of failed runs) when that happened; the tuner
        whose runs stopped is not among the labels (nothing of it was written).
    """
    study.check_tuner_labels(tuners)
    study.check_plant_labels(plants)
    folder, out = Path(folder), Path(out)
    tasks = plan_batches(study)
    budgets = {task.plant: task.budget for task in tasks}
    optima = suite_optima(study, budgets, folder, out / "optima.json", progress=progress)
    restamp(study, tuners, folder, optima)
    current = current_fingerprints(study, optima)
    refs = load_references(study, optima, folder)
    done: dict = {}
    for entry in _selected(study, tuners):
        chosen = [p.label for p in study.plants if study.runs_on(entry, p) and (not plants or p.label in plants)
                  and (force or refs.status(entry.label, p.label) != "current")]
        if not chosen:
            done[entry.label] = []
            continue
        part = study.subset(plants=chosen, tuners=(entry,), name=f"{study.name}-{slugify(entry.label)}")
        before = {p: current[(entry.label, p)] for p in chosen}
        # one working folder per source version: an interrupted rebuild resumes, one of changed code starts anew
        version = hashlib.sha256(json.dumps(sorted((p, f.tuner_hash, f.plant_hash) for p, f in before.items()))
                                 .encode()).hexdigest()[:10]
        work = out / slugify(entry.label) / version
        run = run_study(part, work, backend=backend, address=address, workers=workers, progress=progress, log=log)
        if run.interrupted or run.failed:
            done["interrupted" if run.interrupted else "failed"] = [name for name, _ in run.failed] or True
            return done
        new = load_curves(work, part, optima=optima)
        modules = set(fingerprint.tuner_modules(entry.name))
        for plant in chosen:
            modules.update(fingerprint.plant_modules(study.plant(plant).env_id))
        stamp = fingerprint.git_commit(sorted(modules)) or "unknown"
        fingerprint.reread_sources()
        again = current_fingerprints(part, optima)
        changed = [p for p in chosen if again[(entry.label, p)] != before[p]]
        if changed:
            raise RuntimeError(f"the sources of {entry.label} on {changed} changed while its references were "
                               "built; rebuild again")
        new = new.assign(commit=stamp, tuner_hash=[before[p].tuner_hash for p in new["plant"]],
                         plant_hash=[before[p].plant_hash for p in new["plant"]],
                         tuner_behaviour=behaviour.tuner_behaviour(entry.name, before[chosen[0]].params),
                         plant_behaviour=[behaviour.plant_behaviour(before[p].env_id, before[p].env_kwargs)
                                          for p in new["plant"]], source="engine")
        old = read_curves(reference_file(entry.label, folder))
        keep = old[~old["plant"].isin(chosen)] if len(old) else old
        merged = pd.concat([frame for frame in (keep, new) if len(frame)], ignore_index=True)
        order = {p.label: i for i, p in enumerate(study.plants)}
        merged = merged.sort_values(["plant", "batch"], key=lambda s: s.map(order) if s.name == "plant" else s,
                                    kind="stable")
        write_references(merged, reference_file(entry.label, folder))
        done[entry.label] = chosen
    _write_plant_table(study, budgets, optima, folder)
    return done


def _selected(study: Study, tuners: list[str] | None):
    """The reference entries of ``study`` labelled ``tuners`` (all without)."""
    return [entry for entry in study.tuners if not tuners or entry.label in tuners]


def restamp(study: Study, tuners: list[str] | None = None, folder: Path | str = REFERENCES_DIR,
            optima: dict[str, np.ndarray] | None = None) -> dict[str, list[str]]:
    """Stamp the current reference runs with the code's source hashes and behaviour fingerprints, in place.

    A run is current when nothing of its fingerprint changed but the sources, and its behaviour did
    not (:func:`stale_reasons`): after a refactor that keeps every number, its rows take the new
    ``tuner_hash`` and ``plant_hash`` (its ``commit`` stays the one its curves came from), so that
    later loads need no behaviour check. Rows without behaviour fingerprints whose sources are
    unchanged get them. Stale runs are left for :func:`rebuild` to rerun.

    Parameters
    ----------
    study : Study
        The suite with its reference tuners.
    tuners : list of str, optional
        Reference labels to restamp (default: all).
    folder : Path
        The references folder.
    optima : dict, optional
        ``J*_k`` per plant (default: :func:`suite_optima`).

    Returns
    -------
    dict
        ``tuner label -> the plant labels restamped``.
    """
    folder = Path(folder)
    if optima is None:
        optima = suite_optima(study, {task.plant: task.budget for task in plan_batches(study)}, folder)
    current = current_fingerprints(study, optima)
    refs = load_references(study, optima, folder)
    done: dict = {}
    for entry in _selected(study, tuners):
        path = reference_file(entry.label, folder)
        curves = read_curves(path)
        done[entry.label] = []
        if not len(curves):
            continue
        curves = curves.reindex(columns=CURVE_COLUMNS + FINGERPRINT_COLUMNS)
        for column in FINGERPRINT_COLUMNS:  # text (a column the file lacked comes as floats: NaN)
            curves[column] = curves[column].astype(object)
        for plant in study.plants:
            rows = (curves["plant"] == plant.label).to_numpy()
            if not study.runs_on(entry, plant) or not rows.any() or (entry.label, plant.label) in refs.stale:
                continue
            now = current[(entry.label, plant.label)]
            stored = curves.loc[rows, FINGERPRINT_COLUMNS]
            stamped = stored[["tuner_behaviour", "plant_behaviour"]].map(_stamp).notna().all(axis=1)
            if ((stored["tuner_hash"] == now.tuner_hash) & (stored["plant_hash"] == now.plant_hash) & stamped).all():
                continue  # stamped with this code already: no probe to run
            stamp = {"tuner_hash": now.tuner_hash, "plant_hash": now.plant_hash,
                     "tuner_behaviour": behaviour.tuner_behaviour(now.tuner_name, now.params),
                     "plant_behaviour": behaviour.plant_behaviour(now.env_id, now.env_kwargs)}
            for column, value in stamp.items():
                curves.loc[rows, column] = value
            done[entry.label].append(plant.label)
        if done[entry.label]:
            write_references(curves, path)
    table = plant_table(folder)
    fresh = False
    for plant in study.plants:  # the plant table's optima hold while the plant does what it did
        known = table.get(plant.label)
        if known and known["plant_hash"] == plant_hash(plant.env_id) and _stamp(known.get("plant_behaviour")):
            continue  # stamped with this code already
        if known and _same_plant(known, plant):
            stamp = {"plant_hash": plant_hash(plant.env_id),
                     "plant_behaviour": behaviour.plant_behaviour(plant.env_id, plant.env_kwargs)}
            fresh = fresh or any(known.get(key) != value for key, value in stamp.items())
            known.update(stamp)
    if fresh:
        with atomic_write(folder / PLANTS_FILE) as handle:
            json.dump(table, handle, indent=1)
            handle.write("\n")
    return done


def write_references(curves: pd.DataFrame, path: Path) -> Path:
    """Write a reference curves file: :func:`evaluation.curves.write_curves` with the fingerprint columns."""
    path.parent.mkdir(parents=True, exist_ok=True)
    frame = curves.reindex(columns=CURVE_COLUMNS + FINGERPRINT_COLUMNS).reset_index(drop=True)
    frame["curve"] = [np.asarray(v, dtype=float).tolist() for v in frame["curve"]]
    frame["instant"] = [None if v is None else np.asarray(v, dtype=float).tolist() for v in frame["instant"]]
    with atomic_write(path, "wb") as handle:
        frame.to_parquet(handle, index=False, compression="zstd")
    return path


def describe(refs: ReferenceSet) -> list[str]:
    """One line per reference tuner with stale or missing plants, for the command's output and the leaderboard:
    ``"stale reference: botorch on DCMotor-v0, LinearMotor-v0: the tuner's source changed since a30627b13b"``."""
    stale: dict = {}
    for (tuner, plant), reasons in refs.stale.items():
        plants, kinds = stale.setdefault(tuner, ([], {}))
        plants.append(plant)
        for reason in reasons:
            kind, since, commit = reason.rpartition(" since ")
            commits = kinds.setdefault(kind if since else reason, [])
            if since and commit not in commits:
                commits.append(commit)
    lines = [f"stale reference: {tuner} on {', '.join(plants)}: "
             + "; ".join(f"{kind} since {', '.join(commits)}" if commits else kind
                         for kind, commits in sorted(kinds.items()))
             for tuner, (plants, kinds) in stale.items()]
    missing: dict = {}
    for tuner, plant in refs.missing:
        missing.setdefault(tuner, []).append(plant)
    lines += [f"missing reference: {tuner} on {', '.join(plants)}" for tuner, plants in missing.items()]
    return lines
