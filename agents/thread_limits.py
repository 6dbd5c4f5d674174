"""One thread for the BLAS (and optionally OpenMP) pools, through threadpoolctl.

The GP's matrices and the twin's many small matrix exponentials are too small
for BLAS threads to help: they only contend and spin. A study worker also runs
single-threaded so that every backend computes the same numbers and the cores
are shared by processes, not oversubscribed by threads.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager

from threadpoolctl import ThreadpoolController

__all__ = ["blas_kernels", "single_thread"]

#: Values of ``user_api``: the BLAS pools, the OpenMP pools, or (None) both.
USER_APIS = ("blas", "openmp", None)

# Inspecting the loaded libraries costs about 7 ms, so the controller is kept;
# it is rebuilt when a module was imported since, as that may have loaded a new pool.
_controller: ThreadpoolController | None = None
_n_modules = -1

# Open blocks per user_api: inside one, a nested block of the same pools (or of a subset) is a
# no-op, since setting and restoring the limits costs about 50 us, as much as a GP prediction
# of one point (an EI polish makes dozens).
_open_blocks: dict[str | None, int] = {api: 0 for api in USER_APIS}


def _thread_pools() -> ThreadpoolController:
    global _controller, _n_modules
    if _controller is None or len(sys.modules) != _n_modules:
        _controller = ThreadpoolController()
        _n_modules = len(sys.modules)
    return _controller


def single_thread(user_api: str | None = "blas"):
    """Limit the thread pools to one thread inside a ``with`` block or a decorated function.

    Parameters
    ----------
    user_api : {"blas", "openmp"} or None, default "blas"
        Which pools to limit; None limits both.

    Examples
    --------
    >>> with single_thread():
    ...     pass
    >>> @single_thread()
    ... def fit():
    ...     pass

    Returns
    -------
    contextlib.AbstractContextManager
        Also usable as a decorator: each call of the function enters it anew. Inside a block
        that already limits these pools (the same ``user_api``, or ``None``), it changes nothing.
    """
    if user_api not in USER_APIS:
        raise ValueError(f"user_api: must be one of {USER_APIS}, got {user_api!r}")
    return _one_thread(user_api)


@contextmanager
def _one_thread(user_api: str | None):
    if _open_blocks[None] or _open_blocks[user_api]:
        yield  # an enclosing block already holds these pools at one thread
        return
    limiter = _thread_pools().limit(limits=1, user_api=user_api)
    _open_blocks[user_api] += 1
    try:
        yield
    finally:
        _open_blocks[user_api] -= 1
        limiter.restore_original_limits()


def blas_kernels() -> set[str]:
    """The kernel families (``OPENBLAS_CORETYPE`` names, e.g. ``"Haswell"``) of the OpenBLAS libraries loaded.

    numpy and scipy each load their own OpenBLAS, which picks its kernels by the CPU unless
    ``OPENBLAS_CORETYPE`` names them; the same matrices then give results that differ in the last bits.
    """
    return {info["architecture"] for info in _thread_pools().info()
            if info.get("internal_api") == "openblas" and info.get("architecture")}
