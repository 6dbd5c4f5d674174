"""How long work shows itself: the env's display name and the one progress-bar helper of the project.

Every loop that can take more than a few seconds (the tuning loop, RL pre-training,
study batches, twin diagnoses and reports) draws its bar with :func:`progress_bar`,
on stderr. The library's default is no bar (``progress=False``); the ``gbo`` command
line passes ``None`` (a bar only when stderr is a terminal) unless ``--quiet``.
"""

from __future__ import annotations

import sys

__all__ = ["env_id", "progress_bar", "progress_enabled"]


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

    return tqdm(total=total, initial=initial, desc=desc, unit=unit, leave=leave, file=sys.stderr, dynamic_ncols=True)
