"""Worker processes end with their parent, also when it is killed with SIGKILL (issue 57: loky workers and
resource trackers outlived a killed ``gbo bench`` by minutes, holding the caller's pipes)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from tests.support import REPO_ROOT

PARENT = """
import multiprocessing, os, sys, time
from joblib import Parallel, delayed
from agents.process_lifetime import die_with_parent

def sleep(seconds):
    time.sleep(seconds)
    return os.getpid()

if __name__ == "__main__":
    if sys.argv[1] == "fork":
        pool = multiprocessing.get_context("fork").Pool(2, initializer=die_with_parent, initargs=(os.getpid(),))
        print(*set(pool.map(sleep, [0.2] * 4, chunksize=1)), flush=True)
        pool.map_async(sleep, [60, 60])
    else:
        out = Parallel(n_jobs=2, return_as="generator_unordered", initializer=die_with_parent,
                       initargs=(os.getpid(),))(delayed(sleep)(s) for s in [0.5, 0.5, 60, 60])
        print(next(out), next(out), flush=True)
    time.sleep(120)
"""


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as handle:
            return handle.read().rpartition(")")[2].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
@pytest.mark.parametrize("pool", ["fork", "loky"])
def test_busy_workers_die_within_seconds_of_a_sigkill_of_their_parent(tmp_path, pool):
    script = tmp_path / "parent.py"
    script.write_text(PARENT)
    parent = subprocess.Popen([sys.executable, str(script), pool], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(REPO_ROOT)})
    workers = {int(pid) for pid in parent.stdout.readline().split()}
    assert workers and all(alive(pid) for pid in workers)
    os.kill(parent.pid, signal.SIGKILL)  # the parent alone, as a crash or the OOM killer ends it
    parent.wait()
    deadline = time.monotonic() + 5.0
    while any(alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(alive(pid) for pid in workers), [pid for pid in workers if alive(pid)]
    parent.stdout.close()
