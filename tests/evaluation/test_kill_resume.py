"""SIGKILL ``gbo tune`` at random points, resume after each kill: nothing lost, nothing doubled, same proposals.

The trial itself lives in ``benchmarks/bench_kill_resume.py`` (which prints the
same figures as JSON); see its docstring for what is killed and counted.
"""

from __future__ import annotations

import importlib.util
import json
import sys

import pytest

from tests.support import REPO_ROOT

pytestmark = [pytest.mark.skipif(sys.platform == "win32", reason="SIGKILL and forkserver are POSIX"), pytest.mark.slow]


def _bench():
    path = REPO_ROOT / "benchmarks" / "bench_kill_resume.py"
    spec = importlib.util.spec_from_file_location("bench_kill_resume", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _check(figures: dict, kills: int, budget: int) -> None:
    print("kill-and-resume figures:", json.dumps(figures))
    assert figures["kills"] >= kills and figures["kills_survived"] == figures["kills"]
    assert figures["completed"] == budget  # exactly the budgeted experiments ...
    assert figures["lost"] == 0 and figures["duplicated"] == 0  # ... none lost, none twice
    assert figures["experiment_numbers_ok"]  # numbered 1..budget in order
    assert figures["proposals_equal"]  # gains and costs equal those of an uninterrupted run with the seed
    assert figures["twin_rows_ok"]  # the tuner's twin rows: one per ask and per tell, none lost or doubled
    assert figures["integrity"] == "ok"


def test_sigkill_at_24_random_points_then_resume(tmp_path):
    # every run is forked from a server that imported the package once, so 24 kills take seconds
    figures = _bench().kill_resume_trial(tmp_path, kills=24, budget=36, seed=11, experiment_s=0.04, rng_seed=1,
                                         launcher="fork")
    _check(figures, kills=24, budget=36)
    assert figures["lost_in_crash"] >= 1  # some kills landed inside an experiment, after its intent


def test_sigkill_of_fresh_interpreters_then_resume(tmp_path):
    # the same with `python script.py` processes (the real start-up path), fewer kills to stay fast
    figures = _bench().kill_resume_trial(tmp_path, kills=3, budget=12, seed=3, experiment_s=0.04, rng_seed=2,
                                         launcher="subprocess")
    _check(figures, kills=3, budget=12)
