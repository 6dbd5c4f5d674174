"""Study specs: a small declarative TOML (or YAML) file that describes a Monte Carlo study.

A study runs every tuner entry for ``batches`` batches of ``budget`` plant
experiments on one env. Batch ``i`` uses seed ``seed + i`` for the env and for
every tuner, so BO and guided BO start from the same initial points and see the
same noise. Example (``evaluation/studies/smoke.toml``)::

    [study]
    name = "smoke"                # default: the file name
    title = "Smoke test"
    batches = 4                   # Monte Carlo batches per tuner entry
    budget = 8                    # plant experiments per batch (initial ones included)
    n_initial = 1                 # N0, passed to tuners whose constructor takes n_initial
    seed = 0                      # batch i uses seed + i
    resolution = 40               # ground-truth grid points per gain

    [env]
    id = "gbo_envs/DCMotor-v0"
    kwargs = {}                   # passed to gym.make
    # constraints = {overshoot_pct = 2.0, peak_u = 140.0}   # the machine's limits (docs/constraints.md)

    [[tuners]]
    name = "random"               # registry name (agents.make)
    label = "random search"       # unique label in results (default: the name)
    params = {}                   # constructor keyword arguments

    [[tuners]]
    name = "guided-bo"
    label = "guided BO eta1={eta1}"      # {param} is filled from the sweep point
    params = {twin = "linear", guidance = {iterations = {eta3 = 0.2}}}
    sweep = {guidance.iterations.eta1 = [1e-6, 3, 20]}   # Cartesian product -> one entry per point,
    # or sweep = [{delta = 1.0, eta2 = 0.1}, {delta = 2.0, eta2 = 0.2}]  (explicit points)
    # a dotted key sweeps a parameter inside a table of params (merged into it); labels and
    # the report name it by its last part (eta1)

    [[thresholds]]                # optimality ratios J / J*
    ratio = 1.05                  # label defaults to "phi=1.05"
    [[thresholds]]
    label = "nominal PGM 60 deg"
    gains = [0.85, 1.07]          # the ratio is this controller's noise-free J / J*
    paper_ratio = 1.71            # optional: the paper's value, shown in the report

    [analysis]
    count_initial = true          # count the N0 initial experiments in "experiments to threshold"

    [report]                      # optional figure settings (see REPORT_KEYS)
    surface_batch = 0

    [paper]                       # the paper's published numbers (see PAPER_KEYS)
    source = "Table IV"
    thresholds = [{tuner = "random search", threshold = "phi=1.05", mean = 20}]

    [notes]
    text = "Free text copied into the report."

A study may run on several plants instead of one ``[env]``: ``[[plants]]`` tables, each
with its own label, env, thresholds and, optionally, its own number of batches, budget
(default: the env's episode length) and phase (``"after-change"``: a plant-changing env
such as ``DCMotorStep-v0`` is judged from its change on). A tuner entry may run on a subset
of the plants (``plants = [...]``) and on fewer batches (``batches = N``)::

    [study]
    name = "peers"
    batches = 30
    imports = ["my_tuners"]       # modules imported first: tuners they register can be named

    [[plants]]
    label = "DC+saturation"
    id = "gbo_envs/DCMotor-v0"
    kwargs = {effects = {saturation = {limit = 138.0}}}
    thresholds = [1.1, 1.05]

    [[tuners]]
    name = "bo"
    plants = ["DC+saturation"]
    batches = 10

The runs of such a study are summarised per plant by a comparison table
(:mod:`evaluation.comparison`; ``[report] table``); the benchmark suite
(:mod:`evaluation.suite`) is one such study.
"""

from __future__ import annotations

import copy
import itertools
import json
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import agents
from gbo_envs.constraints import Constraints

#: Study names: letters, digits, ``_`` and ``-`` (no dots: ``..`` is no name, and no path).
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-]+")

__all__ = [
    "PHASES",
    "Plant",
    "Study",
    "StudySpecError",
    "Threshold",
    "TunerEntry",
    "STUDIES_DIR",
    "load_study",
    "parse_study",
    "resolve_study_path",
    "shipped_studies",
    "slugify",
]

#: Folder of the shipped studies (package data).
STUDIES_DIR = Path(__file__).resolve().parent / "studies"

TOP_KEYS = ("study", "env", "plants", "tuners", "thresholds", "analysis", "report", "paper", "notes", "suite")
STUDY_KEYS = ("name", "title", "description", "batches", "budget", "n_initial", "seed", "resolution", "imports")
ENV_KEYS = ("id", "kwargs", "constraints")
PLANT_KEYS = ("label", "id", "kwargs", "constraints", "thresholds", "batches", "budget", "phase")
TUNER_KEYS = ("name", "label", "params", "sweep", "plants", "batches")
#: ``[suite]``: the plants and batches of the quick suite (``gbo bench suite --suite quick``).
SUITE_KEYS = ("quick_plants", "quick_batches")
#: How a plant's runs are judged: from the first experiment (``"run"``), or from the plant change of a
#: plant-changing env on, counting only experiments on the changed plant (``"after-change"``).
PHASES = ("run", "after-change")
THRESHOLD_KEYS = ("label", "ratio", "gains", "tuner", "params", "paper_ratio")
#: ``[report] table`` of a ``[[plants]]`` study: the comparison table's layout (:mod:`evaluation.comparison`).
TABLES = ("versus", "columns", "sections", "paired", "list", "leaderboard")
ANALYSIS_KEYS = ("count_initial",)
#: ``[report]`` options: batch drawn on the cost surface, tuners drawn there (labels), the
#: experiment at which best gains are tabulated, histogram bins / upper ratio limit,
#: the swept parameter of the sweep figure, and whether to draw percentile bands.
REPORT_KEYS = ("surface_batch", "surface_tuners", "gains_at", "histogram_bins", "histogram_max", "sweep_param",
               "bands", "table", "reference", "columns", "caption", "csv", "ratio", "ratio_label", "phases", "headers")
#: ``[paper]`` entries: free ``source``/``text``, ``thresholds`` rows ``{tuner, threshold, mean, best,
#: worst}``, ``gains`` rows ``{label, <gain names>, cost}``, ``metrics`` rows ``{tuner, metric, value}``.
PAPER_KEYS = ("source", "text", "thresholds", "gains", "metrics")
#: Per-tuner summary metrics a ``[[paper.metrics]]`` row may name (see ``analysis.summary_table``).
PAPER_METRICS = ("final_ratio", "mean_measured_ratio", "activations", "twin_evaluations", "batch_wall_time")


class StudySpecError(ValueError):
    """A study spec is invalid; the message names the file, the key and what is allowed."""


@dataclass(frozen=True)
class TunerEntry:
    """One tuner configuration of a study (a sweep expands into several).

    Attributes
    ----------
    name : str
        Registry name for :func:`agents.make`.
    label : str
        Unique label, the ``tuner`` column of the results.
    params : dict
        Constructor keyword arguments (sweep point included).
    sweep : dict
        The swept parameters of this entry and their values (empty if not swept).
    group : str
        Label template of the entry it was expanded from (entries of one sweep share it).
    plants : tuple of str
        Labels of the plants it runs on (empty: every plant of the study).
    batches : int or None
        At most this many batches on each plant (None: the plant's).
    """

    name: str
    label: str
    params: dict = field(default_factory=dict)
    sweep: dict = field(default_factory=dict)
    group: str = ""
    plants: tuple[str, ...] = ()
    batches: int | None = None


@dataclass(frozen=True)
class Threshold:
    """An optimality-ratio threshold, given directly or as a controller's ratio.

    Attributes
    ----------
    label : str
    ratio : float or None
        ``J / J*`` threshold (dimensionless), when given directly.
    gains : tuple of float or None
        Controller gains whose noise-free ratio is the threshold (e.g. the nominal PGM controller).
    tuner : str or None
        A tuner whose first experiment's noise-free ratio is the threshold (e.g. ``"nominal"``, which
        designs its gains from the plant), made with ``params``.
    params : dict
        Constructor keyword arguments of ``tuner``.
    paper_ratio : float or None
        The paper's value of this threshold, for the report.
    """

    label: str
    ratio: float | None = None
    gains: tuple[float, ...] | None = None
    paper_ratio: float | None = None
    tuner: str | None = None
    params: dict = field(default_factory=dict)

    def resolve(self, env, optimum: float) -> float:
        """The ratio: ``ratio`` itself, or ``J(gains) / J*`` on the noise-free ``env``.

        Parameters
        ----------
        env : gymnasium.Env
            The study's env (wrappers allowed).
        optimum : float
            Ground-truth ``J(theta*)``.
        """
        if self.ratio is not None:
            return float(self.ratio)
        if self.tuner is not None:
            spec = env.spec
            quiet = gym.make(spec.id, **{**(spec.kwargs or {}), "noise": False})
            result = agents.make(self.tuner, **self.params).run(quiet, budget=1, seed=0, progress=False)
            return float(result.min_true_cost_curve()[0]) / float(optimum)
        plant = env.unwrapped
        if len(self.gains) != len(plant.gain_names):
            raise StudySpecError(f"thresholds '{self.label}': gains has {len(self.gains)} values, the env has "
                                 f"{len(plant.gain_names)} gains {plant.gain_names}")
        cost = plant.evaluate(np.asarray(self.gains, dtype=float)[None, :], experiment_index=0)[1][0]
        return float(cost) / float(optimum)


@dataclass(frozen=True)
class Plant:
    """One plant of a study: an env with its kwargs, thresholds and run length.

    Attributes
    ----------
    label : str
        Unique label, the ``plant`` column of the results (an ``[env]`` study's one plant: the env's name).
    env_id : str
    env_kwargs : dict
    thresholds : tuple of Threshold
        Its thresholds (empty: the study's).
    batches : int or None
        Batches on this plant (None: the study's).
    budget : int or None
        Plant experiments per run (None: the study's budget, else the env's episode length).
    phase : {"run", "after-change"}
        Judge runs from the first experiment, or from the plant change of a plant-changing env on
        (:data:`PHASES`).
    """

    label: str
    env_id: str
    env_kwargs: dict = field(default_factory=dict)
    thresholds: tuple[Threshold, ...] = ()
    batches: int | None = None
    budget: int | None = None
    phase: str = "run"


@dataclass(frozen=True)
class Study:
    """A validated study spec; see the module docstring for the file format.

    Attributes
    ----------
    name, title, description : str
    env_id : str
    env_kwargs : dict
    tuners : tuple of TunerEntry
        Sweeps already expanded.
    batches, budget : int
        Batches per tuner entry; plant experiments per batch.
    n_initial : int or None
        N0, passed to tuners that accept ``n_initial`` (unless their params set it).
    seed : int
        Base seed; batch ``i`` uses ``seed + i``.
    thresholds : tuple of Threshold
    resolution : int
        Ground-truth grid points per gain.
    count_initial : bool
        Whether experiments-to-threshold counts the N0 initial experiments.
    report, paper : dict
    notes : str
    path : Path or None
    text : str
        The spec file's text (copied into the report).
    plants : tuple of Plant
        The plants (an ``[env]`` study: its one env; ``env_id`` and ``env_kwargs`` are the first plant's).
    per_plant : bool
        The spec has ``[[plants]]`` (its report is a comparison table per plant).
    imports : tuple of str
        Modules imported before the tuners are made (they may register tuners).
    suite : dict
        ``[suite]`` options (:data:`SUITE_KEYS`).
    """

    name: str
    env_id: str
    tuners: tuple[TunerEntry, ...]
    batches: int
    budget: int | None
    title: str = ""
    description: str = ""
    env_kwargs: dict = field(default_factory=dict)
    n_initial: int | None = None
    seed: int = 0
    thresholds: tuple[Threshold, ...] = ()
    resolution: int = 100
    count_initial: bool = True
    report: dict = field(default_factory=dict)
    paper: dict = field(default_factory=dict)
    notes: str = ""
    path: Path | None = None
    text: str = ""
    plants: tuple[Plant, ...] = ()
    per_plant: bool = False
    imports: tuple[str, ...] = ()
    suite: dict = field(default_factory=dict)

    @property
    def labels(self) -> list[str]:
        """Tuner labels in spec order."""
        return [entry.label for entry in self.tuners]

    @property
    def plant_labels(self) -> list[str]:
        """Plant labels in spec order."""
        return [plant.label for plant in self.plants]

    def plant(self, label: str) -> Plant:
        """The plant with this label."""
        for plant in self.plants:
            if plant.label == label:
                return plant
        raise KeyError(f"no plant labelled {label!r}; labels: {self.plant_labels}")

    def check_plant_labels(self, labels) -> None:
        """Refuse plant labels (``--plant``) that this study does not have, with a message naming its plants.

        Raises
        ------
        ValueError
            ``--plant: ['DCMotor'] are not plants of 'suite'; its plants: DCMotor-v0, ...``.
        """
        unknown = [label for label in labels or () if label not in self.plant_labels]
        if unknown:
            raise ValueError(f"--plant: {unknown} are not plants of {self.name!r}; its plants: "
                             f"{', '.join(self.plant_labels)}")

    def check_tuner_labels(self, labels, option: str = "--tuner") -> None:
        """Refuse tuner labels (given to ``option``) that this study does not have, with a message naming its
        tuners."""
        unknown = [label for label in labels or () if label not in self.labels]
        if unknown:
            raise ValueError(f"{option}: {unknown} are not tuners of {self.name!r}; its tuners: "
                             f"{', '.join(self.labels)}")

    def plant_batches(self, plant: Plant, entry: TunerEntry | None = None) -> int:
        """Batches of ``entry`` (default: any tuner) on ``plant``: the plant's or the study's, capped by the entry's."""
        batches = plant.batches if plant.batches is not None else self.batches
        if entry is not None and entry.batches is not None:
            batches = min(batches, entry.batches)
        return batches

    def plant_thresholds(self, plant: Plant) -> tuple[Threshold, ...]:
        """The plant's thresholds, or the study's."""
        return plant.thresholds or self.thresholds

    def runs_on(self, entry: TunerEntry, plant: Plant) -> bool:
        """Whether the tuner entry runs on the plant."""
        return not entry.plants or plant.label in entry.plants

    def subset(self, plants: list[str] | None = None, batches: int | None = None,
               tuners: tuple[TunerEntry, ...] | None = None, name: str | None = None) -> Study:
        """The same study on fewer plants, with ``batches`` batches on every plant, or with other tuners.

        Parameters
        ----------
        plants : list of str, optional
            Plant labels to keep, in this order (an unknown one raises :meth:`check_plant_labels`'s error).
        batches : int, optional
            Batches per plant (replaces every plant's and entry's own count).
        tuners : tuple of TunerEntry, optional
            The tuner entries (their ``plants`` must name kept plants).
        name : str, optional
            The new study's name.
        """
        self.check_plant_labels(plants)
        kept = self.plants if plants is None else tuple(self.plant(label) for label in plants)
        entries = self.tuners if tuners is None else tuple(tuners)
        if batches is not None:
            batches = _positive_int(batches, "batches", "batches")
            kept = tuple(replace(plant, batches=None) for plant in kept)
            entries = tuple(replace(entry, batches=None) for entry in entries)
        labels = {plant.label for plant in kept}
        entries = tuple(replace(entry, plants=tuple(p for p in entry.plants if p in labels)) for entry in entries
                        if not entry.plants or labels & set(entry.plants))
        return replace(self, plants=kept, tuners=entries, batches=self.batches if batches is None else batches,
                       env_id=kept[0].env_id, env_kwargs=dict(kept[0].env_kwargs), name=name or self.name)

    @property
    def threshold_offset(self) -> int:
        """Experiments subtracted from experiments-to-threshold counts (N0 when not counted)."""
        return 0 if self.count_initial else int(self.n_initial or 0)

    def with_batches(self, batches: int) -> Study:
        """The same study with another number of batches (``gbo bench --batches``): at most ``batches`` on
        every plant and tuner."""
        batches = _positive_int(batches, "batches", "--batches")
        plants = tuple(replace(p, batches=min(p.batches, batches)) if p.batches is not None else p
                       for p in self.plants)
        return replace(self, batches=batches, plants=plants)

    def tuner(self, label: str) -> TunerEntry:
        """The tuner entry with this label."""
        for entry in self.tuners:
            if entry.label == label:
                return entry
        raise KeyError(f"no tuner labelled {label!r}; labels: {self.labels}")


# -- loading -----------------------------------------------------------------------------------------
def shipped_studies() -> list[str]:
    """Names of the studies shipped in :data:`STUDIES_DIR`."""
    return sorted(p.stem for p in STUDIES_DIR.glob("*.toml"))


def resolve_study_path(study: str | Path) -> Path:
    """A spec path from a path or the name of a shipped study (``"smoke"``)."""
    path = Path(study)
    if path.is_file():
        return path
    if path.is_dir():
        raise StudySpecError(f"study {str(study)!r}: is a folder; expected a .toml/.yaml spec or a shipped study "
                             f"name ({', '.join(shipped_studies())})")
    shipped = STUDIES_DIR / f"{study}.toml"
    if NAME_PATTERN.fullmatch(str(study)) and shipped.is_file():
        return shipped
    raise StudySpecError(f"study {str(study)!r}: no such file and no shipped study of that name; "
                         f"shipped studies: {', '.join(shipped_studies())}")


def load_study(study: str | Path) -> Study:
    """Read and validate a study spec from a path (``.toml``, ``.yaml``/``.yml``) or a shipped name.

    Raises
    ------
    StudySpecError
        On a syntax error or an invalid key; the message names file, key and allowed values.
    """
    path = resolve_study_path(study)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise StudySpecError(f"{path}: not UTF-8 text (byte {exc.object[exc.start:exc.start + 1]!r} at position "
                             f"{exc.start}); save the spec as UTF-8") from None
    try:
        if path.suffix in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text) or {}
        else:
            import tomllib

            data = tomllib.loads(text)
    except Exception as exc:  # tomllib.TOMLDecodeError, yaml.YAMLError
        raise StudySpecError(f"{path}: cannot parse the spec: {exc}") from exc
    return parse_study(data, name=path.stem, path=path, text=text)


def parse_study(data: dict, name: str = "study", path: Path | None = None, text: str = "") -> Study:
    """Validate a parsed spec (a dict as read from TOML) and expand its sweeps.

    Parameters
    ----------
    data : dict
    name : str
        Default study name (the file stem).
    path : Path, optional
        For error messages.
    text : str, optional
        The spec's text, kept for the report.
    """
    where = str(path) if path is not None else name
    try:
        return _parse(data, name, path, text)
    except StudySpecError as exc:
        raise StudySpecError(f"{where}: {exc}") from None


def _parse(data: dict, name: str, path: Path | None, text: str) -> Study:
    _table(data, "the spec")
    _check_keys(data, TOP_KEYS, "top level")
    head = _table(data.get("study", {}), "[study]")
    _check_keys(head, STUDY_KEYS, "[study]")
    per_plant = "plants" in data
    if per_plant == ("env" in data):
        raise StudySpecError("give exactly one of [env] (one env) or [[plants]] (several plants, each with a "
                             "label and an env id)")
    if per_plant:
        plants = tuple(_plant(raw, f"plants[{i}]") for i, raw in enumerate(_list(data["plants"], "plants")))
        if not plants:
            raise StudySpecError("plants: expected at least one [[plants]] table with a label and an id")
        plant_labels = [plant.label for plant in plants]
        repeated = sorted({label for label in plant_labels if plant_labels.count(label) > 1})
        if repeated:
            raise StudySpecError(f"plants: labels must be unique, repeated: {repeated}")
        env_id, env_kwargs = plants[0].env_id, dict(plants[0].env_kwargs)
    else:
        env = _table(data.get("env"), "[env]", required=True)
        _check_keys(env, ENV_KEYS, "[env]")
        env_id = env.get("id")
        if not isinstance(env_id, str) or not env_id:
            raise StudySpecError(f"[env] id: expected an env id string such as 'gbo_envs/DCMotor-v0', got {env_id!r}")
        env_kwargs = _with_constraints(dict(_table(env.get("kwargs", {}), "[env] kwargs")), env, "[env]")
        plants = (Plant(label=env_id.rsplit("/", 1)[-1], env_id=env_id, env_kwargs=dict(env_kwargs)),)

    tuners = data.get("tuners")
    if not isinstance(tuners, list) or not tuners:
        raise StudySpecError("tuners: expected at least one [[tuners]] table with a 'name'")
    entries: list[TunerEntry] = []
    for i, raw in enumerate(tuners):
        entries.extend(_tuner_entries(raw, f"tuners[{i}]"))
    labels = [e.label for e in entries]
    known = [plant.label for plant in plants]
    for entry in entries:
        unknown = [label for label in entry.plants if label not in known]
        if unknown:
            raise StudySpecError(f"tuners '{entry.label}' plants: {unknown} are not plant labels; plants: {known}")
    duplicates = sorted({lab for lab in labels if labels.count(lab) > 1})
    if duplicates:
        raise StudySpecError(f"tuners: labels must be unique, repeated: {duplicates}; set 'label' "
                             "(a sweep label may use {param} placeholders)")
    slugs = [slugify(lab) for lab in labels]
    if len(set(slugs)) != len(slugs):
        raise StudySpecError(f"tuners: labels {labels} give clashing file names {slugs}; make them more distinct")

    thresholds = tuple(_threshold(t, f"thresholds[{i}]") for i, t in enumerate(_list(data.get("thresholds", []),
                                                                                       "thresholds")))
    names = [t.label for t in thresholds]
    if len(set(names)) != len(names):
        raise StudySpecError(f"thresholds: labels must be unique, got {names}")

    analysis = _table(data.get("analysis", {}), "[analysis]")
    _check_keys(analysis, ANALYSIS_KEYS, "[analysis]")
    count_initial = analysis.get("count_initial", True)
    if not isinstance(count_initial, bool):
        raise StudySpecError(f"[analysis] count_initial: expected true or false, got {count_initial!r}")

    report = dict(_table(data.get("report", {}), "[report]"))
    _check_keys(report, REPORT_KEYS, "[report]")
    _check_report(report, labels)
    paper = dict(_table(data.get("paper", {}), "[paper]"))
    _check_keys(paper, PAPER_KEYS, "[paper]")
    _check_paper(paper, labels, names)

    notes = data.get("notes", "")
    if isinstance(notes, dict):
        _check_keys(notes, ("text",), "[notes]")
        notes = notes.get("text", "")
    if not isinstance(notes, str):
        raise StudySpecError(f"[notes] text: expected a string, got {type(notes).__name__}")

    suite = dict(_table(data.get("suite", {}), "[suite]"))
    _check_keys(suite, SUITE_KEYS, "[suite]")
    if "quick_plants" in suite and not (isinstance(suite["quick_plants"], list) and suite["quick_plants"]
                                        and all(label in known for label in suite["quick_plants"])):
        raise StudySpecError(f"[suite] quick_plants: expected a list of plant labels from {known}, "
                             f"got {suite['quick_plants']!r}")
    if "quick_batches" in suite:
        _positive_int(suite["quick_batches"], "quick_batches", "[suite] quick_batches")
    imports = head.get("imports", [])
    if not isinstance(imports, list) or not all(isinstance(m, str) and m for m in imports):
        raise StudySpecError(f"[study] imports: expected a list of module names such as ['my_tuners'], "
                             f"got {imports!r}")
    budget = head.get("budget")
    if budget is not None or not per_plant:
        budget = _positive_int(budget, "budget", "[study] budget")
    n_initial = head.get("n_initial")
    if n_initial is not None:
        n_initial = _positive_int(n_initial, "n_initial", "[study] n_initial")
    study_name = head.get("name", name)
    if not isinstance(study_name, str) or not NAME_PATTERN.fullmatch(study_name):
        raise StudySpecError(f"[study] name: expected letters, digits, '_' and '-' only (the default is the file "
                             f"name), got {study_name!r}")
    seed = head.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise StudySpecError(f"[study] seed: expected an integer >= 0, got {seed!r}")
    for key in ("title", "description"):
        if not isinstance(head.get(key, ""), str):
            raise StudySpecError(f"[study] {key}: expected a string, got {head[key]!r}")
    return Study(
        name=study_name,
        title=head.get("title", "") or study_name,
        description=head.get("description", ""),
        env_id=env_id,
        env_kwargs=env_kwargs,
        tuners=tuple(entries),
        batches=_positive_int(head.get("batches"), "batches", "[study] batches"),
        budget=budget,
        n_initial=n_initial,
        seed=seed,
        thresholds=thresholds,
        resolution=_positive_int(head.get("resolution", 100), "resolution", "[study] resolution", minimum=2),
        count_initial=count_initial,
        report=report,
        paper=paper,
        notes=notes,
        path=path,
        text=text,
        plants=plants,
        per_plant=per_plant,
        imports=tuple(imports),
        suite=suite,
    )


# -- pieces -------------------------------------------------------------------------------------------
def _tuner_entries(raw: Any, where: str) -> list[TunerEntry]:
    raw = _table(raw, where)
    _check_keys(raw, TUNER_KEYS, where)
    name = raw.get("name")
    if not isinstance(name, str) or not name:
        raise StudySpecError(f"{where} name: expected a tuner registry name such as 'bo' or 'random', got {name!r}")
    label = raw.get("label", name)
    if not isinstance(label, str) or not label:
        raise StudySpecError(f"{where} label: expected a non-empty string, got {label!r}")
    params = dict(_table(raw.get("params", {}), f"{where} params"))
    plants = raw.get("plants", [])
    if not isinstance(plants, list) or not all(isinstance(p, str) and p for p in plants):
        raise StudySpecError(f"{where} plants: expected a list of plant labels, got {plants!r}")
    batches = raw.get("batches")
    if batches is not None:
        batches = _positive_int(batches, "batches", f"{where} batches")
    scope = {"plants": tuple(plants), "batches": batches}
    points = _sweep_points(raw.get("sweep"), f"{where} sweep")
    if not points:
        return [TunerEntry(name=name, label=label, params=params, sweep={}, group=label, **scope)]
    entries = []
    for point in points:
        merged = _merged(params, point)
        swept = {path[-1]: value for path, value in point.items()}  # by the last part of a dotted key
        if len(swept) < len(point):
            raise StudySpecError(f"{where} sweep: two swept parameters end in the same name "
                                 f"({sorted('.'.join(path) for path in point)})")
        if "{" in label:
            fields = {path[-1]: value for path, value in _paths(merged).items()}
            try:
                text = label.format(**{k: _fmt(v) for k, v in {**fields, **swept}.items()})
            except (KeyError, IndexError, ValueError) as exc:
                raise StudySpecError(f"{where} label: placeholder {exc} is neither a param nor a swept "
                                     f"parameter ({sorted(fields)})") from None
        else:
            text = f"{label} " + " ".join(f"{k}={_fmt(v)}" for k, v in swept.items())
        entries.append(TunerEntry(name=name, label=text, params=merged, sweep=swept, group=label, **scope))
    return entries


def _paths(table: dict, prefix: tuple = ()) -> dict[tuple, Any]:
    """``{("guidance", "iterations", "eta1"): 3.0}`` from ``{"guidance": {"iterations": {"eta1": 3.0}}}``."""
    out = {}
    for key, value in table.items():
        if isinstance(value, dict) and value:
            out.update(_paths(value, (*prefix, key)))
        else:
            out[(*prefix, key)] = value
    return out


def _merged(params: dict, point: dict[tuple, Any]) -> dict:
    """``params`` with each swept value set at its path (a copy: the entries of a sweep share no table)."""
    merged = copy.deepcopy(params)
    for path, value in point.items():
        table = merged
        for key in path[:-1]:
            if not isinstance(table.get(key, {}), dict):
                raise StudySpecError(f"sweep {'.'.join(path)}: params {key} = {table[key]!r} is not a table")
            table = table.setdefault(key, {})
        table[path[-1]] = value
    return merged


def _with_constraints(kwargs: dict, raw: dict, where: str) -> dict:
    """``kwargs`` with the table's ``constraints = {name = limit}`` (checked) as the env's ``constraints``."""
    if "constraints" not in raw:
        return kwargs
    limits = dict(_table(raw["constraints"], f"{where} constraints"))
    try:
        Constraints(limits)
    except (TypeError, ValueError) as exc:
        raise StudySpecError(f"{where} constraints: {exc}") from None
    if "constraints" in kwargs:
        raise StudySpecError(f"{where}: constraints given twice, as constraints and in kwargs; keep one")
    return {**kwargs, "constraints": limits}


def _plant(raw: Any, where: str) -> Plant:
    raw = _table(raw, where)
    _check_keys(raw, PLANT_KEYS, where)
    env_id = raw.get("id")
    if not isinstance(env_id, str) or not env_id:
        raise StudySpecError(f"{where} id: expected an env id string such as 'gbo_envs/DCMotor-v0', got {env_id!r}")
    label = raw.get("label", env_id.rsplit("/", 1)[-1])
    if not isinstance(label, str) or not NAME_PATTERN.fullmatch(label.replace("+", "_").replace(".", "_")):
        raise StudySpecError(f"{where} label: expected letters, digits and '_-+.' (e.g. 'DC+saturation'), "
                             f"got {label!r}")
    kwargs = _with_constraints(dict(_table(raw.get("kwargs", {}), f"{where} kwargs")), raw, where)
    thresholds = tuple(_threshold(t, f"{where} thresholds[{i}]")
                       for i, t in enumerate(_list(raw.get("thresholds", []), f"{where} thresholds")))
    names = [t.label for t in thresholds]
    if len(set(names)) != len(names):
        raise StudySpecError(f"{where} thresholds: labels must be unique, got {names}")
    batches, budget = raw.get("batches"), raw.get("budget")
    phase = raw.get("phase", "run")
    if phase not in PHASES:
        raise StudySpecError(f"{where} phase: expected one of {list(PHASES)}, got {phase!r}")
    return Plant(label=label, env_id=env_id, env_kwargs=kwargs, thresholds=thresholds,
                 batches=None if batches is None else _positive_int(batches, "batches", f"{where} batches"),
                 budget=None if budget is None else _positive_int(budget, "budget", f"{where} budget"), phase=phase)


def _sweep_points(sweep: Any, where: str) -> list[dict[tuple, Any]]:
    """The sweep's points, each ``{path: value}`` (a path is a dotted key's parts, ``("eta1",)`` for a plain one)."""
    if sweep is None:
        return []
    if isinstance(sweep, dict):
        if not sweep:
            raise StudySpecError(f"{where}: expected at least one parameter, e.g. {{eta1 = [1, 3]}}")
        lists = _paths(sweep)
        for path, values in lists.items():
            if not isinstance(values, list) or not values:
                raise StudySpecError(f"{where} {'.'.join(path)}: expected a non-empty list of values, got {values!r}")
        paths = list(lists)
        return [dict(zip(paths, combo)) for combo in itertools.product(*(lists[p] for p in paths))]
    if isinstance(sweep, list) and sweep and all(isinstance(p, dict) and p for p in sweep):
        return [_paths(p) for p in sweep]
    raise StudySpecError(f"{where}: expected a table of value lists ({{eta1 = [1, 3]}}, Cartesian product) or a "
                         f"list of parameter tables ([{{n_ei = 5, period = 1}}, ...]), got {sweep!r}")


def _threshold(raw: Any, where: str) -> Threshold:
    if isinstance(raw, (int, float)) and not isinstance(raw, bool):
        raw = {"ratio": raw}
    raw = _table(raw, where)
    _check_keys(raw, THRESHOLD_KEYS, where)
    ratio, gains, tuner = raw.get("ratio"), raw.get("gains"), raw.get("tuner")
    if sum(value is not None for value in (ratio, gains, tuner)) != 1:
        raise StudySpecError(f"{where}: give exactly one of 'ratio' (an optimality ratio >= 1), 'gains' "
                             "(a controller whose ratio is the threshold) or 'tuner' (a tuner whose first "
                             "experiment's ratio is the threshold, e.g. 'nominal')")
    params = dict(_table(raw.get("params", {}), f"{where} params"))
    if params and tuner is None:
        raise StudySpecError(f"{where} params: only with 'tuner'")
    if tuner is not None:
        if not isinstance(tuner, str) or not tuner:
            raise StudySpecError(f"{where} tuner: expected a tuner registry name such as 'nominal', got {tuner!r}")
        label = raw.get("label", tuner)
    elif ratio is not None:
        if not _is_number(ratio) or not ratio > 0:
            raise StudySpecError(f"{where} ratio: expected a number > 0 (an optimality ratio J / J*), got {ratio!r}")
        ratio = float(ratio)
        label = raw.get("label", f"phi={ratio:g}")
    else:
        if not isinstance(gains, list) or not gains or not all(_is_number(g) for g in gains):
            raise StudySpecError(f"{where} gains: expected a list of numbers (one per gain), got {gains!r}")
        gains = tuple(float(g) for g in gains)
        label = raw.get("label", "gains " + ", ".join(f"{g:g}" for g in gains))
    if not isinstance(label, str) or not label:
        raise StudySpecError(f"{where} label: expected a non-empty string, got {label!r}")
    paper_ratio = raw.get("paper_ratio")
    if paper_ratio is not None and not _is_number(paper_ratio):
        raise StudySpecError(f"{where} paper_ratio: expected a number, got {paper_ratio!r}")
    return Threshold(label=label, ratio=ratio, gains=gains, tuner=tuner, params=params,
                     paper_ratio=None if paper_ratio is None else float(paper_ratio))


def _check_report(report: dict, labels: list[str]) -> None:
    checks = {
        "surface_batch": lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 0,
        "surface_tuners": lambda v: isinstance(v, list) and all(x in labels for x in v),
        "gains_at": lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1,
        "histogram_bins": lambda v: (isinstance(v, int) and v >= 1) or (isinstance(v, list) and len(v) >= 2
                                                                         and all(_is_number(x) for x in v)),
        "histogram_max": lambda v: _is_number(v) and v > 1,
        "sweep_param": lambda v: isinstance(v, str),
        "bands": lambda v: isinstance(v, bool),
        "table": lambda v: v in TABLES,
        "reference": lambda v: v in labels,
        "columns": lambda v: isinstance(v, list) and all(isinstance(x, str) for x in v),
        "caption": lambda v: isinstance(v, str),
        "csv": lambda v: isinstance(v, bool),
        "ratio": lambda v: isinstance(v, list) and len(v) == 2 and all(x in labels for x in v),
        "ratio_label": lambda v: isinstance(v, str),
        "phases": lambda v: isinstance(v, bool),
        "headers": lambda v: isinstance(v, dict) and set(v) <= {"plant", "tuner", "seeds"}
        and all(isinstance(x, str) for x in v.values()),
    }
    allowed = {
        "surface_batch": "an integer >= 0",
        "surface_tuners": f"a list of tuner labels from {labels}",
        "gains_at": "an experiment number >= 1",
        "histogram_bins": "a number of bins or a list of bin edges",
        "histogram_max": "a ratio > 1",
        "sweep_param": "a swept parameter name",
        "bands": "true or false",
        "table": f"one of {list(TABLES)}",
        "reference": f"a tuner label from {labels}",
        "columns": "a list of column names (see evaluation.comparison.COLUMNS)",
        "caption": "a string (the line above the table)",
        "csv": "true or false",
        "ratio": f"two tuner labels from {labels} (compared, reference)",
        "ratio_label": "a string (the ratio column's header)",
        "phases": "true or false",
        "headers": "a table with 'plant', 'tuner' or 'seeds' (new column headers; seeds = '' drops it)",
    }
    for key, value in report.items():
        if not checks[key](value):
            raise StudySpecError(f"[report] {key}: expected {allowed[key]}, got {value!r}")


def _check_paper(paper: dict, labels: list[str], thresholds: list[str]) -> None:
    for key in ("source", "text"):
        if key in paper and not isinstance(paper[key], str):
            raise StudySpecError(f"[paper] {key}: expected a string, got {paper[key]!r}")
    for i, row in enumerate(_list(paper.get("thresholds", []), "[paper] thresholds")):
        where = f"[paper] thresholds[{i}]"
        _check_keys(_table(row, where), ("tuner", "threshold", "mean", "best", "worst"), where)
        if row.get("tuner") not in labels:
            raise StudySpecError(f"{where} tuner: expected one of the tuner labels {labels}, got {row.get('tuner')!r}")
        if row.get("threshold") not in thresholds:
            raise StudySpecError(f"{where} threshold: expected one of the threshold labels {thresholds}, "
                                 f"got {row.get('threshold')!r}")
        for key in ("mean", "best", "worst"):
            if key in row and not (_is_number(row[key]) or isinstance(row[key], str)):
                raise StudySpecError(f"{where} {key}: expected a number or a string such as '>50', got {row[key]!r}")
    for i, row in enumerate(_list(paper.get("gains", []), "[paper] gains")):
        where = f"[paper] gains[{i}]"
        _table(row, where)
        if not isinstance(row.get("label"), str):
            raise StudySpecError(f"{where} label: expected a string (e.g. 'Guided BO'), got {row.get('label')!r}")
        for key, value in row.items():
            if key != "label" and not _is_number(value):
                raise StudySpecError(f"{where} {key}: expected a number, got {value!r}")
    for i, row in enumerate(_list(paper.get("metrics", []), "[paper] metrics")):
        where = f"[paper] metrics[{i}]"
        _check_keys(_table(row, where), ("tuner", "metric", "value"), where)
        if row.get("tuner") not in labels:
            raise StudySpecError(f"{where} tuner: expected one of the tuner labels {labels}, got {row.get('tuner')!r}")
        if row.get("metric") not in PAPER_METRICS:
            raise StudySpecError(f"{where} metric: expected one of {PAPER_METRICS}, got {row.get('metric')!r}")
        if not _is_number(row.get("value")):
            raise StudySpecError(f"{where} value: expected a number, got {row.get('value')!r}")


# -- small helpers ------------------------------------------------------------------------------------
def slugify(label: str) -> str:
    """A file-name-safe form of a label (``"guided BO eta1=3"`` -> ``"guided-BO-eta1-3"``)."""
    slug = re.sub(r"[^A-Za-z0-9_.]+", "-", label).strip("-.")
    return slug or "tuner"


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, (list, tuple, dict)):
        return json.dumps(value)
    return str(value)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _positive_int(value: Any, name: str, where: str, minimum: int = 1) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
        raise StudySpecError(f"{where}: expected an integer >= {minimum}, got {value!r}")
    return int(value)


def _table(value: Any, where: str, required: bool = False) -> dict:
    if value is None and required:
        raise StudySpecError(f"{where}: missing (a table is required)")
    if not isinstance(value, dict):
        raise StudySpecError(f"{where}: expected a table, got {type(value).__name__} {value!r}")
    return value


def _list(value: Any, where: str) -> list:
    if not isinstance(value, list):
        raise StudySpecError(f"{where}: expected a list (array of tables), got {type(value).__name__}")
    return value


def _check_keys(table: dict, allowed: tuple[str, ...], where: str) -> None:
    unknown = [key for key in table if key not in allowed]
    if unknown:
        raise StudySpecError(f"{where}: unknown key(s) {unknown}; allowed keys: {list(allowed)}")
