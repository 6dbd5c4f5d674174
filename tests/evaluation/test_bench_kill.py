"""A ``gbo bench`` killed with SIGKILL takes its worker processes and their resource trackers with it
(issue 57: two loky workers and two resource trackers outlived it by minutes, holding the caller's pipes)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from tests.support import REPO_ROOT

SPEC = ('[study]\nname = "kill"\nbatches = 2\nbudget = 3\n[env]\nid = "gbo_envs/DCMotor-v0"\n'
        '[[tuners]]\nname = "random"\n[[tuners]]\nname = "grid"\n')


def loky_workers(sid: int) -> int:
    """How many of the session's processes are loky workers."""
    count = 0
    for pid in session_processes(sid):
        try:
            count += b"LokyProcess" in open(f"/proc/{pid}/cmdline", "rb").read()
        except OSError:
            continue
    return count


def session_processes(sid: int) -> list[int]:
    """Live processes of session ``sid`` (from ``/proc``; zombies have ended)."""
    pids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                fields = open(f"/proc/{entry}/stat").read().rpartition(")")[2].split()
            except OSError:
                continue
            if int(fields[3]) == sid and fields[0] != "Z":
                pids.append(int(entry))
    return pids


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG and /proc are Linux's")
def test_no_process_of_a_killed_bench_outlives_it_by_more_than_a_few_seconds(tmp_path):
    (tmp_path / "spec.toml").write_text(SPEC)
    bench = subprocess.Popen([sys.executable, "-m", "evaluation.cli", "bench", "spec.toml", "--workers", "2", "--out",
                              "o", "--quiet"], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             env={**os.environ, "PYTHONPATH": str(REPO_ROOT)}, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        saved = tmp_path / "o" / "results"  # a saved batch: the workers are past their start-up
        while (loky_workers(bench.pid) < 2 or not any(saved.glob("*.parquet"))) and bench.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.01)
        assert loky_workers(bench.pid) == 2, "the worker processes did not start"
        os.kill(bench.pid, signal.SIGKILL)  # the command alone, as a crash or the OOM killer ends it
        bench.wait()
        deadline = time.monotonic() + 5.0
        while session_processes(bench.pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert session_processes(bench.pid) == []
        bench.communicate(timeout=5)  # nothing holds its pipes any more
    finally:
        for pid in session_processes(bench.pid):
            os.kill(pid, signal.SIGKILL)
