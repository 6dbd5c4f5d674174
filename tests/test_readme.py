"""Every code block of README.md runs and prints what the README shows.

* ```` ```pycon ```` blocks are doctests (``>>>`` lines and their output), run in
  order in one namespace, as a reader pastes them; ``...`` in an output stands
  for any text (ELLIPSIS), and runs of white space compare equal.
* ```` ```python ```` blocks are parts of ``examples/`` files: the block, after
  its first line (``# examples/x.py ...``), must appear verbatim in the file it
  names, and a test runs that file (``tests/agents/test_agents_api.py``).
* ```` ```console ```` blocks are shell sessions: each ``$ gbo ...`` line runs
  (``python -m evaluation.cli``) in a temporary folder (the commands on one
  ``--db`` file in one folder, in order; each group a test of its own), and must
  exit 0 and print the lines below it (same matching as the doctests).
  ``$ make ...`` lines must name a Makefile target (they are what CI and a
  fresh machine run: ``make test`` runs this test); ``$ python3 -m venv`` and
  ``$ .venv/bin/pip`` lines must be the commands ``make setup`` runs.
"""

from __future__ import annotations

import doctest
import os
import re
import shlex
import subprocess
import sys

import matplotlib
import pytest

from tests.support import REPO_ROOT

README = (REPO_ROOT / "README.md").read_text()
BLOCKS = re.findall(r"^```(\w*)\n(.*?)^```", README, re.S | re.M)
FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _blocks(language: str) -> list[str]:
    return [code for lang, code in BLOCKS if lang == language]


def test_every_block_has_a_language_the_test_runs():
    unrun = [code.splitlines()[0] for lang, code in BLOCKS if lang not in ("pycon", "python", "console", "text")]
    assert not unrun, f"README blocks without pycon/python/console/text: {unrun}"
    assert len(_blocks("pycon")) >= 3 and len(_blocks("console")) >= 3


@pytest.mark.slow
def test_readme_doctests_print_what_the_readme_shows(monkeypatch, tmp_path):
    matplotlib.use("Agg")
    monkeypatch.chdir(tmp_path)  # anything a block writes stays out of the checkout
    parser, runner = doctest.DocTestParser(), doctest.DocTestRunner(optionflags=FLAGS)
    namespace: dict = {"__name__": "__readme__"}
    for number, code in enumerate(_blocks("pycon"), 1):
        test = parser.get_doctest(code, namespace, f"README.md pycon block {number}", "README.md", 0)
        runner.run(test, clear_globs=False)
        namespace = test.globs  # DocTest copies its globals: carry them to the next block
    assert runner.failures == 0, f"{runner.failures} README doctest line(s) differ (output above)"


def test_python_blocks_are_the_examples_they_name():
    for code in _blocks("python"):
        first, body = code.split("\n", 1)
        assert first.startswith("# examples/"), f"a python block must name its example file: {first!r}"
        name = first[2:].split()[0]
        assert body in (REPO_ROOT / name).read_text(), f"README block is not verbatim in {name}"


def _sessions(code: str) -> list[tuple[str, str]]:
    """(command, expected output) pairs of a console block."""
    pairs: list[tuple[str, list[str]]] = []
    for line in code.splitlines():
        if line.startswith("$ "):
            pairs.append((line[2:].split("  #")[0].strip(), []))
        elif pairs:
            pairs[-1][1].append(line)
    return [(command, "\n".join(out).strip() + "\n" if out else "") for command, out in pairs]


def test_make_and_install_lines_are_what_the_makefile_runs():
    makefile = (REPO_ROOT / "Makefile").read_text()
    targets = set(re.findall(r"^([\w-]+):", makefile, re.M))
    for code in _blocks("console"):
        for command, _ in _sessions(code):
            words = shlex.split(command)
            if words[0] == "make":
                assert words[1] in targets, f"README: {command!r} names no Makefile target"
            elif words[:3] == ["python3", "-m", "venv"]:
                assert "-m venv" in makefile
            elif words[0] == ".venv/bin/pip":  # the same requirement, installed by make setup's $(PIP)
                assert words[1] == "install" and f'"{words[-1]}"' in makefile, command


def _gbo_sessions() -> list[list[tuple[str, str]]]:
    """The ``$ gbo ...`` lines of the console blocks with their output, in groups that run in one folder:
    commands on the same ``--db`` file form one group, in order (a tuning session, then what reads it);
    every other command is a group of its own."""
    groups: list[list[tuple[str, str]]] = []
    by_db: dict[str, list] = {}
    for code in _blocks("console"):
        for command, expected in _sessions(code):
            words = shlex.split(command)
            if words[0] != "gbo":
                continue
            db = words[words.index("--db") + 1] if "--db" in words else None
            if db is not None and db in by_db:
                by_db[db].append((command, expected))
                continue
            groups.append([(command, expected)])
            if db is not None:
                by_db[db] = groups[-1]
    return groups


@pytest.mark.slow
@pytest.mark.parametrize("session", _gbo_sessions(), ids=lambda group: " ".join(shlex.split(group[0][0])[:3]))
def test_readme_gbo_commands_print_what_the_readme_shows(session, tmp_path):
    checker = doctest.OutputChecker()
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT), "COLUMNS": "120"}
    (tmp_path / "examples").symlink_to(REPO_ROOT / "examples")  # the bundled data, as from the checkout
    for command, expected in session:
        words = shlex.split(command)
        done = subprocess.run([sys.executable, "-m", "evaluation.cli", *words[1:]], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, f"{command}: exit {done.returncode}\n{done.stderr}"
        if expected:
            assert checker.check_output(expected, done.stdout, FLAGS), \
                f"{command}: README shows\n{expected}\nbut it printed\n{done.stdout}"
