"""Import cycles and function-local imports of the project's packages.

Prints, for each of ``gbo_envs``, ``agents``, ``agents.twin`` and ``evaluation``:

* the **cycles among its children** (its modules and subpackages, each subpackage squashed into one node,
  as import-linter's ``acyclic_siblings`` contract sees them), from grimp's import graph, which counts the
  imports made inside functions; once with every import and once without the imports under
  ``if TYPE_CHECKING:`` (those that ``exclude_type_checking_imports = true`` hides from the contracts);
* the **function-local imports of the project's own modules** (``import``/``from`` statements inside a
  function body naming ``gbo_envs``, ``agents`` or ``evaluation``, or relative), and how many of them carry a
  comment ``# heavy optional dependency: <name>`` or ``# heavy dependency: <name>`` (the one reason allowed to
  keep such an import local: it would load that third-party library at every start).

The counts of ``agents`` leave out ``agents.twin``, which has its own line. Run from the repository root::

    PYTHONPATH=$PWD python benchmarks/import_graph.py [--list]

``--list`` also prints every function-local import of a project module without that comment.
"""

from __future__ import annotations

import argparse
import ast
import io
import re
import tokenize
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import grimp
import numpy as np
from scipy.sparse import csr_array
from scipy.sparse.csgraph import connected_components

ROOTS = ("gbo_envs", "agents", "evaluation")
PACKAGES = ("gbo_envs", "agents", "agents.twin", "evaluation")
#: The comment that keeps a function-local import of a project module local (on its line or the line above).
HEAVY_COMMENT = re.compile(r"#.*\bheavy (optional )?dependency: *\S")
REPOSITORY = Path(__file__).resolve().parent.parent


def build_graph(*, exclude_type_checking_imports: bool) -> grimp.ImportGraph:
    """Return grimp's graph of the project's packages (function-local imports included)."""
    return grimp.build_graph(
        *ROOTS,
        include_external_packages=False,
        exclude_type_checking_imports=exclude_type_checking_imports,
        cache_dir=None,
    )


def sibling_cycles(graph: grimp.ImportGraph, package: str) -> list[list[str]]:
    """Return one shortest cycle per strongly connected group of ``package``'s children.

    Every module below a child is mapped to that child (a subpackage is one node), the imports between
    different children become edges, and each strongly connected component of more than one child yields
    the shortest cycle through its first child (alphabetically).

    Parameters
    ----------
    graph : grimp.ImportGraph
        The project's import graph.
    package : str
        Dotted name of the package whose children are checked.

    Returns
    -------
    list of list of str
        Each cycle as child names ``[a, b, ..., a]``, without the package prefix; empty when acyclic.
    """
    children = sorted(graph.find_children(package))
    index = {child: i for i, child in enumerate(children)}
    depth = package.count(".") + 2

    def child_of(module: str) -> str | None:
        if not module.startswith(package + "."):
            return None
        return ".".join(module.split(".")[:depth])

    edges: set[tuple[int, int]] = set()
    for module in graph.find_descendants(package):
        source = child_of(module)
        for imported in graph.find_modules_directly_imported_by(module):
            target = child_of(imported)
            if target is not None and source != target:
                edges.add((index[source], index[target]))
    if not edges:
        return []
    rows, cols = np.array(sorted(edges)).T
    adjacency = csr_array((np.ones(len(rows)), (rows, cols)), shape=(len(children), len(children)))
    _, labels = connected_components(adjacency, directed=True, connection="strong")
    successors: dict[int, list[int]] = {}
    for source, target in sorted(edges):
        successors.setdefault(source, []).append(target)
    cycles = []
    for label in sorted(set(labels), key=lambda lab: int(np.flatnonzero(labels == lab)[0])):
        members = np.flatnonzero(labels == label)
        if len(members) < 2:
            continue
        start = int(members[0])
        cycle = _shortest_cycle(start, successors)
        cycles.append([children[i][len(package) + 1 :] for i in cycle])
    return cycles


def _shortest_cycle(start: int, successors: dict[int, list[int]]) -> list[int]:
    """Breadth-first search for the shortest path from ``start`` back to itself."""
    parent: dict[int, int] = {}
    queue = deque([start])
    while queue:
        node = queue.popleft()
        for nxt in successors.get(node, []):
            if nxt == start:
                path = [node]
                while path[-1] != start:
                    path.append(parent[path[-1]])
                return [start, *reversed(path[:-1]), start]
            if nxt not in parent:
                parent[nxt] = node
                queue.append(nxt)
    raise ValueError(f"node {start} is on no cycle")


@dataclass(frozen=True)
class LocalImport:
    """One ``import``/``from`` statement inside a function body."""

    path: Path
    line: int
    statement: str
    project: bool
    heavy_comment: bool


def _comment_lines(source: str) -> dict[int, str]:
    comments: dict[int, str] = {}
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            comments[token.start[0]] = token.string
    return comments


def function_local_imports(path: Path) -> list[LocalImport]:
    """Return every import statement made inside a function (or lambda) body of the file at ``path``.

    An import counts as commented when :data:`HEAVY_COMMENT` matches a comment on one of its lines or on
    the line just above it.
    """
    source = path.read_text(encoding="utf-8")
    tree = ast.parse(source)
    comments = _comment_lines(source)
    found: list[LocalImport] = []

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)) and in_function:
                if isinstance(child, ast.Import):
                    names = [alias.name for alias in child.names]
                else:
                    names = [child.module or ""] if child.level == 0 else ["."]
                project = any(name == "." or name.split(".")[0] in ROOTS for name in names)
                lines = range(child.lineno - 1, (child.end_lineno or child.lineno) + 1)
                heavy = any(HEAVY_COMMENT.search(comments.get(line, "")) for line in lines)
                found.append(LocalImport(path, child.lineno, ast.unparse(child), project, heavy))
            visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(tree, False)
    return found


def package_files(package: str) -> list[Path]:
    """Return the ``.py`` files of ``package``; those of ``agents`` leave out ``agents.twin``."""
    folder = REPOSITORY.joinpath(*package.split("."))
    files = sorted(folder.rglob("*.py"))
    if package == "agents":
        twin = folder / "twin"
        files = [f for f in files if twin not in f.parents]
    return files


def main() -> None:
    """Print the cycles and the function-local import counts of each package."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--list", action="store_true", help="list the uncommented local project imports")
    args = parser.parse_args()
    graphs = {
        "all imports": build_graph(exclude_type_checking_imports=False),
        "TYPE_CHECKING excluded": build_graph(exclude_type_checking_imports=True),
    }
    totals = [0, 0, 0]
    for package in PACKAGES:
        print(f"== {package}")
        for label, graph in graphs.items():
            cycles = sibling_cycles(graph, package)
            print(f"  cycles ({label}): {len(cycles)}")
            for cycle in cycles:
                print("    " + " -> ".join(cycle))
        imports = [imp for path in package_files(package) for imp in function_local_imports(path)]
        project = [imp for imp in imports if imp.project]
        commented = [imp for imp in project if imp.heavy_comment]
        third_party_commented = [imp for imp in imports if not imp.project and imp.heavy_comment]
        print(
            f"  function-local imports of project modules: {len(project)}"
            f" ({len(commented)} with a 'heavy dependency' comment);"
            f" of third-party modules with that comment: {len(third_party_commented)}"
        )
        totals = [totals[0] + len(project), totals[1] + len(commented), totals[2] + len(third_party_commented)]
        if args.list:
            for imp in project:
                if not imp.heavy_comment:
                    print(f"    {imp.path.relative_to(REPOSITORY)}:{imp.line}: {imp.statement}")
    print(f"== total function-local imports of project modules: {totals[0]} ({totals[1]} with the comment)")


if __name__ == "__main__":
    main()
