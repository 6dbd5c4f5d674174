"""Independent pieces of a diagnosis in worker processes: the other cores for a user's command.

A diagnosis is mostly fits that do not depend on one another: the candidates' starting
problems, their least-squares fits, the cross-validation's refits. :func:`map_independent`
runs such pieces in the worker processes of joblib's active configuration
(:func:`worker_processes` sets it: ``n_jobs`` forked processes, joblib's ``"multiprocessing"``
backend), and one after another in this process when that configuration has one job (joblib's
default). Every piece is computed by the same code from the same inputs either way, so the
results do not depend on ``n_jobs``.

Why forked processes: the Python between the compiled parts holds the GIL, so two threads
made the Coulomb case of ``benchmarks/bench_diagnose.py`` only 10 % faster; forked workers
start in milliseconds with the parent's imports and compiled kernels, where joblib's default
``loky`` workers are fresh interpreters that import them again (2 s each on the project machine).
"""

from __future__ import annotations

import numbers
import os
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar

from joblib import Parallel, delayed, effective_n_jobs, parallel_config

__all__ = ["check_n_jobs", "map_independent", "worker_processes", "workers_available"]

#: The pool of the innermost :func:`worker_processes` block, with the process that owns it (a forked worker
#: inherits the variable, and runs its own maps one by one).
_POOL: ContextVar[tuple[int, Parallel] | None] = ContextVar("agents_twin_worker_pool", default=None)


def check_n_jobs(n_jobs) -> int | None:
    """``n_jobs`` checked: ``None`` (joblib's active configuration, one process by default), a positive
    count of processes, or a negative one counted back from the cores (``-1``: all of them)."""
    if n_jobs is None:
        return None
    if isinstance(n_jobs, bool) or not isinstance(n_jobs, numbers.Integral) or n_jobs == 0:
        raise ValueError(f"n_jobs (--jobs): must be None, a positive number of processes or a negative one "
                         f"counted back from the cores (-1: all), got {n_jobs!r}")
    return int(n_jobs)


@contextmanager
def worker_processes(n_jobs: int | None) -> Iterator[None]:
    """Within it, :func:`map_independent` uses ``n_jobs`` forked worker processes, forked once (``None``:
    the caller's joblib configuration is left as it is)."""
    if check_n_jobs(n_jobs) is None:
        yield
        return
    with parallel_config(backend="multiprocessing", n_jobs=n_jobs):
        if effective_n_jobs(None) == 1:  # one job, or refused where forking cannot nest (a worker, a thread)
            yield
            return
        # one pool for every map of the block, forked once; one piece per dispatch (joblib's automatic batches
        # left a worker idle at a map's end: Coulomb case, 0.99 / 0.62 s of busy time on the two)
        with Parallel(batch_size=1) as pool:
            token = _POOL.set((os.getpid(), pool))
            try:
                yield
            finally:
                _POOL.reset(token)


def workers_available() -> bool:
    """Whether :func:`map_independent` would run two or more pieces in worker processes here."""
    owner, _ = _POOL.get() or (None, None)
    return owner == os.getpid() or effective_n_jobs(None) > 1


def map_independent(fn: Callable, args: Iterable[tuple]) -> Iterator:
    """``fn(*a)`` for each ``a`` of ``args``, in order: all at once from the worker processes of
    :func:`worker_processes` (or of the active joblib configuration), or one by one as computed here
    when there is one job or one piece.

    ``fn`` and the arguments must pickle (a module-level function; numpy arrays, dataclasses).
    """
    args = list(args)
    owner, pool = _POOL.get() or (None, None)
    if owner != os.getpid():
        pool = None
    if len(args) < 2 or not workers_available():
        return (fn(*a) for a in args)
    return iter((pool or Parallel(batch_size=1))(delayed(fn)(*a) for a in args))

