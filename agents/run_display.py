"""How long work shows itself: the env's display name and the one progress-bar helper of the project.

Every loop that can take more than a few seconds (the tuning loop, RL pre-training,
study batches, twin diagnoses and reports) draws its bar with :func:`progress_bar`,
on stderr. The library's default is no bar (``progress=False``); the ``gbo`` command
line passes ``None`` (a bar only when stderr is a terminal) unless ``--quiet``.
"""

from __future__ import annotations

import os
import sys

__all__ = ["FALLBACK_COLUMNS", "FALLBACK_ROWS", "env_id", "progress_bar", "progress_enabled"]

#: The size taken for a terminal that reports 0 columns or rows (some pseudo-terminals, editors' shells).
FALLBACK_COLUMNS, FALLBACK_ROWS = 80, 24


def env_id(env) -> str:
    """The registered id of an env (wrappers allowed), else its class name."""
    spec = getattr(env, "spec", None)
    return spec.id if spec is not None else type(env.unwrapped).__name__


class _NoBar:
    """Stands in for a disabled bar: a disabled tqdm still allocates a multiprocessing lock."""

    total = None

    def refresh(self) -> None:
        pass

    def update(self, n: int = 1) -> None:
        pass

    def set_postfix_str(self, text: str = "", refresh: bool = True) -> None:
        pass

    def close(self) -> None:
        pass


def progress_enabled(enabled: bool | None) -> bool:
    """Whether a bar is drawn: ``True`` and ``False`` as given; ``None`` when stderr is a terminal.

    ``None`` is tqdm's ``disable=None`` rule: no bar in a pipe, a log file or CI.
    """
    if enabled is None:
        isatty = getattr(sys.stderr, "isatty", None)
        return bool(isatty is not None and isatty())
    return bool(enabled)


def progress_bar(total: int, desc: str, enabled: bool | None, initial: int = 0, unit: str = "exp",
                 leave: bool = True):
    """A tqdm bar of ``total`` steps on stderr, or a no-op stand-in when disabled.

    Parameters
    ----------
    total : int
        Steps of the loop.
    desc : str
        What the loop does, shown left of the bar.
    enabled : bool or None
        Draw the bar; ``None``: only when stderr is a terminal (:func:`progress_enabled`).
    initial : int, default 0
        Steps already done (a resumed session).
    unit : str, default "exp"
        What one step is.
    leave : bool, default True
        Keep the finished bar on screen (``False`` for a bar nested in another).
    """
    if not progress_enabled(enabled):
        return _NoBar()
    from tqdm.auto import tqdm

    # tqdm's dynamic_ncols, with a size of our own: tqdm takes a terminal's reported 0 rows as no room for
    # any bar and 0 columns as a bar 1 character wide (a 0 x 0 pseudo-terminal got no bar at all)
    columns, rows = _terminal_shape(sys.stderr)
    bar = tqdm(total=total, initial=initial, desc=desc, unit=unit, leave=leave, file=sys.stderr, ncols=columns,
               nrows=rows)
    bar.dynamic_ncols = _terminal_shape  # re-read on every refresh, as dynamic_ncols=True does
    return bar


def _terminal_shape(stream) -> tuple[int | None, int | None]:
    """tqdm's ``(ncols, nrows)`` of the terminal behind ``stream`` (one less than its size, as tqdm's own).

    A reported size of 0 (some pseudo-terminals) is taken as :data:`FALLBACK_COLUMNS` columns and
    :data:`FALLBACK_ROWS` rows; ``(None, None)`` when ``stream`` is no terminal.
    """
    try:
        columns, rows = os.get_terminal_size(stream.fileno())
    except (AttributeError, OSError, ValueError):  # no file descriptor, or not a terminal
        return None, None
    return (columns if columns > 0 else FALLBACK_COLUMNS) - 1, (rows if rows > 0 else FALLBACK_ROWS) - 1
