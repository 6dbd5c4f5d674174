"""SIGKILL ``gbo export`` while it overwrites a CSV: the file is always the whole old or the whole new export.

The trial lives in ``benchmarks/bench_export_kill.py`` (20 kills there); see its docstring.
"""

from __future__ import annotations

import importlib.util
import sys

import pytest

from tests.support import REPO_ROOT

pytestmark = [pytest.mark.skipif(sys.platform == "win32", reason="SIGKILL is POSIX"), pytest.mark.slow]


def test_sigkill_during_export_never_leaves_a_partial_file(tmp_path):
    spec = importlib.util.spec_from_file_location("bench_export_kill", REPO_ROOT / "benchmarks" /
                                                  "bench_export_kill.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    tally = bench.export_kill_trial(tmp_path, kills=4, experiments=6, rng_seed=3)
    print("export kill tally:", tally)
    assert tally["kills"] == 4 and tally["old"] + tally["new"] == 4
    assert tally["torn"] == 0 and tally["unreadable"] == 0
