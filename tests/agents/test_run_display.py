"""The one progress-bar helper: on stderr, off by default in the library, ``None`` = only on a terminal."""

from __future__ import annotations

import io

import gymnasium as gym
import pytest

import agents
import gbo_envs  # noqa: F401  (registers the envs)
from agents.run_display import progress_bar, progress_enabled


class _Stream(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


@pytest.mark.parametrize("tty", [True, False])
def test_none_draws_only_on_a_terminal(tty, monkeypatch):
    stream = _Stream(tty)
    monkeypatch.setattr("sys.stderr", stream)
    assert progress_enabled(None) is tty
    assert progress_enabled(True) and not progress_enabled(False)
    bar = progress_bar(3, "work", None, unit="step")
    bar.update(3)
    bar.close()
    assert ("work" in stream.getvalue()) is tty


def test_tuning_run_bar_goes_to_stderr_and_is_off_by_default(capsys):
    env = gym.make("gbo_envs/DCMotor-v0", noise=False)
    agents.make("random").run(env, budget=2, seed=0)
    assert capsys.readouterr().err == ""
    agents.make("random").run(env, budget=2, seed=0, progress=None)  # pytest's stderr is not a terminal
    assert capsys.readouterr().err == ""
    agents.make("random").run(env, budget=2, seed=0, progress=True)
    captured = capsys.readouterr()
    assert "random on gbo_envs/DCMotor-v0" in captured.err and "2/2" in captured.err and captured.out == ""


class _Terminal(_Stream):
    """A terminal stream with a file descriptor, whose size the test sets through ``os.get_terminal_size``."""

    def __init__(self) -> None:
        super().__init__(tty=True)

    def fileno(self) -> int:
        return 2


@pytest.mark.parametrize(("columns", "rows"), [(0, 0), (0, 24), (100, 0), (100, 24)])
def test_a_terminal_of_zero_columns_gets_an_80_column_bar(columns, rows, monkeypatch):
    """Some pseudo-terminals (editors' shells) report a size of 0 x 0; the bar then has 80 columns.

    tqdm took 0 rows as no room for any bar (nothing drawn) and 0 columns as a bar 1 character wide.
    """
    import os
    import re

    stream = _Terminal()
    monkeypatch.setattr("sys.stderr", stream)
    monkeypatch.setattr(os, "get_terminal_size", lambda fd=None: os.terminal_size((columns, rows)))
    bar = progress_bar(10, "work", True, unit="step")
    bar.update(5)
    bar.refresh()
    bar.close()
    lines = [line for line in re.split(r"[\r\n]", stream.getvalue()) if "5/10" in line]
    assert lines, stream.getvalue()
    width = 80 if columns == 0 else columns
    assert len(lines[-1]) == width - 1  # tqdm leaves the last column free
    assert re.search(r"\|\S{5,}\s{5,}\|", lines[-1]), lines[-1]  # half a bar, drawn
