"""What a benchmark result depends on: the source modules of a tuner and of a plant, and their hashes.

A reference result of the benchmark suite (:mod:`evaluation.references`) is stale
when anything it was computed from has changed since. Its fingerprint holds the
env id and kwargs, the ground-truth optimum ``J*``, the tuner's name and keyword
arguments, and two hashes of source code:

- the **tuner's modules**: the module that defines the tuner class (from
  :func:`agents.make`'s registry) and every module of the project it imports,
  transitively, at any nesting level (imports inside functions count), but for
  the modules that only draw, write files or show progress
  (:data:`PRESENTATION_MODULES`);
- the **plant's modules**: the module of the env's entry point, the ground-truth
  module :mod:`gbo_envs.ground_truth`, every project module they import, and the
  env's precomputed truth table (``gbo_envs/data/ground_truth/<env>.npz``) when it
  ships one.

Imports are read from the source (:mod:`ast`), not by importing it. A name imported
from a package (``from gbo_envs import METRIC_NAMES``) counts as the module that
defines it (``gbo_envs.metrics``), followed through the package's ``__init__`` and
its lazy-import tables (``{"Name": "module"}``); a bare ``import package`` counts as
the whole ``__init__`` and what it imports. The project's packages are
:data:`PROJECT_PACKAGES`, plus the top-level package of a tuner defined elsewhere
(a researcher's own module).

The same closure can be read at any git commit (:class:`SourceTree` with
``commit=``), which is how results made before this module existed are dated.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import inspect
import subprocess
from functools import cache, lru_cache
from pathlib import Path

import gymnasium as gym

import gbo_envs  # noqa: F401  (registers the envs)
from agents import registry

__all__ = ["PRESENTATION_MODULES", "PROJECT_PACKAGES", "REPO_ROOT", "SourceTree", "git_commit", "module_closure",
           "plant_modules", "reread_sources", "source_hash", "truth_table_path", "tuner_modules"]

#: Top-level packages whose modules count as source (third-party libraries are pinned by the environment).
PROJECT_PACKAGES = ("gbo_envs", "agents", "evaluation")
#: The repository (or site-packages) folder that holds the project's packages.
REPO_ROOT = Path(__file__).resolve().parents[1]
#: Modules that only draw, write files or show progress: they cannot change a result, so they are left out
#: of every closure (a figure's style does not make a reference stale).
PRESENTATION_MODULES = ("gbo_envs.plotting", "gbo_envs.lazy_pyplot", "gbo_envs.atomic_write", "agents.html_page",
                        "agents.run_display")


class SourceTree:
    """Module sources of the working tree, or of a git commit of this repository.

    Parameters
    ----------
    commit : str, optional
        A git commit of :data:`REPO_ROOT`; project modules are read with ``git show`` (modules outside
        the repository are read from disk in either case).
    """

    def __init__(self, commit: str | None = None) -> None:
        self.commit = commit
        self._cache: dict[str, tuple[str, bytes] | None] = {}
        self._syntax: dict[str, ast.Module] = {}
        self._imports: dict[tuple[str, tuple[str, ...]], frozenset[str]] = {}

    def read(self, module: str) -> tuple[str, bytes] | None:
        """``(relative path, source bytes)`` of ``module``, or None when it is not a module of the tree."""
        if module not in self._cache:
            self._cache[module] = self._read(module)
        return self._cache[module]

    def is_package(self, module: str) -> bool:
        """Whether ``module`` is a package (its source is an ``__init__.py``)."""
        found = self.read(module)
        return found is not None and found[0].endswith("__init__.py")

    def syntax(self, module: str) -> ast.Module:
        """The parsed source of ``module`` (which must be a module of the tree), parsed once per tree: the
        closures of a suite's tuners and plants read the same modules again and again."""
        if module not in self._syntax:
            self._syntax[module] = ast.parse(self.read(module)[1])
        return self._syntax[module]

    def _read(self, module: str) -> tuple[str, bytes] | None:
        parts = module.split(".")
        if parts[0] in PROJECT_PACKAGES:
            for relative in ("/".join(parts) + ".py", "/".join(parts) + "/__init__.py"):
                if self.commit is None:
                    path = REPO_ROOT / relative
                    data = path.read_bytes() if path.is_file() else None
                else:
                    data = _git_show(self.commit, relative)
                if data is not None:
                    return relative, data
            return None
        try:
            spec = importlib.util.find_spec(module)
        except (ImportError, ValueError):
            return None
        if spec is None or not spec.origin or not spec.origin.endswith(".py"):
            return None
        path = Path(spec.origin)
        try:
            relative = str(path.resolve().relative_to(REPO_ROOT))
        except ValueError:
            relative = "/".join(parts) + ("/__init__.py" if path.name == "__init__.py" else ".py")
        return relative, path.read_bytes()


def _git_show(commit: str, relative: str) -> bytes | None:
    done = subprocess.run(["git", "-C", str(REPO_ROOT), "show", f"{commit}:{relative}"], capture_output=True)
    return done.stdout if done.returncode == 0 else None


def git_commit(modules=None) -> str | None:
    """The commit checked out in :data:`REPO_ROOT`, or None outside a git checkout.

    ``"<hash>-dirty"`` when the sources of ``modules`` (default: every tracked file) differ from it.
    """
    head = subprocess.run(["git", "-C", str(REPO_ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode != 0:
        return None
    tree = _working_tree()
    paths = None if modules is None else [found[0] for found in map(tree.read, modules) if found is not None]
    dirty = subprocess.run(["git", "-C", str(REPO_ROOT), "status", "--porcelain", "--untracked-files=all", "--",
                            *(paths or ["."])], capture_output=True, text=True)
    return head.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")


# -- the import closure -------------------------------------------------------------------------------
def module_closure(roots, tree: SourceTree | None = None, packages=PROJECT_PACKAGES) -> list[str]:
    """``roots`` and every module of ``packages`` they import, transitively, sorted.

    Parameters
    ----------
    roots : iterable of str
        Module names.
    tree : SourceTree, optional
        Where the sources are read (default: the working tree).
    packages : tuple of str
        Top-level packages whose modules are followed.
    """
    tree = tree or _working_tree()
    packages = tuple(packages)
    seen: set[str] = set()
    stack = [root for root in roots if tree.read(root) is not None]
    while stack:
        module = stack.pop()
        if module in seen:
            continue
        seen.add(module)
        for name in _imports(module, tree, packages):
            if name not in seen and name not in PRESENTATION_MODULES and tree.read(name) is not None:
                stack.append(name)
    return sorted(seen)


@lru_cache(maxsize=1)
def _working_tree() -> SourceTree:
    """One reader of the working tree per process (the sources do not change while a command runs)."""
    return SourceTree()


def reread_sources() -> None:
    """Forget the working tree's sources read so far (a long-lived process whose sources were edited)."""
    _working_tree.cache_clear()


def _imports(module: str, tree: SourceTree, packages: tuple[str, ...]) -> frozenset[str]:
    """The project modules ``module`` imports (names imported from a package resolved to their module),
    found once per tree."""
    key = (module, packages)
    if key not in tree._imports:
        tree._imports[key] = frozenset(_read_imports(module, tree, packages))
    return tree._imports[key]


def _read_imports(module: str, tree: SourceTree, packages: tuple[str, ...]) -> set[str]:
    if tree.read(module) is None:
        return set()
    syntax = tree.syntax(module)
    package = module if tree.is_package(module) else module.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(syntax):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names if alias.name.split(".")[0] in packages)
        elif isinstance(node, ast.ImportFrom):
            base = _absolute(node, package)
            if base is None or base.split(".")[0] not in packages:
                continue
            for alias in node.names:
                out.add(_resolve_name(base, alias.name, tree, packages, depth=0))
    out.update(_lazy_table(syntax, packages) if tree.is_package(module) else ())
    out.discard(module)
    return out


def _absolute(node: ast.ImportFrom, package: str) -> str | None:
    if not node.level:
        return node.module
    parts = package.split(".") if package else []
    if node.level - 1 > len(parts):
        return None
    base = parts[: len(parts) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else [])) or None


def _resolve_name(base: str, name: str, tree: SourceTree, packages: tuple[str, ...], depth: int) -> str:
    """The module that defines ``name`` as imported by ``from base import name``."""
    if name != "*" and tree.read(f"{base}.{name}") is not None:
        return f"{base}.{name}"
    if depth > 5 or not tree.is_package(base):
        return base
    syntax = tree.syntax(base)
    for node in syntax.body:
        if isinstance(node, ast.ImportFrom):
            source = _absolute(node, base)
            if source is None or source.split(".")[0] not in packages:
                continue
            for alias in node.names:
                if (alias.asname or alias.name) == name:
                    return _resolve_name(source, alias.name, tree, packages, depth + 1)
    lazy = _lazy_table(syntax, packages, name)
    return next(iter(lazy), base)


def _lazy_table(syntax: ast.Module, packages: tuple[str, ...], name: str | None = None) -> set[str]:
    """Modules named in a package's lazy-import tables (``{"Name": "package.module"}`` or ``"module:Class"``),
    for ``name`` only when given."""
    out = set()
    for node in syntax.body:
        value = node.value if isinstance(node, (ast.Assign, ast.AnnAssign)) else None
        if not isinstance(value, ast.Dict):
            continue
        for key, item in zip(value.keys, value.values):
            if not (isinstance(key, ast.Constant) and isinstance(item, ast.Constant) and isinstance(item.value, str)):
                continue
            module = item.value.partition(":")[0]
            if module.split(".")[0] in packages and (name is None or key.value == name):
                out.add(module)
    return out


def source_hash(modules, tree: SourceTree | None = None, extra: dict[str, bytes] | None = None) -> str:
    """16 hex digits of SHA-256 over the modules' names and sources (and ``extra`` named blobs)."""
    tree = tree or _working_tree()
    digest = hashlib.sha256()
    for module in sorted(modules):
        found = tree.read(module)
        digest.update(module.encode() + b"\0" + (found[1] if found else b"<missing>") + b"\0")
    for name, blob in sorted((extra or {}).items()):
        digest.update(name.encode() + b"\0" + blob + b"\0")
    return digest.hexdigest()[:16]


# -- tuners and plants --------------------------------------------------------------------------------
def tuner_modules(name: str, tree: SourceTree | None = None) -> list[str]:
    """The source modules of the registered tuner ``name``: the module of its class and its import closure.

    Raises
    ------
    ValueError
        An unknown tuner name (the message lists the registered ones).
    """
    if name not in registry._REGISTRY:
        registry.make(name)  # raises the registry's own ValueError, listing the names
    entry = registry._REGISTRY[name]
    module = entry.partition(":")[0] if isinstance(entry, str) else inspect.getmodule(entry).__name__
    packages = tuple(dict.fromkeys((*PROJECT_PACKAGES, module.split(".")[0])))
    return module_closure([module], tree, packages)


@cache
def _entry_module(env_id: str) -> str:
    entry = gym.spec(env_id).entry_point
    return entry.partition(":")[0] if isinstance(entry, str) else inspect.getmodule(entry).__name__


def plant_modules(env_id: str, tree: SourceTree | None = None) -> list[str]:
    """The source modules of a registered env: its entry point's module, :mod:`gbo_envs.ground_truth`, and
    their import closure."""
    module = _entry_module(env_id)
    packages = tuple(dict.fromkeys((*PROJECT_PACKAGES, module.split(".")[0])))
    return module_closure([module, "gbo_envs.ground_truth"], tree, packages)


def truth_table_path(env_id: str) -> str | None:
    """Repository-relative path of the env's shipped ground-truth table, or None if it ships none."""
    relative = f"gbo_envs/data/ground_truth/{env_id.rsplit('/', 1)[-1]}.npz"
    return relative if (REPO_ROOT / relative).is_file() else None
