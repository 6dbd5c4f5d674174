"""Run a study's batches in parallel, write each finished batch at once, resume what is missing.

Results layout (``OUT`` is the study's output folder)::

    OUT/results/<tuner-label-slug>__b<batch>__<key>.parquet   one file per finished batch
    OUT/results/<plant>__<tuner>__b<batch>__<key>.parquet     the same in a study of several plants
    OUT/curves.parquet                                        optional: runs kept as curves only
                                                              (evaluation.curves), skipped like files
    OUT/study.toml                                            the spec as run (study.yaml for YAML)
    OUT/runs.jsonl                                            one line per `gbo bench` run (runtime)

Each batch (one tuner entry x one seed) is written by the main process as soon as
it finishes, atomically (:func:`gbo_envs.atomic_write.atomic_write`: a temporary
file, then ``os.replace``), so a file is either complete or absent. ``key`` hashes everything that determines the batch
(env id and kwargs, tuner name and params, budget, seed), so a rerun skips
exactly the batches that already exist and reruns those whose spec changed.
Ctrl-C stops the run and keeps every finished batch; rerunning resumes.

The rows are :meth:`agents.TuningResult.to_pandas` (with ``include_twin=True``) plus ``study``, ``plant``
(its label), ``tuner`` (the label), ``tuner_name`` (registry name), ``batch``, ``seed``, ``row``
(order within the batch), ``params`` and ``info`` (JSON text), ``batch_wall_time`` (s),
``batch_cpu_time`` (CPU s of the run in its process), ``plant_cpu_time`` (the part of it spent in
the plant env's ``step``: the simulated experiment and its ground truth; the tuner's compute is the
difference) and, on plant rows, ``best_true_cost_now``: the lowest noise-free cost of the gains
tried so far judged on the plant as it is at this experiment, ``min_{j <= k} J_k(theta_j)``
(on a plant that does not change, the running minimum of ``true_cost``).
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import json
import os
import signal
import sys
import time
import traceback
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from joblib import Parallel, delayed

import agents
import gbo_envs  # noqa: F401  (registers the envs)
from agents.jsonable import to_json
from agents.process_lifetime import die_with_parent
from agents.run_display import progress_bar
from agents.thread_limits import single_thread
from evaluation.curve_table import CURVES_FILE, read_curves, write_curves
from evaluation.study import Plant, Study, StudySpecError, TunerEntry, slugify
from gbo_envs.atomic_write import atomic_write
from gbo_envs.physics.block import validated_count

__all__ = ["BatchTask", "StudyRun", "BACKENDS", "default_out_dir", "plan_batches", "finished_files",
           "forget", "kept_files", "run_batch", "run_study", "resolve_params", "import_study_modules", "plant_budget"]

#: Execution backends of :func:`run_study`.
BACKENDS = ("local", "dask")
RESULTS_DIR = "results"


@dataclass(frozen=True)
class BatchTask:
    """One batch: one tuner entry on one seed. Picklable; :func:`run_batch` runs it anywhere.

    Attributes
    ----------
    study, label, tuner : str
        Study name, tuner label and registry name.
    params : dict
        Constructor keyword arguments (``n_initial`` resolved).
    batch, seed : int
    env_id : str
    env_kwargs : dict
    budget : int
        Plant experiments.
    plant : str
        The plant's label.
    per_plant : bool
        The study has several plants: the file name starts with the plant's label.
    imports : tuple of str
        Modules imported before the tuner is made (they may register it).
    import_path : str or None
        Folder put first on ``sys.path`` for ``imports`` (the folder the study was started in).
    """

    study: str
    label: str
    tuner: str
    params: dict
    batch: int
    seed: int
    env_id: str
    env_kwargs: dict
    budget: int
    plant: str = ""
    per_plant: bool = False
    imports: tuple[str, ...] = ()
    import_path: str | None = None

    @property
    def key(self) -> str:
        """10 hex digits hashing what determines the batch's results (not the study or label)."""
        payload = to_json([self.env_id, self.env_kwargs, self.tuner, self.params, self.budget, self.seed])
        return hashlib.sha256(payload.encode()).hexdigest()[:10]

    @property
    def filename(self) -> str:
        """Result file name of this batch."""
        plant = f"{slugify(self.plant)}__" if self.per_plant else ""
        return f"{plant}{slugify(self.label)}__b{self.batch:04d}__{self.key}.parquet"


@dataclass
class StudyRun:
    """What :func:`run_study` did.

    Attributes
    ----------
    out : Path
    total : int
        Batches in the study.
    skipped : int
        Batches already finished before this run.
    completed : int
        Batches finished by this run.
    failed : list of (str, str)
        ``(file name, traceback)`` of batches that raised (not written; a rerun retries them).
    interrupted : bool
        Stopped by Ctrl-C (finished batches are kept).
    wall_time : float
        Seconds this run took.
    """

    out: Path
    total: int
    skipped: int = 0
    completed: int = 0
    failed: list = field(default_factory=list)
    interrupted: bool = False
    wall_time: float = 0.0

    @property
    def done(self) -> bool:
        """Every batch of the study is finished."""
        return self.skipped + self.completed == self.total


def default_out_dir(study: Study) -> Path:
    """``out/studies/<study name>`` under the working directory (never inside the installed package).

    The reports committed with the project live in ``docs/reports/<study name>``;
    refresh one with ``gbo bench STUDY --out docs/reports/STUDY``.
    """
    return Path("out") / "studies" / study.name


# -- planning -----------------------------------------------------------------------------------------
def import_study_modules(modules, path: str | None = None) -> None:
    """Import ``modules`` (they may register tuners), with ``path`` first on ``sys.path``.

    Raises
    ------
    StudySpecError
        A module that cannot be found or whose import raises; the message names it.
    """
    if path and path not in sys.path:
        sys.path.insert(0, path)
    for module in modules:
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            raise StudySpecError(f"[study] imports: no module named {exc.name or module!r} (searched "
                                 f"{path or 'the installed packages'} first)") from exc
        except Exception as exc:
            raise StudySpecError(f"[study] imports: importing {module!r} raised {type(exc).__name__}: {exc}") from exc


def plant_budget(study: Study, plant: Plant) -> int:
    """Plant experiments per run on ``plant``: its own budget, the study's, or the env's episode length."""
    if plant.budget is not None:
        return plant.budget
    if study.budget is not None:
        return study.budget
    steps = gym.spec(plant.env_id).max_episode_steps
    if not steps:
        raise StudySpecError(f"plants '{plant.label}': {plant.env_id} has no episode length; give budget")
    return int(steps)


def resolve_params(entry: TunerEntry, n_initial: int | None) -> dict:
    """The entry's params with the study's N0 added when the tuner takes ``n_initial`` and params lack it.

    Raises
    ------
    ValueError
        Unknown tuner name (the message lists the registered ones) or params the tuner rejects.
    """
    params = dict(entry.params)
    try:
        tuner = agents.make(entry.name, **params)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"tuner '{entry.label}' ({entry.name}, params {params}): {exc}") from exc
    if n_initial is not None and "n_initial" not in params and _accepts(type(tuner), "n_initial"):
        params["n_initial"] = int(n_initial)
    return params


def _accepts(cls: type, name: str) -> bool:
    parameters = inspect.signature(cls.__init__).parameters
    return name in parameters or any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values())


def check_env(env_id: str) -> None:
    """Refuse an env id that names no registered env (``MODULE:ID`` imports ``MODULE`` first, as gymnasium does).

    Raises
    ------
    StudySpecError
        The id is unknown, or its module cannot be imported; the message lists the registered ids.
    """
    try:
        gym.spec(env_id)
        return
    except (gym.error.Error, ImportError) as exc:
        reason = " ".join(str(exc).split())
    ours = sorted(k for k in gym.registry if k.startswith("gbo_envs/"))
    raise StudySpecError(f"[env] id {env_id!r}: not a registered env ({reason}); registered: {', '.join(ours)}")


def plan_batches(study: Study, import_path: str | None = None) -> list[BatchTask]:
    """Every batch of ``study``, batch-major (batch 0 of every plant and tuner first) so partial runs stay
    balanced.

    Parameters
    ----------
    study : Study
    import_path : str, optional
        Folder searched first for the study's ``imports`` (default: the working folder).

    Raises
    ------
    StudySpecError, ValueError
        An unknown env (:func:`check_env`), module or tuner, or params a tuner rejects.
    """
    import_path = import_path or os.getcwd()
    import_study_modules(study.imports, import_path)
    for plant in study.plants:
        check_env(plant.env_id)
    params = {entry.label: resolve_params(entry, study.n_initial) for entry in study.tuners}
    budgets = {plant.label: plant_budget(study, plant) for plant in study.plants}
    tasks = []
    for batch in range(max(study.plant_batches(plant) for plant in study.plants)):
        for plant in study.plants:
            for entry in study.tuners:
                if study.runs_on(entry, plant) and batch < study.plant_batches(plant, entry):
                    tasks.append(BatchTask(study=study.name, label=entry.label, tuner=entry.name,
                                           params=params[entry.label], batch=batch, seed=study.seed + batch,
                                           env_id=plant.env_id, env_kwargs=dict(plant.env_kwargs),
                                           budget=budgets[plant.label], plant=plant.label,
                                           per_plant=study.per_plant, imports=tuple(study.imports),
                                           import_path=import_path if study.imports else None))
    return tasks


def finished_files(out: Path) -> set[str]:
    """Names of the result files already written under ``out/results``."""
    folder = Path(out) / RESULTS_DIR
    return {p.name for p in folder.glob("*.parquet")} if folder.is_dir() else set()


def forget(study: Study, out: Path | str, labels) -> int:
    """Delete the finished runs of the tuner entries ``labels`` under ``out`` (batch files and kept curves), so
    that the next run makes them again with the current code (``gbo bench STUDY --rerun LABEL``).

    Returns
    -------
    int
        Runs deleted.

    Raises
    ------
    ValueError
        A label that is no tuner entry of the study.
    """
    study.check_tuner_labels(labels, "--rerun")
    out = Path(out)
    names = {task.filename for task in plan_batches(study) if task.label in set(labels)}
    deleted = 0
    for name in names:
        path = out / RESULTS_DIR / name
        if path.is_file():
            path.unlink()
            deleted += 1
    curves = read_curves(out / CURVES_FILE)
    drop = curves["file"].isin(names)
    if drop.any():
        write_curves(curves[~drop], out / CURVES_FILE)
        deleted += int(drop.sum())
    return deleted


def kept_files(out: Path) -> set[str]:
    """Batch file names of the runs kept as curves in ``out/curves.parquet`` (:mod:`evaluation.curve_table`)."""
    curves = read_curves(Path(out) / CURVES_FILE)
    return {name for name in curves["file"] if isinstance(name, str)}


# -- one batch ----------------------------------------------------------------------------------------
def run_batch(task: BatchTask):
    """Run one batch and return its tidy table (a pandas DataFrame, one row per experiment).

    A pure function of ``task``: the env and the tuner are both seeded with
    ``task.seed`` and BLAS runs single-threaded, so any process on any backend
    returns the same numbers.
    """
    import_study_modules(task.imports, task.import_path)
    with single_thread(user_api=None):  # BLAS and OpenMP: same numbers on every backend, no oversubscription
        kwargs = dict(task.env_kwargs)
        kwargs.setdefault("max_episode_steps", task.budget)
        env = _StepClock(gym.make(task.env_id, **kwargs))
        tuner = agents.make(task.tuner, **task.params)
        _torch_single_thread()
        start, cpu = time.perf_counter(), time.process_time()
        result = tuner.run(env, budget=task.budget, seed=task.seed)
        elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
        now = best_true_cost_now(env.unwrapped, result)
        env.close()
    frame = result.to_pandas(include_twin=True)  # the twin rows feed the twin-use and timing tables
    info = {k: v for k, v in result.info.items() if k != "params"}
    frame.insert(0, "row", np.arange(len(frame)))
    for position, (column, value) in enumerate([("study", task.study), ("plant", task.plant or task.env_id),
                                                 ("tuner", task.label), ("tuner_name", task.tuner),
                                                 ("batch", task.batch), ("seed", task.seed)]):
        frame.insert(position, column, value)
    frame["params"] = to_json(task.params)
    frame["info"] = to_json(info)
    frame["batch_wall_time"] = float(elapsed)
    frame["batch_cpu_time"] = float(cpu)
    frame["plant_cpu_time"] = float(env.cpu_seconds)
    frame["best_true_cost_now"] = np.nan
    plant_rows = (frame["source"] == "plant").to_numpy()
    frame.loc[plant_rows, "best_true_cost_now"] = now
    return _tidy(frame)


def best_true_cost_now(plant, result) -> np.ndarray:
    """``min_{j <= k} J_k(theta_j)`` after every plant experiment ``k`` of ``result``, shape (n_experiments,).

    The best gains tried so far judged on the plant as it is at experiment ``k``
    (``plant.evaluate(gains, experiment_index=k)``, the expected cost): the controller a user would
    deploy then. On a plant that does not change between experiments (no ``plant_params_at``) it is
    :meth:`agents.TuningResult.min_true_cost_curve`.
    """
    if not hasattr(plant, "plant_params_at"):
        return result.min_true_cost_curve()
    rows = result.plant_rows
    gains = np.array([[row[name] for name in result.gain_names] for row in rows], dtype=float)
    return np.array([float(np.min(plant.evaluate(gains[: k + 1], experiment_index=k)[1])) for k in range(len(rows))])


def _torch_single_thread() -> None:
    """One torch thread, if torch is already imported (the BoTorch-based tuners); BLAS is limited by the caller."""
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


class _StepClock(gym.Wrapper):
    """Adds up the CPU seconds spent in the env's ``step`` (the simulated experiment and its ground truth)."""

    def __init__(self, env) -> None:
        super().__init__(env)
        self.cpu_seconds = 0.0

    def step(self, action):
        start = time.process_time()
        try:
            return self.env.step(action)
        finally:
            self.cpu_seconds += time.process_time() - start


def _safe_run_batch(task: BatchTask):
    """``(task, frame, None)`` or ``(task, None, traceback)``: one failing batch does not stop the study."""
    try:
        return task, run_batch(task), None
    except Exception:
        return task, None, traceback.format_exc()


def _tidy(frame):
    """Make every column Parquet-friendly: ``unstable`` as bool, nested values as JSON text."""
    import pyarrow as pa

    if "unstable" in frame:
        frame["unstable"] = frame["unstable"].fillna(False).astype(bool)
    for column in frame.columns:
        if frame[column].dtype == object:
            try:
                pa.array(frame[column], from_pandas=True)
            except (pa.ArrowInvalid, pa.ArrowTypeError, TypeError, ValueError):
                frame[column] = [None if _is_missing(v) else to_json(v, sort_keys=False)
                                 for v in frame[column]]
    return frame


def _is_missing(value: Any) -> bool:
    return value is None or (isinstance(value, float) and np.isnan(value))


def write_batch(frame, out: Path, filename: str) -> Path:
    """Write a batch table atomically to ``out/results/filename`` (:func:`gbo_envs.atomic_write.atomic_write`)."""
    path = Path(out) / RESULTS_DIR / filename
    with atomic_write(path, "wb") as handle:
        frame.to_parquet(handle, index=False)
    return path


# -- backends -----------------------------------------------------------------------------------------
def _local(tasks: list[BatchTask], workers: int) -> Iterator:
    if workers == 1:
        for task in tasks:
            yield _safe_run_batch(task)
        return

    # the workers end with this process, also when it is killed (SIGKILL), instead of finishing their batches
    parallel = Parallel(n_jobs=workers, return_as="generator_unordered", batch_size=1, initializer=die_with_parent,
                        initargs=(os.getpid(),))
    yield from parallel(delayed(_safe_run_batch)(task) for task in tasks)


def _dask(tasks: list[BatchTask], workers: int, address: str | None) -> Iterator:
    from distributed import Client, LocalCluster, as_completed  # heavy optional dependency: dask

    cluster = None
    if address:
        client = Client(address)
    else:
        with _sigint_ignored():  # Ctrl-C stops the client loop below, not the workers mid-batch
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0")
        client = Client(cluster)
    futures = [client.submit(_safe_run_batch, task, pure=False) for task in tasks]
    try:
        for future in as_completed(futures):
            yield future.result()
    finally:
        client.cancel(futures)
        client.close()
        if cluster is not None:
            cluster.close()


class _sigint_ignored:
    """Processes started inside inherit an ignored SIGINT (main thread only; no-op elsewhere)."""

    def __enter__(self):
        try:
            self._previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
        except ValueError:  # not the main thread
            self._previous = None
        return self

    def __exit__(self, *exc):
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
        return False


# -- a whole study ------------------------------------------------------------------------------------
def run_study(study: Study, out: Path | str | None = None, backend: str = "local", address: str | None = None,
              workers: int | None = None, progress: bool | None = False, log=None) -> StudyRun:
    """Run every unfinished batch of ``study`` and write each one as it finishes.

    Parameters
    ----------
    study : Study
    out : Path, optional
        Output folder (default :func:`default_out_dir`).
    backend : {"local", "dask"}
        ``"local"``: joblib worker processes on this machine. ``"dask"``: a
        ``dask.distributed`` scheduler at ``address``, or a new LocalCluster.
    address : str, optional
        Scheduler address for ``backend="dask"`` (e.g. ``"tcp://10.0.0.5:8786"``);
        its workers need this package installed.
    workers : int, optional
        Worker processes (default: all cores; ignored with a dask ``address``).
        ``1`` runs the batches in this process, one after the other.
    progress : bool or None, default False
        Show a tqdm bar on stderr (batches done, ETA); ``None``: only when stderr is a terminal
        (:func:`agents.run_display.progress_bar`).
    log : callable, optional
        Message sink (default ``print`` to stderr).

    Returns
    -------
    StudyRun
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    if address and backend != "dask":
        raise ValueError("address: only used with backend='dask'")
    if workers is not None:
        workers = validated_count("workers", workers, low=1)
    log = log or (lambda message: print(message, file=sys.stderr))
    out = Path(out) if out is not None else default_out_dir(study)
    tasks = plan_batches(study)  # raises on unknown tuners or rejected params before anything is written
    out.mkdir(parents=True, exist_ok=True)
    if study.text:
        suffix = study.path.suffix if study.path is not None else ".toml"
        with atomic_write(out / f"study{suffix}") as handle:
            handle.write(study.text)
    done = finished_files(out) | kept_files(out)
    pending = [task for task in tasks if task.filename not in done]
    run = StudyRun(out=out, total=len(tasks), skipped=len(tasks) - len(pending))
    if run.skipped:
        log(f"{study.name}: {run.skipped} of {run.total} batches already finished in {out / RESULTS_DIR}; "
            "running the rest")
    if not pending:
        return run
    workers = workers or os.cpu_count() or 1
    workers = max(1, min(workers, len(pending)))
    start = time.perf_counter()
    bar = progress_bar(run.total, study.name, progress, initial=run.skipped, unit="batch")
    results: Iterable = _local(pending, workers) if backend == "local" else _dask(pending, workers, address)
    try:
        for task, frame, error in results:
            if error is None:
                write_batch(frame, out, task.filename)
                run.completed += 1
            else:
                run.failed.append((task.filename, error))
                log(f"{study.name}: batch {task.batch} of '{task.label}' failed (not written):\n{error}")
            bar.update(1)
    except KeyboardInterrupt:
        run.interrupted = True
        log(f"\n{study.name}: interrupted; {run.skipped + run.completed} of {run.total} batches are saved in "
            f"{out / RESULTS_DIR}; rerun the same command to resume")
    finally:
        close = getattr(results, "close", None)
        if close is not None:
            try:
                close()
            except Exception:  # pragma: no cover - best effort while shutting down workers
                pass
        bar.close()
        run.wall_time = time.perf_counter() - start
        _append_run_log(out, run, backend, workers, address)
    return run


def _append_run_log(out: Path, run: StudyRun, backend: str, workers: int, address: str | None) -> None:
    entry = {"finished": time.strftime("%Y-%m-%dT%H:%M:%S"), "backend": backend, "address": address,
             "workers": workers, "batches_run": run.completed, "batches_failed": len(run.failed),
             "interrupted": run.interrupted, "wall_time": round(run.wall_time, 3), "python": sys.version.split()[0],
             "cpu_count": os.cpu_count()}
    with open(out / "runs.jsonl", "a", encoding="utf-8") as handle:
        handle.write(json.dumps(entry) + "\n")
