"""Worker processes that end with the process that started them.

A worker pool's processes (joblib's ``loky`` workers, a forked ``multiprocessing``
pool) outlive a parent killed with SIGKILL: a busy worker finishes its task first,
an idle one waits for the next until its idle timeout (loky: 300 s), and a forked
worker holds the write end of its own task queue, so it never reads an end of file.
All that time they hold the parent's standard output and error, so a caller that
reads them (a shell pipeline, ``subprocess.run``) does not see the command end.

:func:`die_with_parent`, run first in each worker (the pools' ``initializer``), asks
Linux to send the worker SIGKILL when its parent ends (``prctl(PR_SET_PDEATHSIG)``,
prctl(2)); the resource trackers the pools start then read an end of file and exit too.
Elsewhere (macOS, Windows) it does nothing: there a worker ends when it next finds its
pool gone.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys

__all__ = ["die_with_parent"]

#: ``PR_SET_PDEATHSIG`` of ``<linux/prctl.h>``.
_PR_SET_PDEATHSIG = 1


def die_with_parent(parent: int | None = None) -> None:
    """In a worker process: be killed (SIGKILL) when the parent process ends; on Linux only, else a no-op.

    Linux delivers the signal when the thread that started the worker ends, which for a pool's
    workers is the parent's main thread or its pool-managing thread: both last as long as the pool.

    Parameters
    ----------
    parent : int, optional
        The process id of the parent that started the pool (``initargs=(os.getpid(),)``): a worker
        whose parent ended before the request (it has another parent by then) ends at once.
    """
    if not sys.platform.startswith("linux"):
        return
    parent = os.getppid() if parent is None else int(parent)
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):  # no libc with prctl (a static build): the pool's own shutdown only
        return
    if os.getppid() != parent:  # the parent ended before the request: end now
        os._exit(1)
