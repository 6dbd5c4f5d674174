"""Every code block of README.md and of its pages in docs/ runs and prints what the page shows.

The pages are :data:`PAGES`; each is tested on its own, its blocks in order:

* ```` ```pycon ```` blocks are doctests (``>>>`` lines and their output), run in
  order in one namespace per page, as a reader pastes them; ``...`` in an output stands
  for any text (ELLIPSIS), and runs of white space, line breaks included, compare equal
  (an expected output may be wrapped).
* ```` ```python ```` blocks are parts of ``examples/`` files: the block, after
  its first line (``# examples/x.py ...``), must appear verbatim in the file it
  names, and a test runs that file (``tests/agents/test_agents_api.py``).
* ```` ```console ```` blocks are shell sessions: each ``$ gbo ...`` line runs
  (``python -m evaluation.cli``) in a temporary folder (the commands of a page on one
  ``--db`` file in one folder, in order; each group a test of its own), and must
  exit 0 and print the lines below it (same matching as the doctests).
  ``$ make ...`` lines must name a Makefile target (they are what CI and a
  fresh machine run: ``make test`` runs this test); ``$ python3 -m venv`` and
  ``$ .venv/bin/pip`` lines must be the commands ``make setup`` runs.

Besides: the README stays a 10-minute read (:data:`README_MAX_LINES` lines of at most
:data:`README_MAX_WIDTH` characters), benchmarks/README.md stays a reference
(:data:`BENCHMARKS_README_MAX_LINES` lines) whose generated tables are what
``benchmarks/readme_tables.py`` renders from the committed results, CHANGELOG.md stays short
(:data:`CHANGELOG_MAX_LINES` lines), and every relative link of the pages points at a file (and
heading) that exists.
"""

from __future__ import annotations

import doctest
import importlib.util
import os
import re
import shlex
import subprocess
import sys

import matplotlib
import pytest

from tests.support import REPO_ROOT

#: the pages whose code blocks run: the README and the docs pages it links for the detail
PAGES = ("README.md", "docs/envs.md", "docs/tuners.md", "docs/workbench.md", "docs/benchmark.md", "docs/cli.md",
         "docs/constraints.md")
#: the pages whose relative links are checked: the above and the other hand-written docs
LINKED_PAGES = (*PAGES, "docs/real-data.md", "docs/surfaces.md", "docs/design.md", "benchmarks/README.md",
                "CHANGELOG.md")
README_MAX_LINES, README_MAX_WIDTH = 250, 120
BENCHMARKS_README_MAX_LINES = 300
CHANGELOG_MAX_LINES = 150
FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
LANGUAGES = ("pycon", "python", "console", "text")


def _text(page: str) -> str:
    return (REPO_ROOT / page).read_text()


def _blocks(page: str, language: str | None = None) -> list[str] | list[tuple[str, str]]:
    """The fenced code blocks of ``page``: (language, code) pairs, or the code of one language."""
    blocks = re.findall(r"^```(\w*)\n(.*?)^```", _text(page), re.S | re.M)
    return blocks if language is None else [code for lang, code in blocks if lang == language]


@pytest.mark.parametrize("page", PAGES)
def test_every_block_has_a_language_the_test_runs(page):
    unrun = [code.splitlines()[0] for lang, code in _blocks(page) if lang not in LANGUAGES]
    assert not unrun, f"{page}: blocks without {'/'.join(LANGUAGES)}: {unrun}"


def test_the_pages_have_examples_to_run():
    counts = {lang: sum(len(_blocks(page, lang)) for page in PAGES) for lang in ("pycon", "console", "python")}
    assert counts["pycon"] >= 5 and counts["console"] >= 5 and counts["python"] >= 1, counts
    assert _blocks("README.md", "pycon") and _blocks("README.md", "console"), "the README shows no example"


def test_readme_is_a_ten_minute_read():
    lines = _text("README.md").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines (at most {README_MAX_LINES})"
    wide = [(number, len(line)) for number, line in enumerate(lines, 1) if len(line) > README_MAX_WIDTH]
    assert not wide, f"README.md lines over {README_MAX_WIDTH} characters (line, length): {wide}"
    first = _blocks("README.md")[0]
    assert first[0] == "console" and "$ make demo" in first[1] and "$ make test" in first[1], \
        "the README starts with make demo and make test"


def test_benchmarks_readme_is_a_reference():
    lines = _text("benchmarks/README.md").splitlines()
    assert len(lines) <= BENCHMARKS_README_MAX_LINES, \
        f"benchmarks/README.md has {len(lines)} lines (at most {BENCHMARKS_README_MAX_LINES})"


def test_changelog_is_short():
    lines = _text("CHANGELOG.md").splitlines()
    assert len(lines) <= CHANGELOG_MAX_LINES, \
        f"CHANGELOG.md has {len(lines)} lines (at most {CHANGELOG_MAX_LINES}: one to five lines an issue)"
    assert lines[0] == "# Changelog" and "## [Unreleased]" in lines


def _readme_tables():
    spec = importlib.util.spec_from_file_location("readme_tables", REPO_ROOT / "benchmarks" / "readme_tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_benchmarks_readme_tables_are_what_the_results_render():
    tables = _readme_tables()
    text = _text("benchmarks/README.md")
    assert tables.render(text, REPO_ROOT) == text, \
        "benchmarks/README.md's generated tables differ from the results: run python benchmarks/readme_tables.py"
    assert len(tables.SECTIONS) >= 3 and all(f"<!-- {name} -->" in text for name in tables.SECTIONS)


def test_benchmarks_readme_tables_follow_the_results(tmp_path):
    tables = _readme_tables()
    results = tmp_path / "benchmarks" / "results"
    results.mkdir(parents=True)
    for path in (REPO_ROOT / "benchmarks" / "results").glob("*.json"):
        (results / path.name).write_text(path.read_text().replace('"DCMotorRig-v0"', '"ChangedRig-v0"'))
    text = _text("benchmarks/README.md")
    rendered = tables.render(text, tmp_path)
    assert rendered != text and "ChangedRig-v0" in rendered


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


@pytest.mark.parametrize("page", LINKED_PAGES)
def test_relative_links_point_at_what_exists(page):
    text = re.sub(r"^```.*?^```", "", _text(page), flags=re.S | re.M)
    broken = []
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target):
            continue  # a URL
        path, _, anchor = target.partition("#")
        file = (REPO_ROOT / page).parent / path if path else REPO_ROOT / page
        if not file.exists():
            broken.append(target)
        elif anchor and file.suffix == ".md":
            headings = re.findall(r"^#+ (.*)$", file.read_text(), re.M)
            if anchor not in {_slug(heading) for heading in headings}:
                broken.append(target)
    assert not broken, f"{page}: links to nothing: {broken}"


@pytest.mark.slow
@pytest.mark.parametrize("page", [page for page in PAGES if _blocks(page, "pycon")])
def test_pycon_blocks_print_what_the_page_shows(page, monkeypatch, tmp_path):
    matplotlib.use("Agg")
    monkeypatch.chdir(tmp_path)  # anything a block writes stays out of the checkout
    parser, runner = doctest.DocTestParser(), doctest.DocTestRunner(optionflags=FLAGS)
    namespace: dict = {"__name__": "__readme__"}
    for number, code in enumerate(_blocks(page, "pycon"), 1):
        test = parser.get_doctest(code, namespace, f"{page} pycon block {number}", page, 0)
        runner.run(test, clear_globs=False)
        namespace = test.globs  # DocTest copies its globals: carry them to the next block
    assert runner.failures == 0, f"{runner.failures} doctest line(s) of {page} differ (output above)"


@pytest.mark.parametrize("page", PAGES)
def test_python_blocks_are_the_examples_they_name(page):
    for code in _blocks(page, "python"):
        first, body = code.split("\n", 1)
        assert first.startswith("# examples/"), f"{page}: a python block must name its example file: {first!r}"
        name = first[2:].split()[0]
        assert body in (REPO_ROOT / name).read_text(), f"{page}: block is not verbatim in {name}"


def _sessions(code: str) -> list[tuple[str, str]]:
    """(command, expected output) pairs of a console block."""
    pairs: list[tuple[str, list[str]]] = []
    for line in code.splitlines():
        if line.startswith("$ "):
            pairs.append((line[2:].split("  #")[0].strip(), []))
        elif pairs:
            pairs[-1][1].append(line)
    return [(command, "\n".join(out).strip() + "\n" if out else "") for command, out in pairs]


@pytest.mark.parametrize("page", PAGES)
def test_make_and_install_lines_are_what_the_makefile_runs(page):
    makefile = (REPO_ROOT / "Makefile").read_text()
    targets = set(re.findall(r"^([\w-]+):", makefile, re.M))
    for code in _blocks(page, "console"):
        for command, _ in _sessions(code):
            words = shlex.split(command)
            if words[0] == "make":
                assert words[1] in targets, f"{page}: {command!r} names no Makefile target"
            elif words[:3] == ["python3", "-m", "venv"]:
                assert "-m venv" in makefile
            elif words[0] == ".venv/bin/pip":  # the same requirement, installed by make setup's $(PIP)
                assert words[1] == "install" and f'"{words[-1]}"' in makefile, command


def _gbo_sessions(page: str) -> list[list[tuple[str, str]]]:
    """The ``$ gbo ...`` lines of a page's console blocks with their output, in groups that run in one folder:
    commands on the same ``--db`` file form one group, in order (a tuning session, then what reads it);
    every other command is a group of its own."""
    groups: list[list[tuple[str, str]]] = []
    by_db: dict[str, list] = {}
    for code in _blocks(page, "console"):
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


GBO_SESSIONS = [(page, group) for page in PAGES for group in _gbo_sessions(page)]


@pytest.mark.slow
@pytest.mark.parametrize("page, session", GBO_SESSIONS,
                         ids=[f"{page}: {' '.join(shlex.split(group[0][0])[:3])}" for page, group in GBO_SESSIONS])
def test_gbo_commands_print_what_the_page_shows(page, session, tmp_path):
    checker = doctest.OutputChecker()
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT), "COLUMNS": "120"}
    (tmp_path / "examples").symlink_to(REPO_ROOT / "examples")  # the bundled data, as from the checkout
    for command, expected in session:
        words = shlex.split(command)
        done = subprocess.run([sys.executable, "-m", "evaluation.cli", *words[1:]], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, f"{page}: {command}: exit {done.returncode}\n{done.stderr}"
        if expected:
            assert checker.check_output(expected, done.stdout, FLAGS), \
                f"{page}: {command}: the page shows\n{expected}\nbut it printed\n{done.stdout}"
