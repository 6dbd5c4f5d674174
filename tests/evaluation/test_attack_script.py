"""Smoke test of ``benchmarks/attack.py``: a handful of its fast cases, run in this process, come out clear.

The whole attack (130 cases in fresh interpreters under time, memory and process
limits) is a benchmark: ``python benchmarks/attack.py --out benchmarks/results/attack.md``.
Here: the cases exist for every item of issues 19 and 57, the classifier tells the
outcomes apart, and a few fast cases give a clear error.
"""

from __future__ import annotations

import importlib.util
import sys

import pytest

from tests.support import REPO_ROOT


@pytest.fixture(scope="module")
def attack():
    path = REPO_ROOT / "benchmarks" / "attack.py"
    spec = importlib.util.spec_from_file_location("attack", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["attack"] = module
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop("attack", None)


def test_the_cases_cover_every_item_of_the_issues(attack):
    assert len(attack.CASES) >= 120
    assert {case.item for case in attack.CASES} == set(range(1, 16))  # issue 19: 1-10, issue 57: 11-15
    assert {"hang", "data changed", "unclear message"} <= set(attack.FAILURES)


@pytest.mark.parametrize("case_id", ["folds-0", "json-tuner-kwargs-syntax", "csv-folder", "api-csv-binary",
                                     "study-name-dotdot", "env-module-colon", "jobs-negative-huge", "effects-twice",
                                     "budget-huge", "seed-huge", "poles-20", "record-timing-1-based"])
def test_fast_cases_give_a_clear_error(attack, tmp_path, case_id):
    case = next(c for c in attack.CASES if c.id == case_id)
    fixtures = tmp_path / "fixtures"
    fixtures.mkdir()
    outcome, run = attack.run_case(case, tmp_path, attack.Fixtures(fixtures), in_process=True)
    assert outcome == "clear error", (outcome, run.stderr, run.notes)


@pytest.mark.parametrize(("expect", "returncode", "stderr", "outcome"), [
    ("error", 2, "gbo x: error: --folds must be >= 2\n", "clear error"),
    ("error", 2, "gbo x: error: something\n", "unclear message"),  # does not name --folds
    ("error", 2, "line one\nline two\n", "unclear message"),
    ("error", 1, "Traceback (most recent call last):\n  ...\nKeyError: 1\n", "raw traceback"),
    ("error", 0, "", "silently wrong"),
    ("ok", 0, "", "correct result"),
    ("ok", 2, "gbo x: error: refused\n", "wrongly refused"),
    ("error", -9, "", "runaway"),
    ("error", 1, "Traceback (most recent call last):\nMemoryError\n", "runaway"),
])
def test_the_classifier_tells_the_outcomes_apart(attack, tmp_path, expect, returncode, stderr, outcome):
    case = attack.Case("c", 5, "t", ("x",), expect=expect, needles=("--folds",))
    run = attack.Run(returncode, "", stderr, 0.1)
    assert attack.classify(case, run, tmp_path, attack.Fixtures(tmp_path)) == outcome


def test_a_timeout_is_a_hang_when_blocked_and_a_runaway_when_computing(attack, tmp_path):
    case = attack.Case("c", 11, "t", ("x",), needles=("x",))
    fx = attack.Fixtures(tmp_path)
    blocked = attack.Run(None, "", "", 31.0, timed_out=True, cpu_seconds=0.0)  # in the second after the limit
    busy = attack.Run(None, "", "", 31.0, timed_out=True, cpu_seconds=0.4)  # a CPU shared with others
    assert attack.classify(case, blocked, tmp_path, fx) == "hang"
    assert attack.classify(case, busy, tmp_path, fx) == "runaway"


def test_too_many_processes_and_survivors_of_a_kill_are_runaways(attack, tmp_path):
    case = attack.Case("c", 11, "t", ("x",), expect="ok", max_processes=8)
    fx = attack.Fixtures(tmp_path)
    forking = attack.Run(None, "", "", 3.0, too_many_processes=True, peak_processes=1228)
    survived = attack.Run(-9, "", "", 3.0, killed=True, survivors=4, pipes_held=True)
    assert attack.classify(case, forking, tmp_path, fx) == "runaway"
    assert attack.classify(case, survived, tmp_path, fx) == "runaway"
    assert "holding its output pipes" in survived.notes[0]


def test_a_named_pipe_case_is_a_clear_error_within_its_time_limit(attack, tmp_path):
    case = next(c for c in attack.CASES if c.id == "fifo-compare")
    fixtures = tmp_path / "fixtures"
    fixtures.mkdir()
    outcome, run = attack.run_case(case, tmp_path, attack.Fixtures(fixtures))  # a child process: it may block
    assert outcome == "clear error", (outcome, run.stderr, run.notes)
