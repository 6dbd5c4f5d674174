"""SIGKILL ``gbo export`` while it overwrites an existing CSV, and check the file after each kill.

A database holds two sessions of ``--experiments`` plant experiments each. The
CSV of the first is written to ``data.csv``; then ``gbo export`` of the second
session over ``data.csv`` is started as a fresh interpreter and killed with
SIGKILL, ``--kills`` times (the old content is put back before each run): at a
random time after it starts writing (a temporary file beside ``data.csv``
appears, or ``data.csv`` itself changes), up to 1.2 times the time an unkilled
export takes to write, so that most kills land inside the write. After
each kill the file must be byte for byte the complete old or the complete new
export, and :func:`agents.twin.csvio.read_csv` must read it.

Prints one JSON object: ``kills`` delivered, how many left the ``old`` and the
``new`` content, ``torn`` (neither: a partial file), ``unreadable`` (read_csv
raised), ``stray_tmp`` (temporary files left beside it by kills inside the write;
harmless, they never replace the file; removed before the next run), ``export_s`` (wall time of one unkilled export)
``write_s`` (its time from the first write to the end) and ``wall_s``. Usage:
``python benchmarks/bench_export_kill.py [--kills 20] [--experiments 30]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ENV = "gbo_envs/DCMotor-v0"


def _gbo(*argv: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    return subprocess.Popen([sys.executable, "-m", "evaluation.cli", *argv], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, env=env)


def _run(*argv: str) -> None:
    """``gbo ARGV`` in this process (the set-up; only the killed exports get their own interpreter)."""
    from evaluation.cli import main as gbo

    with contextlib.redirect_stdout(io.StringIO()):
        code = gbo(list(argv))
    if code != 0:
        raise RuntimeError(f"gbo {' '.join(argv)} failed (exit {code})")


def _wait_for_write(proc: subprocess.Popen, csv: Path) -> float:
    """Wait until ``proc`` starts writing ``csv`` (a temporary file beside it, or ``csv`` changed); the time then."""
    before = csv.stat()
    while proc.poll() is None:
        now = csv.stat() if csv.exists() else None
        if any(csv.parent.glob(f".{csv.name}.*")) or now is None or (now.st_size, now.st_mtime_ns) != (
                before.st_size, before.st_mtime_ns):
            break
        time.sleep(0.001)
    return time.perf_counter()


def export_kill_trial(workdir: Path, kills: int = 20, experiments: int = 30, rng_seed: int = 0) -> dict:
    """Run the trial in ``workdir``; return the tally (see the module docstring)."""
    from agents.twin.csvio import read_csv

    start = time.perf_counter()
    workdir = Path(workdir)
    db, csv = workdir / "runs.sqlite", workdir / "data.csv"
    for seed in (0, 1):
        _run("tune", "--env", ENV, "--tuner", "random", "--budget", str(experiments), "--seed", str(seed),
             "--db", str(db), "--no-progress")
    _run("export", "--db", str(db), "--session", "2", "--csv", str(csv))
    new = csv.read_bytes()
    _run("export", "--db", str(db), "--session", "1", "--csv", str(csv))
    old = csv.read_bytes()
    tick = time.perf_counter()
    proc = _gbo("export", "--db", str(db), "--session", "2", "--csv", str(csv))
    writing = _wait_for_write(proc, csv)
    proc.communicate()
    export_s, write_s = time.perf_counter() - tick, time.perf_counter() - writing

    rng = np.random.default_rng(rng_seed)
    tally = {"kills": 0, "old": 0, "new": 0, "torn": 0, "unreadable": 0, "finished_before_kill": 0, "stray_tmp": 0}
    while tally["kills"] < kills:
        for stray in workdir.glob(f".{csv.name}.*"):  # left by the last kill; removed so that the next run's shows
            stray.unlink()
            tally["stray_tmp"] += 1
        csv.write_bytes(old)
        proc = _gbo("export", "--db", str(db), "--session", "2", "--csv", str(csv))
        _wait_for_write(proc, csv)
        time.sleep(rng.uniform(0.0, 1.2 * write_s))
        if proc.poll() is not None:
            tally["finished_before_kill"] += 1
            continue
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        tally["kills"] += 1
        content = csv.read_bytes()
        kind = "old" if content == old else "new" if content == new else "torn"
        tally[kind] += 1
        try:
            read_csv(csv, gain_names=("Kp", "Ki"))
        except ValueError:
            tally["unreadable"] += 1
    tally["stray_tmp"] += len(list(workdir.glob(f".{csv.name}.*")))
    tally["export_s"], tally["write_s"] = round(export_s, 2), round(write_s, 2)
    tally["wall_s"] = round(time.perf_counter() - start, 1)
    return tally


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=20)
    parser.add_argument("--experiments", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        return export_kill_trial(Path(tmp), kills=args.kills, experiments=args.experiments, rng_seed=args.seed)


if __name__ == "__main__":
    print(json.dumps(main()))
