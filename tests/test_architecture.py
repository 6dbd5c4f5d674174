"""The import architecture: no cycle inside a package, no function-local import of a project module without a reason.

Counted as ``benchmarks/import_graph.py`` measures it: grimp's graph with the imports made inside functions
and those under ``if TYPE_CHECKING:`` (a cycle hidden by either is still a cycle), and an ``import`` inside a
function body naming ``gbo_envs``, ``agents`` or ``evaluation`` allowed only with a comment
``# heavy dependency: <name>`` (or ``# heavy optional dependency: <name>``): it keeps that third-party library
from loading at every start.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys

import pytest

from tests.support import REPO_ROOT


@pytest.fixture(scope="module")
def import_graph():
    path = REPO_ROOT / "benchmarks" / "import_graph.py"
    spec = importlib.util.spec_from_file_location("import_graph", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["import_graph"] = module
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop("import_graph", None)


@pytest.fixture(scope="module")
def graph(import_graph):
    return import_graph.build_graph(exclude_type_checking_imports=False)


@pytest.mark.parametrize("package", ["gbo_envs", "agents", "agents.twin", "evaluation"])
def test_no_import_cycle_among_the_modules_of(package, graph, import_graph):
    assert import_graph.sibling_cycles(graph, package) == []


@pytest.mark.parametrize("part", ["gbo_envs", "agents", "agents.twin", "evaluation"])
def test_every_function_local_import_of_a_project_module_names_its_heavy_dependency(part, import_graph):
    unexplained = [f"{imp.path.relative_to(REPO_ROOT)}:{imp.line}: {imp.statement}"
                   for path in import_graph.package_files(part) for imp in import_graph.function_local_imports(path)
                   if imp.project and not imp.heavy_comment]
    assert unexplained == []


def test_the_measurement_finds_a_cycle_through_a_function_local_import(tmp_path, import_graph):
    """The graph counts an import inside a function, and a marked local import is told from a bare one."""
    package = tmp_path / "cyclic"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("from cyclic import b\n")
    (package / "b.py").write_text("def f():\n    # heavy dependency: numba\n    from cyclic import a\n\n"
                                  "def g():\n    import cyclic.a\n")
    sys.path.insert(0, str(tmp_path))
    try:
        graph = import_graph.grimp.build_graph("cyclic", cache_dir=None)
    finally:
        sys.path.remove(str(tmp_path))
    assert import_graph.sibling_cycles(graph, "cyclic") == [["a", "b", "a"]]
    imports = import_graph.function_local_imports(package / "b.py")
    assert [(imp.line, imp.heavy_comment) for imp in imports] == [(3, True), (6, False)]
    # project modules are gbo_envs, agents and evaluation: cyclic is not one
    assert not any(imp.project for imp in imports)


def test_building_the_gbo_parser_loads_no_command(tmp_path):
    """Every sub-command's handler is named (``evaluation.cli_args.Handler``) and resolves, and building the
    parser of every command imports none of them, nor scikit-learn, scipy.stats or the twin workbench."""
    code = (
        "import sys, argparse, pkgutil\n"
        "from evaluation.cli import build_parser\n"
        "from evaluation.cli_args import Handler\n"
        "parser = build_parser()\n"
        "loaded = sorted(m for m in ('evaluation.bench_cli', 'evaluation.tune_cli', 'evaluation.twin_cli',\n"
        "    'evaluation.demo', 'agents.twin', 'sklearn', 'scipy.stats', 'scipy.signal') if m in sys.modules)\n"
        "targets = []\n"
        "def walk(p):\n"
        "    handler = p.get_default('handler')\n"
        "    if handler is not None:\n"
        "        assert isinstance(handler, Handler), (p.prog, handler)\n"
        "        targets.append(handler.target)\n"
        "    for action in p._actions:\n"
        "        if isinstance(action, argparse._SubParsersAction):\n"
        "            for sub in action.choices.values():\n"
        "                walk(sub)\n"
        "walk(parser)\n"
        "for target in targets:\n"
        "    assert callable(pkgutil.resolve_name(target)), target\n"
        "print(loaded, len(targets))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO_ROOT,
                          env={**os.environ, "PYTHONPATH": str(REPO_ROOT)}, timeout=120)
    assert done.returncode == 0, done.stderr
    # demo, bench, tune, sessions, export and the four twin commands
    assert done.stdout.split() == ["[]", "9"]
