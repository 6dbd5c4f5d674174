"""Time the resume of a tuning session after ``n`` stored experiments (CPU time of the resume).

A session of ``--tuner`` on ``--env`` is run to ``--stored`` plant experiments
(default 30) in a fresh database; then a new process-level session object with
the same specification resumes it, as a rerun of ``gbo tune`` after a crash
does, and the CPU time (``time.process_time``, this process only) of bringing
the tuner back to its state is measured:

* ``resume_cpu_s``: :meth:`evaluation.sessions.SessionRecorder.resume` alone
  (the tuner set up and the env reset first, as :meth:`agents.Tuner.run` does);
* ``rerun_cpu_s``: a whole rerun of the finished session
  (:meth:`evaluation.sessions.TuningSession.run`: open, resume, nothing to
  run, read the result back);
* ``next_equal``: the proposal after the resume equals that of the tuner
  which ran the session without stopping;
* ``snapshot_bytes``: size of the stored tuner snapshot (None on code
  without snapshots).

Prints one JSON object, ``{"tuners": [figures per tuner]}``. Usage:
``python benchmarks/bench_resume.py [--tuner bo] [--tuner guided-bo] [--stored 30]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import gbo_envs  # noqa: F401  (registers the envs)
from agents.space import GainSpace
from evaluation.sessions import SessionRecorder, SessionStore, TuningSession


def resume_figures(workdir: Path, tuner: str, env_id: str = "gbo_envs/DCMotor-v0", stored: int = 30,
                   seed: int = 0) -> dict:
    """Store ``stored`` experiments of ``tuner`` in ``workdir`` and time their resume (see the module docstring)."""
    db = Path(workdir) / f"{tuner}.sqlite"
    start = time.process_time()
    first = TuningSession(db, env_id, tuner, budget=stored, seed=seed)
    first.run()
    run_cpu = time.process_time() - start
    expected = first.tuner.ask()  # the uninterrupted tuner's next proposal

    session = TuningSession(db, env_id, tuner, budget=stored, seed=seed)
    with SessionStore(db) as store:
        info = store.open_session(session.key, session.spec, session.space.names)
        recorder = SessionRecorder(store, info.id)
        start = time.process_time()
        session.tuner.setup(GainSpace.from_env(session.env), seed=seed, env=session.env)
        session.env.reset(seed=seed)
        told, _ = recorder.resume(session.tuner, session.env)
        resume_cpu = time.process_time() - start
        snapshot = store.snapshot(info.id) if hasattr(store, "snapshot") else None
        store.release_session(info.id, "done")
    next_equal = session.tuner.ask() == expected

    rerun = TuningSession(db, env_id, tuner, budget=stored, seed=seed)
    start = time.process_time()
    rerun.run()
    rerun_cpu = time.process_time() - start
    return {"tuner": tuner, "env": env_id, "stored": told, "run_cpu_s": round(run_cpu, 3),
            "resume_cpu_s": round(resume_cpu, 3), "rerun_cpu_s": round(rerun_cpu, 3), "next_equal": next_equal,
            "snapshot_bytes": None if snapshot is None else len(snapshot[1])}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tuner", action="append", default=None, help="registry name; repeatable (default: bo)")
    parser.add_argument("--env", default="gbo_envs/DCMotor-v0")
    parser.add_argument("--stored", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for tuner in args.tuner or ["bo"]:
            figures = resume_figures(Path(tmp), tuner, env_id=args.env, stored=args.stored, seed=args.seed)
            print(json.dumps(figures), file=sys.stderr, flush=True)
            out.append(figures)
    return {"tuners": out}


if __name__ == "__main__":
    print(json.dumps(main()))
