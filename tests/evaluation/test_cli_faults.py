"""Issue 57 at the command line: bounded integers and ``--jobs``, named pipes, a closed stdout, data the fit
cannot take, ``--effects`` named twice, a non-causal log, and SQLite errors that name the file.

Each test runs the public entry point (the CLI's ``main``, or ``python -m evaluation.cli`` where the
process itself matters) and fails on the code before the fix: there the command forked without limit,
blocked, printed ``internal error: OverflowError`` or ``BrokenPipeError``, or LAPACK's complaint on stdout.
"""

from __future__ import annotations

import argparse
import os
import sqlite3
import subprocess
import sys
import threading

import numpy as np
import pytest

from agents.twin.csvio import read_csv, write_csv
from evaluation import cli_args
from evaluation.cli_args import error_message, job_count
from tests.evaluation.test_cli_errors import refused
from tests.support import REPO_ROOT, loop_records

HUGE = "99999999999999999999"


@pytest.fixture(scope="module")
def csv_path(tmp_path_factory):
    records = loop_records(gains=np.array([[0.3, 1.0], [0.9, 1.2], [1.05, 2.0]]), duration=0.5, start_index=4)
    return write_csv(records, tmp_path_factory.mktemp("twin") / "three.csv")


@pytest.mark.parametrize(("argv", "words"), [
    (["tune", "--budget", HUGE], ("--budget", "from 1 to 1000000")),
    (["tune", "--budget", "2", "--seed", HUGE], ("--seed", "from 0 to 4294967295")),
    (["export", "--session", HUGE, "--csv", "o.csv"], ("--session", "9223372036854775807")),
])
def test_huge_integers_name_the_argument_and_its_range_and_write_nothing(capsys, tmp_path, argv, words):
    db = tmp_path / "runs.sqlite"
    refused(capsys, [*argv, "--db", str(db)], *words)
    assert not db.exists()


def test_a_huge_experiment_id_names_the_row_and_the_range(capsys, tmp_path, csv_path):
    lines = csv_path.read_text().splitlines()
    big = tmp_path / "big.csv"
    big.write_text("\n".join([lines[0], *(HUGE + line[line.index(","):] for line in lines[1:])]) + "\n")
    refused(capsys, ["twin", "compare", str(big)], f"{big}, row 2, column 'experiment'", "9007199254740992")


def test_jobs_above_the_cores_are_capped_with_a_note_and_huge_negatives_refused(capsys, monkeypatch):
    monkeypatch.setattr(cli_args, "usable_cores", lambda: 2)
    assert job_count("16") == 2 and job_count(HUGE) == 2
    assert capsys.readouterr().err.count("more than the 2 usable cores; using 2") == 2
    assert job_count("-1") == -1 and job_count("2") == 2
    with pytest.raises(argparse.ArgumentTypeError, match="from -2 to 2"):
        job_count("-" + HUGE)


def test_a_named_pipe_is_refused_without_waiting_for_a_writer(capsys, tmp_path):
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    outcome = {}

    def read():
        try:
            read_csv(fifo)
        except ValueError as exc:
            outcome["error"] = str(exc)

    reader = threading.Thread(target=read, daemon=True)  # the old reader blocked in open() for ever
    reader.start()
    reader.join(timeout=10)
    assert "not a regular file" in outcome.get("error", ""), outcome
    refused(capsys, ["twin", "compare", str(fifo)], str(fifo), "not a regular file")


def test_effects_named_twice_are_refused(capsys, csv_path):
    from agents.twin.model import effect_items

    refused(capsys, ["twin", "compare", str(csv_path), "--effects", "saturation,saturation"], "--effects",
            "'saturation' is named twice")
    with pytest.raises(ValueError, match="'saturation' is named twice"):
        effect_items(["saturation", "saturation"])


def test_values_the_fit_cannot_square_are_refused_and_stdout_stays_clean(capfd, tmp_path, csv_path):
    lines = csv_path.read_text().splitlines()
    header = lines[0].split(",")
    y = header.index("y")
    huge = tmp_path / "huge.csv"
    rows = [line.split(",") for line in lines[1:]]
    for row in rows:
        row[y] = repr(float(row[y]) * 1e305)
    huge.write_text("\n".join([lines[0], *(",".join(row) for row in rows)]) + "\n")
    capfd.readouterr()
    from evaluation.cli import main

    assert main(["twin", "compare", str(huge), "--json"]) == 2
    out, err = capfd.readouterr()  # the file descriptors: LAPACK writes its DLASCL line to fd 1
    assert out == "" and "DLASCL" not in err
    assert "values must be within +-1e+100" in err and str(huge) in err
    assert main(["twin", "compare", str(csv_path), "--poles", "20", "--json"]) == 2
    out, err = capfd.readouterr()
    assert out == "" and err == "gbo twin compare: error: n_poles (--poles): must be an integer from 1 to 8, got 20\n"


def test_experiments_too_short_for_the_model_get_a_length_error(capsys, tmp_path, csv_path):
    lines = csv_path.read_text().splitlines()
    seen: dict[str, int] = {}
    keep = []
    for line in lines[1:]:
        seen[line.split(",")[0]] = seen.get(line.split(",")[0], 0) + 1
        if seen[line.split(",")[0]] <= 3:
            keep.append(line)
    short = tmp_path / "short.csv"
    short.write_text("\n".join([lines[0], *keep]) + "\n")
    refused(capsys, ["twin", "compare", str(short)], "has 3 samples", "needs at least 7 per experiment")


def test_a_non_causal_log_is_said_on_stderr_and_json_stays_clean(capsys, tmp_path):
    from scipy.signal import lfilter

    from evaluation.cli import main

    rng = np.random.default_rng(0)
    rows = []
    for experiment in (1, 2, 3):
        u = np.repeat(rng.choice([-1.0, 1.0], 50), 10)
        y = lfilter([0.2], [1.0, -0.8], u) + 0.001 * rng.standard_normal(u.size)  # y[k] answers u[k]
        rows += [f"{experiment},{k * 0.01:.2f},{u[k]:g},{u[k]:g},{y[k]:.10g}\n" for k in range(u.size)]
    log = tmp_path / "log.csv"
    log.write_text("experiment,t,r,u,y\n" + "".join(rows))
    capsys.readouterr()
    assert main(["twin", "compare", str(log), "--json", "--out", str(tmp_path / "out")]) == 0
    out, err = capsys.readouterr()
    assert out.startswith("{") and "same sample" not in out
    assert f"gbo twin compare: warning: {log}: the output y answers the input u within the same sample" in err


def test_sqlite_errors_name_the_database_file():
    assert error_message(sqlite3.DatabaseError("database disk image is malformed"), db="runs.sqlite") \
        .startswith("runs.sqlite: database disk image is malformed; the file is damaged")


def test_a_reader_that_goes_away_ends_the_command_quietly(csv_path, tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "evaluation.cli", "twin", "compare", str(csv_path), "--out",
                             str(tmp_path / "out")], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(REPO_ROOT)})
    proc.stdout.close()  # gbo twin compare ... | head: the reader left before the first line
    err = proc.communicate(timeout=300)[1].decode()
    assert proc.returncode == 1 and err == "", (proc.returncode, err)


def test_event_printing_into_a_closed_pipe_stops_the_session_as_interrupted(monkeypatch):
    import logging

    from evaluation.cli_args import OutputClosed
    from evaluation.tune_cli import _PrintEvents

    class Closed:
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self):
            raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(sys, "stdout", Closed())
    record = logging.LogRecord("agents.base", logging.INFO, __file__, 1, "twin: + saturation", None, None)
    with pytest.raises(OutputClosed) as caught:  # a KeyboardInterrupt: the session is "interrupted", not "failed"
        _PrintEvents().emit(record)
    assert isinstance(caught.value, KeyboardInterrupt)


def test_ctrl_c_while_the_workers_shut_down_is_one_line_and_exit_130():
    code = ("import os, signal, time\nfrom joblib import Parallel, delayed\nfrom evaluation import cli\n"
            "shut_down = cli._shut_down_workers\n"
            "def interrupted_shut_down():\n    os.kill(os.getpid(), signal.SIGINT)\n    time.sleep(0.2)\n"
            "    shut_down()\n"
            "cli._shut_down_workers = interrupted_shut_down\n"
            "cli.main = lambda: (Parallel(n_jobs=2)(delayed(abs)(i) for i in range(4)), 0)[1]  # loky workers left\n"
            "raise SystemExit(cli.run())\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(REPO_ROOT)})
    assert done.returncode == 130, done.stderr
    assert done.stderr.count("\n") == 1 and "interrupted" in done.stderr, done.stderr  # no traceback, no leak warning
