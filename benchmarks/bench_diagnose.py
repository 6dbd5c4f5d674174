"""Speed of ``gbo twin diagnose``: 12 experiments of 2,501 samples (issues 15 and 37).

Prints one JSON object per case: the wall time, the CPU time and the peak resident size of
:func:`agents.twin.workbench.diagnose` (every catalogued effect tried, ranked by 4-fold
cross-validation over experiments) with the data's size, the named effect, the ranking and
the RMSEs (rad/s). Cases, each 12 experiments of DCMotor-v0's PI loop at random gains
(uniform on the action space, seed 0):

* ``dcmotor_<effect>`` for every effect of the catalogue (``gbo_envs.physics.EFFECT_NAMES``):
  that one effect hidden in the plant (:data:`HIDDEN`), sensor noise 0.1 rad/s. Effects that
  only show when the speed and the command change sign (``coulomb_friction``, ``stiction``,
  ``backlash``, ``dead_zone``) step the reference from -30 to +30 rad/s through zero speed
  (the env's loop with another ``r1, r2``); the others use the env's 245 -> 306 rad/s step;
* ``dcmotor_saturation_0.3``: saturation (limit 150) with sensor noise 0.3 rad/s (issue 15's case);
* ``dcmotor_rig``: DCMotorRig-v0 (saturation 160, Coulomb friction 5, speed encoder; no
  speed reversal, so friction acts as a constant load).

The issue's target is at most 8 s per case on the project machine (2 cores), goal 3 s, with a
peak resident size of at most 400 MB::

    python benchmarks/bench_diagnose.py                      # every case, once, in this process
    python benchmarks/bench_diagnose.py --case dcmotor_stiction --repeat 3
    python benchmarks/bench_diagnose.py --command --repeat 3  # the gbo command a user runs

In-process runs (default) time :func:`~agents.twin.workbench.diagnose` on the case's data,
after one call of :func:`gbo_envs.physics.kernels.warm_up` that compiles (or loads from
numba's cache) the compiled simulation; its time is printed apart as ``compile_s``.
``peak_rss_mb`` is the process's peak so far (``ru_maxrss``), so run one case per process
to read it per case.

``--command`` writes each case's records to a CSV (in ``--data DIR`` if given, so that another
tree runs on the same data) and times the whole ``gbo twin diagnose FILE --quiet`` process
(start-up, reading, the diagnosis in its worker processes, the advice), each run its own child
(``os.wait4``): wall time, CPU time (user + system, the worker processes included), system time,
minor page faults, peak resident size (``peak_rss_mb``: the largest single process) and, with
``--pss``, the peak of the processes' proportional set sizes summed (``peak_pss_mb``: the memory the
command takes, the pages its forked workers share with it counted once; sampled every 0.1 s, needs
psutil; the sampling slows the command by about 1 s, so time it in a run without ``--pss``). The
children share one fresh numba cache folder (``NUMBA_CACHE_DIR``). First, apart, a child
compiles the kernels into it (``compile_s``: what a user's very first command pays once) and
another loads them from it (``cache_load_s``: what every later command pays); a tree without
compiled kernels (before issue 37) prints ``compile_s: null``::

    python benchmarks/bench_diagnose.py --command --repeat 3 --data out/bench_diagnose
    PYTHONPATH=/path/to/other/tree python benchmarks/bench_diagnose.py --command --repeat 3 --data out/bench_diagnose

``--csv FILE`` times the command on records of your own (a real machine's, or ``benchmarks/real_like_sets.py``'s),
and ``--effects NAMES`` a later step of the ladder, the model already holding those effects::

    python benchmarks/real_like_sets.py --out out/real_like
    python benchmarks/bench_diagnose.py --command --repeat 3 --csv out/real_like/belt_tacho.csv --effects input_map
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import gymnasium as gym
import numpy as np

import gbo_envs  # noqa: F401  (registers the envs)

# The workbench's modules are imported where the records are made or diagnosed in this process: with
# --command on CSVs that exist, an older tree (PYTHONPATH) is timed though it lacks them (3345589 has
# no agents.twin.data).
if TYPE_CHECKING:
    from agents.twin.records import Batch

#: Reference step through zero speed, for the effects that need a speed (and command) reversal.
REVERSAL = (-30.0, 30.0)

#: The hidden effect of each ``dcmotor_<effect>`` case: its parameters and its reference step (None: the env's).
HIDDEN = {
    "time_delay": ({"delay": 0.03}, None),
    "saturation": ({"limit": 150.0}, None),
    "dead_zone": ({"width": 20.0}, REVERSAL),
    "coulomb_friction": ({"torque": 8.0}, REVERSAL),
    "viscous_friction": ({"coefficient": 0.05}, None),
    "stiction": ({"breakaway": 10.0, "threshold": 1.0}, REVERSAL),
    "backlash": ({"width": 6.0}, REVERSAL),
    "quantization": ({"step": 1.534, "mode": "floor"}, None),
    "drift": ({"rate": -0.06, "parameter": "gain"}, None),
    "offset": ({"value": 5.0}, None),
    "cogging": ({"amplitude": 10.0, "period": 2.0 * np.pi}, None),
    # a flexible coupling at 15 rad/s, damping 0.1 (the test suite's and the beyond-catalogue study's rig)
    "compliance": ({"frequency": 15.0, "damping": 0.1}, None),
}

#: case -> (env id, make kwargs, reference step or None)
CASES = {f"dcmotor_{name}": ("gbo_envs/DCMotor-v0", {"effects": {name: params}, "output_noise_std": 0.1}, step)
         for name, (params, step) in HIDDEN.items()}
CASES["dcmotor_saturation_0.3"] = ("gbo_envs/DCMotor-v0", {"effects": {"saturation": {"limit": 150.0}},
                                                           "output_noise_std": 0.3}, None)
CASES["dcmotor_rig"] = ("gbo_envs/DCMotorRig-v0", {}, None)

TARGET_S = 8.0
TARGET_RSS_MB = 400.0


def case_records(case: str, n_experiments: int = 12, seed: int = 0) -> tuple[list, tuple[str, ...]]:
    """The records of ``case`` at ``n_experiments`` random gains (uniform on the env's action space), and
    the env's gain names."""
    from agents.twin.csvio import records_from_loop

    env_id, kwargs, step = CASES[case]
    env = gym.make(env_id, **kwargs)
    low, high = env.action_space.low, env.action_space.high
    gains = np.random.default_rng(seed).uniform(low, high, size=(n_experiments, low.size))
    loop = env.unwrapped.loop if step is None else env.unwrapped.loop.replace(r1=step[0], r2=step[1])
    return records_from_loop(loop, gains, rng=np.random.default_rng(seed)), env.unwrapped.gain_names


def case_data(case: str, n_experiments: int = 12, seed: int = 0) -> Batch:
    """:func:`case_records` as the workbench's data."""
    from agents.twin.records import Batch

    return Batch.from_records(case_records(case, n_experiments, seed)[0])


def _warm_up() -> float | None:
    """Seconds to compile (or load from the cache) the compiled simulation; None on a tree without it."""
    try:
        from gbo_envs.physics.kernels import warm_up
    except ImportError:
        return None
    return round(warm_up(), 2)


def main(case: str = "dcmotor_saturation", n_experiments: int = 12, seed: int = 0, repeat: int = 1) -> dict:
    from agents.twin.workbench import diagnose

    compile_s = _warm_up()
    data = case_data(case, n_experiments, seed)
    times, cpu = [], []
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        result = diagnose(data)
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    out = result.to_dict()
    top = out["candidates"][0] if out["candidates"] else None
    return {"benchmark": "diagnose", "case": case, "n_experiments": data.n_records,
            "n_samples_per_experiment": int(data.u.shape[1]), "n_candidates": len(out["candidates"]),
            "time_s": round(float(np.median(times)), 2), "times_s": [round(t, 2) for t in times],
            "target_s": TARGET_S, "cpu_s": round(float(np.median(cpu)), 2), "cpus_s": [round(t, 2) for t in cpu],
            "compile_s": compile_s, "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
            "load": round(os.getloadavg()[0], 2),
            "best": out["best"], "ranking": [c["effect"] for c in out["candidates"]],
            "rmse": out["rmse"], "heldout_rmse": out["heldout_rmse"],
            "top_candidate": None if top is None else top["effect"],
            "top_params": None if top is None else top["params"],
            "rmse_top": None if top is None else top["train_rmse"],
            "heldout_rmse_top": None if top is None else top["rmse"], "noise_rmse": out["noise_rmse"]}


def _run_child(args: list[str], env: dict, pss: bool = False) -> tuple[float, resource.struct_rusage, str, int | None]:
    """Wall time, resource usage, standard output and peak total PSS (MB) of one child process (``os.wait4``: its
    own figures, with ``ru_maxrss`` the largest of it and its worker processes). With ``pss``, the largest sum,
    sampled every 0.1 s, of the proportional set sizes of the child and its worker processes (the memory they take
    together, the pages they share counted once; needs psutil, else ``None``); without, ``None``."""
    start = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out:
        proc = subprocess.Popen(args, stdout=out, stderr=subprocess.DEVNULL, text=True, env=env)
        sampler, memory = None, {}
        if pss:
            done = threading.Event()
            sampler = threading.Thread(target=_sample_pss, args=(proc.pid, done, memory), daemon=True)
            sampler.start()
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        if sampler is not None:
            done.set()
            sampler.join()
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            raise subprocess.CalledProcessError(proc.returncode, args)
        out.seek(0)
        return wall, usage, out.read(), memory.get("peak_pss_mb")


def _sample_pss(pid: int, done: threading.Event, memory: dict) -> None:
    """Peak total PSS (MB) of process ``pid`` and its descendants until ``done``, into ``memory["peak_pss_mb"]``."""
    try:
        import psutil  # installed with the distributed extra (dask)
    except ImportError:
        memory["peak_pss_mb"] = None
        return
    peak = 0.0
    while not done.wait(0.1):
        total = 0
        try:
            root = psutil.Process(pid)
            for p in [root, *root.children(recursive=True)]:
                total += p.memory_full_info().pss
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
            continue  # a process ended between the listing and the reading: the next sample
        peak = max(peak, total / 2**20)
    memory["peak_pss_mb"] = round(peak)


def compile_child(env: dict) -> dict:
    """A fresh process compiling the kernels into the (empty) cache of ``env``, then one loading them from it."""
    args = [sys.executable, "-c", "from gbo_envs.physics.kernels import warm_up; print(warm_up())"]
    out = {"benchmark": "diagnose_compile"}
    for label in ("compile", "cache_load"):
        try:
            wall, usage, stdout, _ = _run_child(args, env)
        except subprocess.CalledProcessError:  # a tree without compiled kernels
            return {**out, "compile_s": None}
        out[f"{label}_s"] = round(float(stdout.strip()), 2)
        out[f"{label}_process_cpu_s"] = round(usage.ru_utime + usage.ru_stime, 2)
    return out


def command(case: str = "dcmotor_saturation", n_experiments: int = 12, seed: int = 0, repeat: int = 1,
            env: dict | None = None, data: Path | None = None, pss: bool = False, csv: Path | None = None,
            effects: str | None = None) -> dict:
    """``gbo twin diagnose`` on the records of ``case`` as a user runs it, timed as a whole process.

    ``data``: a folder holding the case's CSV (written there first if missing), so that other trees
    run on the same data; by default a temporary one. ``pss``: also sample the processes' total PSS
    (the sampling slows the command by about 1 s on the project machine: time it in another run).
    ``csv``: a CSV of your own to diagnose instead of the case's records; ``effects``: the effects already
    in the model (``--effects``, a step further down the ladder).
    """
    runs = []
    with tempfile.TemporaryDirectory() as folder:
        path = Path(csv) if csv is not None else Path(data or folder) / f"{case}.csv"
        if csv is None and not path.exists():
            from agents.twin.csvio import write_csv

            records, gain_names = case_records(case, n_experiments, seed)
            write_csv(records, path, gain_names=gain_names)
        args = [sys.executable, "-m", "evaluation.cli", "twin", "diagnose", str(path), "--quiet",
                *(["--effects", effects] if effects else [])]
        for _ in range(repeat):
            load = os.getloadavg()[0]
            wall, usage, stdout, peak_pss = _run_child(args, env or dict(os.environ), pss)
            runs.append({"wall_s": round(wall, 2), "cpu_s": round(usage.ru_utime + usage.ru_stime, 2),
                         "system_s": round(usage.ru_stime, 2), "minor_faults": usage.ru_minflt,
                         "peak_rss_mb": round(usage.ru_maxrss / 1024), "peak_pss_mb": peak_pss,
                         "load": round(load, 2)})
    best = next((line for line in stdout.splitlines() if line.startswith("best:")), None)
    return {"benchmark": "diagnose_command", "case": case if csv is None else str(csv), "effects": effects,
            "n_experiments": n_experiments,
            "time_s": float(np.median([r["wall_s"] for r in runs])),
            "cpu_s": float(np.median([r["cpu_s"] for r in runs])),
            "peak_rss_mb": max(r["peak_rss_mb"] for r in runs),
            "peak_pss_mb": max((r["peak_pss_mb"] for r in runs if r["peak_pss_mb"] is not None), default=None),
            "target_s": TARGET_S,
            "target_rss_mb": TARGET_RSS_MB, "runs": runs, "best": best}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=[*CASES, "all"], default="all")
    parser.add_argument("--experiments", type=int, default=12)
    parser.add_argument("--repeat", type=int, default=1, help="runs per case; the median time is printed")
    parser.add_argument("--command", action="store_true", help="time the gbo twin diagnose command instead")
    parser.add_argument("--pss", action="store_true", help="with --command: also sample the total PSS of the command "
                                                           "and its worker processes (slows it by about 1 s)")
    parser.add_argument("--data", type=Path, help="with --command: folder of the cases' CSV files (written if "
                                                  "missing), to run other trees on the same data")
    parser.add_argument("--csv", type=Path, action="append", default=[],
                        help="with --command: time the diagnosis of this CSV instead of the cases (repeatable)")
    parser.add_argument("--effects", help="with --command: the effects already in the model, as gbo twin "
                                          "diagnose --effects takes them (a later step of the ladder)")
    args = parser.parse_args()
    if (args.csv or args.effects) and not args.command:
        parser.error("--csv and --effects time the command: add --command")
    missing = [str(path) for path in args.csv if not path.is_file()]
    if missing:
        parser.error(f"--csv: no such file: {', '.join(missing)}")
    names = list(CASES) if args.case == "all" else [args.case]
    if args.command:
        with tempfile.TemporaryDirectory() as cache:  # a fresh numba cache: the compile is measured, then loaded
            child_env = dict(os.environ, NUMBA_CACHE_DIR=cache)
            print(json.dumps(compile_child(child_env)), flush=True)
            for name, csv in ([(path.stem, path) for path in args.csv] or [(name, None) for name in names]):
                print(json.dumps(command(name, args.experiments, repeat=args.repeat, env=child_env, data=args.data,
                                         pss=args.pss, csv=csv, effects=args.effects)), flush=True)
    else:
        for name in names:
            print(json.dumps(main(name, args.experiments, repeat=args.repeat)), flush=True)
