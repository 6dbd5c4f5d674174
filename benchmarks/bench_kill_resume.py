"""Kill ``gbo tune`` with SIGKILL at random points, resume after each kill, and count what was lost.

Prints one JSON object:

* ``kills``: SIGKILLs delivered (each followed by a resume); ``kills_survived``
  equals it when every resume went on from the database;
* ``budget``, ``completed``: plant experiments asked for and stored as done;
* ``lost``: budgeted experiments missing at the end (``budget - completed``);
* ``duplicated``: experiment numbers stored twice (should be 0);
* ``proposals_equal``: whether the gains (and costs) match an uninterrupted
  run with the same seed, experiment by experiment;
* ``lost_in_crash``: experiments whose intent was committed but whose result
  was cut by a kill (each was run again on resume, as the crash policy says);
* ``twin_rows_ok``: every experiment has exactly one twin row from ``ask`` and
  one from ``tell`` (none lost or doubled by the replay);
* ``integrity``: ``PRAGMA integrity_check`` of the killed database;
* ``wall_s``: wall time of the whole trial.

The session runs a cost-aware random search (its random draws depend on the
costs it is told, so a wrong replay shows) on DCMotor-v0 with default noise,
slowed to ``experiment_s`` per experiment so that kills land inside
experiments as well as between them. Each run is a script calling
``evaluation.cli.main(["tune", ...])``, started as a fresh interpreter
(``--launcher subprocess``, default) or forked from a preloaded forkserver
(``--launcher fork``, what the test uses to stay fast). Usage:
``python benchmarks/bench_kill_resume.py [--kills 20] [--budget 30] [--launcher subprocess]``.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: A module the killed process imports (``--import killtest_plugin``): a slow env and a cost-aware tuner.
PLUGIN = '''
import time

import numpy as np
from gymnasium.envs.registration import register

import agents
from agents.base import Tuner
from gbo_envs.envs.dc_motor import DCMotorEnv


class SlowDCMotor(DCMotorEnv):
    """DCMotor-v0 whose experiments take ``experiment_s`` of wall time (the plant "runs")."""

    def __init__(self, experiment_s=0.05, **kwargs):
        super().__init__(**kwargs)
        self.experiment_s = experiment_s

    def step(self, action):
        time.sleep(self.experiment_s)
        return super().step(action)


class CostAwareRandom(Tuner):
    """Random search with an extra draw after each improvement and a twin row per ask and tell."""

    name = "killtest-random"

    def __init__(self):
        self._params = {}

    def _setup(self):
        self.best = np.inf

    def _ask(self):
        point = self.rng.uniform(self.space.low, self.space.high)
        self.log_twin(point, 0.0, phase="ask")
        return point

    def _tell(self, gains, cost, record):
        if cost < self.best:
            self.best = cost
            self.rng.random()
        self.log_twin(gains, cost, phase="tell", n_samples=int(record["y"].size))


register(id="killtest/SlowDCMotor-v0", entry_point=SlowDCMotor, max_episode_steps=1000)
agents.register("killtest-random", CostAwareRandom)
'''


SCRIPT = """
import os
import sys

sys.path.insert(0, {workdir!r})
sys.stdout = open(os.devnull, "w")  # the summary lines; stdout of the benchmark is its JSON
from evaluation.cli import main

raise SystemExit(main({argv!r}))
"""

#: Modules a forkserver imports once, so that a forked ``gbo tune`` starts in milliseconds.
PRELOAD = ["numpy", "scipy.signal", "gymnasium", "tqdm", "gbo_envs", "agents", "agents.base", "evaluation.cli",
           "evaluation.tune_cli", "evaluation.sessions"]


def tune_script(workdir: Path, db: Path, budget: int, seed: int, experiment_s: float) -> Path:
    """A script running ``gbo tune`` (``evaluation.cli.main``) for the trial's session on ``db``."""
    argv = ["tune", "--env", "killtest/SlowDCMotor-v0", "--env-kwargs", json.dumps({"experiment_s": experiment_s}),
            "--tuner", "killtest-random", "--budget", str(budget), "--seed", str(seed), "--db", str(db),
            "--import", "killtest_plugin", "--no-progress"]
    path = workdir / f"tune_{db.stem}.py"
    path.write_text(SCRIPT.format(workdir=str(workdir), argv=argv))
    return path


class _Subprocess:
    """``python SCRIPT`` in a fresh interpreter."""

    def __init__(self, script: Path) -> None:
        self.proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, text=True)

    def poll(self) -> int | None:
        return self.proc.poll()

    def kill(self) -> None:
        os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait()  # reap it, so that its process id is free (the resume checks the owner is gone)

    def wait(self) -> tuple[int, str]:
        _, err = self.proc.communicate()
        return self.proc.returncode, err


class _Forked:
    """The same script run by ``runpy`` in a process forked from a forkserver that preloaded the imports."""

    context = None

    def __init__(self, script: Path) -> None:
        import multiprocessing
        import runpy

        if _Forked.context is None:
            _Forked.context = multiprocessing.get_context("forkserver")
            _Forked.context.set_forkserver_preload(PRELOAD)
        self.proc = _Forked.context.Process(target=runpy.run_path, args=(str(script),),
                                            kwargs={"run_name": "__main__"}, daemon=True)
        self.proc.start()

    def poll(self) -> int | None:
        return self.proc.exitcode

    def kill(self) -> None:
        os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.join()

    def wait(self) -> tuple[int, str]:
        self.proc.join()
        return self.proc.exitcode, "(see the test's captured stderr)"


#: A run that does not reach its kill point within this many seconds is a failure (s).
HANG_S = 120.0

#: How the killed process is started: a fresh interpreter, or a fork of a preloaded server (fast start-up).
LAUNCHERS = {"subprocess": _Subprocess, "fork": _Forked}


def _completed(db: Path) -> int:
    """Completed (told) plant experiments in the database, read without disturbing the writer."""
    if not db.exists():
        return 0
    try:
        conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
        try:
            return int(conn.execute("SELECT COUNT(*) FROM experiments WHERE source = 'plant' AND told = 1")
                       .fetchone()[0])
        finally:
            conn.close()
    except sqlite3.Error:  # the file exists but the schema is not committed yet
        return 0


def _plant_rows(db: Path) -> list[tuple]:
    conn = sqlite3.connect(str(db))
    try:
        return conn.execute("SELECT experiment, gains, cost FROM experiments WHERE source = 'plant' AND told = 1 "
                            "ORDER BY seq").fetchall()
    finally:
        conn.close()


def kill_resume_trial(workdir: Path, kills: int = 20, budget: int = 30, seed: int = 7, experiment_s: float = 0.04,
                      rng_seed: int = 0, launcher: str = "subprocess") -> dict:
    """Run the kill-and-resume trial in ``workdir``; return the figures (see the module docstring).

    ``launcher``: ``"subprocess"`` starts every run as ``python SCRIPT``;
    ``"fork"`` forks it from a forkserver that imported the package once (the
    same code and the same SIGKILL, without the interpreter start-up).
    """
    start = time.perf_counter()
    workdir = Path(workdir)
    (workdir / "killtest_plugin.py").write_text(PLUGIN)
    killed_db, reference_db = workdir / "killed.sqlite", workdir / "reference.sqlite"
    launch = LAUNCHERS[launcher]
    reference = launch(tune_script(workdir, reference_db, budget, seed, experiment_s))
    killed_script = tune_script(workdir, killed_db, budget, seed, experiment_s)

    rng = np.random.default_rng(rng_seed)
    # kill points spread over the run: after the k-th committed experiment plus a random part of the next one,
    # or (one kill in four) at a random time after launch - start-up, replay or an experiment - but never
    # later than the k-th experiment, so that the run cannot finish before all kills are delivered
    targets = np.linspace(1, budget - 2, kills).round().astype(int)
    delivered = 0
    while delivered < kills:
        target = int(targets[delivered])
        proc = launch(killed_script)
        hung = time.monotonic() + HANG_S
        at_random_time = rng.random() < 0.25
        deadline = time.monotonic() + rng.uniform(0.0, 2.0) if at_random_time else np.inf
        while _completed(killed_db) < target and proc.poll() is None and time.monotonic() < deadline:
            if time.monotonic() > hung:
                proc.kill()
                raise RuntimeError(f"gbo tune made no progress to experiment {target} in {HANG_S} s")
            time.sleep(0.005)
        if not at_random_time:
            time.sleep(rng.uniform(0.0, 1.5 * experiment_s))
        if proc.poll() is not None:  # finished (or failed) before the kill
            code, err = proc.wait()
            if code != 0:
                raise RuntimeError(f"gbo tune failed (exit {code}): {err}")
            break
        proc.kill()
        delivered += 1
    code, err = launch(killed_script).wait()
    if code != 0:
        raise RuntimeError(f"final resume failed (exit {code}): {err}")
    code, err = reference.wait()
    if code != 0:
        raise RuntimeError(f"reference run failed (exit {code}): {err}")

    rows, ref_rows = _plant_rows(killed_db), _plant_rows(reference_db)
    numbers = [row[0] for row in rows]
    conn = sqlite3.connect(str(killed_db))
    try:
        integrity = conn.execute("PRAGMA integrity_check").fetchone()[0]
        lost_in_crash = conn.execute("SELECT COUNT(*) FROM experiments WHERE status = 'lost-in-crash' "
                                     "AND source = 'plant'").fetchone()[0]
        twin_phases = conn.execute(
            "SELECT p.experiment, SUM(t.phase = 'ask'), SUM(t.phase = 'tell') FROM experiments p "
            "LEFT JOIN experiments t ON t.parent_id = p.id AND t.status = 'ok' "
            "WHERE p.source = 'plant' AND p.told = 1 GROUP BY p.id").fetchall()
    finally:
        conn.close()
    return {
        "kills": delivered,
        "kills_survived": delivered if len(rows) == budget else 0,
        "budget": budget,
        "completed": len(rows),
        "lost": budget - len(set(numbers)),
        "duplicated": len(numbers) - len(set(numbers)),
        "proposals_equal": [(r[1], r[2]) for r in rows] == [(r[1], r[2]) for r in ref_rows],
        "experiment_numbers_ok": numbers == list(range(1, budget + 1)),
        "lost_in_crash": int(lost_in_crash),
        "twin_rows_ok": len(twin_phases) == budget and all(a == 1 and t == 1 for _, a, t in twin_phases),
        "integrity": integrity,
        "launcher": launcher,
        "wall_s": round(time.perf_counter() - start, 1),
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=20)
    parser.add_argument("--budget", type=int, default=30)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--launcher", choices=sorted(LAUNCHERS), default="subprocess")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        return kill_resume_trial(Path(tmp), kills=args.kills, budget=args.budget, seed=args.seed,
                                 launcher=args.launcher)


if __name__ == "__main__":
    print(json.dumps(main()))
