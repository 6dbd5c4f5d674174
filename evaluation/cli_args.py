"""The validation layer of the ``gbo`` command line: argument types and the one-line error policy.

Every sub-command declares its arguments with the ``type=`` callables of this
module (:func:`positive_int`, :func:`int_at_least`, :func:`json_object`,
:func:`env_id`), so a bad value is refused while parsing with a message that
names the argument and the allowed range. What only the running command can
find out (a CSV row, an unknown tuner, a rejected keyword argument) comes as a
``ValueError`` or ``TypeError`` from the Python API; :func:`error_message`
turns those, and the file errors, into the one line that :func:`evaluation.cli.main`
prints before it exits with :data:`EXIT_BAD_INPUT`.

``--import MODULE`` (:func:`import_modules`) imports a module the way
``python -m`` finds it: the current folder comes first on ``sys.path``.

A sub-command names its handler (:class:`Handler`, ``"module:function"``) rather than importing it, so
that the parser of every command, built at each start, loads none of the commands' code.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import pkgutil
import sqlite3
import sys
from dataclasses import dataclass

import gbo_envs  # noqa: F401  (registers the envs)

__all__ = [
    "EXIT_BAD_INPUT",
    "EnvId",
    "Handler",
    "OneLineParser",
    "OutputClosed",
    "check_env_id",
    "env_id",
    "error_message",
    "import_modules",
    "int_at_least",
    "job_count",
    "json_object",
    "positive_int",
    "seed",
]

#: Exit status of a command refused for bad input (argparse's own status for usage errors).
EXIT_BAD_INPUT = 2
#: Largest integer argument (SQLite's INTEGER and numpy's int64 hold at most this).
MAX_INT = 2**63 - 1
#: Largest seed (``--seed``): what every seeded library accepts (numpy's legacy ``RandomState``, scikit-learn).
MAX_SEED = 2**32 - 1


#: File errors and what they mean, most specific first.
_FILE_ERRORS = ((IsADirectoryError, "is a folder, expected a file"),
                (NotADirectoryError, "a part of the path is not a folder"),
                (FileNotFoundError, "no such file or folder"), (PermissionError, "permission denied"),
                (FileExistsError, "already exists"))


class OutputClosed(KeyboardInterrupt):
    """The reader of standard output went away (``gbo tune ... | head``): the command stops as if interrupted
    (a tuning session is left to resume, not failed), and :func:`evaluation.cli.main` ends quietly."""


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line on stderr (exit status 2), not usage + error."""

    def error(self, message: str):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


@dataclass(frozen=True)
class Handler:
    """A sub-command's handler named ``"module:function"``, imported when the command runs.

    ``gbo`` builds the parser of every sub-command at each start (:func:`evaluation.cli.build_parser`); a
    handler named, not imported, keeps each command from loading the code of the others (``gbo twin
    diagnose`` loads no study engine, scipy.stats or tuner; ``gbo bench`` no twin workbench).

    Parameters
    ----------
    target : str
        ``"package.module:function"``; the function takes the parsed ``argparse.Namespace`` and returns
        the exit status.
    """

    target: str

    def __call__(self, args: argparse.Namespace) -> int:
        return pkgutil.resolve_name(self.target)(args)


def positive_int(text: str) -> int:
    """An integer from 1 to :data:`MAX_INT` (``--workers``, ``--budget``, ``--batches``, ``--session``)."""
    return _int_in(text, 1, MAX_INT)


def int_at_least(low: int, high: int = MAX_INT):
    """A ``type=`` callable for an integer from ``low`` to ``high`` (e.g. ``int_at_least(2)`` for ``--folds``)."""

    def parse(text: str) -> int:
        return _int_in(text, low, high)

    parse.__name__ = f"integer >= {low}"
    return parse


def seed(text: str) -> int:
    """A seed (``--seed``): an integer from 0 to :data:`MAX_SEED`."""
    return _int_in(text, 0, MAX_SEED)


def _integer(text: str, expected: str) -> int:
    """``text`` as an integer, or the one-line error saying what was ``expected``."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None


def _int_in(text: str, low: int, high: int) -> int:
    value = _integer(text, f"an integer >= {low}")
    if value < low:
        raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {value}")
    if value > high:
        raise argparse.ArgumentTypeError(f"must be an integer from {low} to {high}, got {value}")
    return value


def usable_cores() -> int:
    """The cores this process may run on: its CPU affinity and the container's CPU quota (joblib's count)."""
    from joblib import cpu_count

    return max(1, int(cpu_count()))


def job_count(text: str) -> int:
    """A count of worker processes (``--jobs``): a positive integer, at most the usable cores (a larger one is
    capped, with a note on stderr), or a negative one counted back from the cores (``-1``: all of them), as
    joblib's ``n_jobs``."""
    value = _integer(text, "a nonzero integer (-1: all cores)")
    cores = usable_cores()
    if value == 0 or value < -cores:
        raise argparse.ArgumentTypeError(f"must be a nonzero integer from -{cores} to {cores} (-1: all {cores} "
                                         f"usable cores, 1: no worker processes), got {value}")
    if value > cores:
        print(f"note: --jobs {value} is more than the {cores} usable cores; using {cores}", file=sys.stderr)
        return cores
    return value


def json_object(text: str) -> dict:
    """A JSON object (``--env-kwargs``, ``--tuner-kwargs``); the message quotes the JSON error's position."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"not valid JSON ({exc.msg} at character {exc.pos}) in {text!r}; "
                                         "expected an object such as '{\"noise\": false}'") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object such as '{{\"noise\": false}}', got {text!r}")
    return value


class EnvId(str):
    """An env id from the command line, checked against the registry by :func:`check_env_id` after ``--import``."""


def env_id(text: str) -> EnvId:
    """An env id (``--env``); whether it is registered is checked once the ``--import`` modules ran."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a registered env id such as 'gbo_envs/DCMotor-v0', got ''")
    return EnvId(text.strip())


def check_env_id(value: str, imported=()) -> str:
    """``value`` if it is a registered env id, else ``ValueError`` listing the registered ids.

    Parameters
    ----------
    value : str
        An id such as ``gbo_envs/DCMotor-v0``; ``MODULE:ID`` only when ``MODULE``
        is among ``imported`` (gymnasium would otherwise import any module named
        in an id, without a word).
    imported : sequence of str
        Modules given with ``--import``.

    Raises
    ------
    ValueError
        An unregistered id, or ``MODULE:ID`` without ``--import MODULE``.
    """
    import gymnasium as gym

    module, colon, name = value.rpartition(":")
    if colon and module not in imported:
        raise ValueError(f"--env {value!r}: ids of the form MODULE:ID are not imported implicitly; pass "
                         f"--import {module} (the current folder is searched first) and --env {name}")
    if (name if colon else value) in gym.registry:
        return value
    ours = sorted(k for k in gym.registry if k.startswith("gbo_envs/"))
    raise ValueError(f"--env {value!r}: not a registered env id; registered: {', '.join(ours)} "
                     "(for your own env: --import MODULE that registers it)")


def import_modules(modules) -> None:
    """Import each module as ``python -m`` would find it (the current folder first on ``sys.path``).

    Raises
    ------
    ValueError
        A module that cannot be found, or whose import raises; the message names it.
    """
    if not modules:
        return
    here = os.getcwd()
    if here not in sys.path and "" not in sys.path:
        sys.path.insert(0, here)
    for module in modules:
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            missing = exc.name or module
            detail = "" if module == missing or module.startswith(f"{missing}.") else f" (it imports {missing!r})"
            raise ValueError(f"--import {module}: no module named {missing!r}{detail} in the current folder "
                             f"({here}) or the installed packages") from exc
        except Exception as exc:
            raise ValueError(f"--import {module}: importing it raised {type(exc).__name__}: {exc}") from exc


def error_message(exc: BaseException, db: str | None = None) -> str | None:
    """The one line for a user-facing error, or None for an unexpected one (a bug).

    ``ValueError`` and ``TypeError`` carry the API's own message; file errors
    name the file; a codec error names the codec and the byte; an SQLite error
    names ``db``, the command's database file.
    """
    if isinstance(exc, UnicodeDecodeError):
        return f"not {exc.encoding} text: byte {exc.object[exc.start:exc.start + 1]!r} at position {exc.start}"
    if isinstance(exc, (ValueError, TypeError)):
        return str(exc) or type(exc).__name__
    for kind, what in _FILE_ERRORS:
        if isinstance(exc, kind):
            return f"{exc.filename}: {what}" if exc.filename else str(exc)
    if isinstance(exc, sqlite3.DatabaseError):
        return f"{db or 'database'}: {exc}" + (
            "; the file is damaged (restore it from a backup, or give another --db file)"
            if "malformed" in str(exc) else "")
    if isinstance(exc, OSError) and exc.filename:
        return f"{exc.filename}: {exc.strerror or exc}"
    try:
        from gymnasium.error import Error as GymError
    except ImportError:  # pragma: no cover - gymnasium is a dependency
        return None
    if isinstance(exc, GymError):
        return str(exc)
    return None
