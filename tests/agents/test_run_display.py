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
