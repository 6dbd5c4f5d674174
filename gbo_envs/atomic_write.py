"""Write a file so that a reader only ever sees its complete old or complete new content.

Every user-facing file the project writes (``gbo export`` CSV, reports, study
results and figures) goes through :func:`atomic_write`: the content goes to a
temporary file in the same folder, which is flushed to disk (``fsync``) and
then renamed over the target with :func:`os.replace` (atomic on POSIX and
Windows). A crash or a SIGKILL at any moment leaves the target as it was, plus
at worst a stray ``.NAME.*.tmp`` file beside it.

>>> with atomic_write("out/data.csv") as handle:  # doctest: +SKIP
...     frame.to_csv(handle, index=False)
"""

from __future__ import annotations

import contextlib
import os
import secrets
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import IO

__all__ = ["atomic_write"]

_MODES = ("w", "wb")


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "w", *, encoding: str | None = "utf-8",
                 newline: str | None = None) -> Iterator[IO]:
    """Open a temporary file beside ``path`` for writing; on success, move it into place atomically.

    Parameters
    ----------
    path : str or Path
        The file to write (its folder is created). A symbolic link is written
        through: its target is replaced, the link stays.
    mode : {"w", "wb"}, default "w"
        Text or binary.
    encoding : str or None, default "utf-8"
        Text encoding (text mode only).
    newline : str or None, optional
        As :func:`open` (text mode only); ``""`` writes line ends unchanged.

    Yields
    ------
    file object
        The temporary file. If the ``with`` block raises, it is deleted and
        ``path`` is left untouched.

    Raises
    ------
    ValueError
        If ``mode`` is not ``"w"`` or ``"wb"``.
    IsADirectoryError
        If ``path`` is a folder.

    Notes
    -----
    An existing target keeps its permission bits; a new file gets the usual
    ``0o666`` less the umask.
    """
    if mode not in _MODES:
        raise ValueError(f"mode: expected one of {_MODES}, got {mode!r}")
    path = Path(os.path.realpath(path))
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder; give the name of a file to write")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    try:
        text = {"encoding": encoding, "newline": newline} if mode == "w" else {}
        with os.fdopen(fd, mode, **text) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        with contextlib.suppress(FileNotFoundError):
            os.chmod(tmp, stat.S_IMODE(os.stat(path).st_mode))
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _sync_folder(path.parent)


def _sync_folder(folder: Path) -> None:
    """Flush the folder entry of the rename to disk (POSIX; a no-op where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
