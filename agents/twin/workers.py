"""Independent pieces of a diagnosis in worker processes: the other cores for a user's command.

A diagnosis is mostly fits that do not depend on one another: the candidates' starting
problems, their least-squares fits, the cross-validation's refits. :func:`map_independent`
runs such pieces in the worker processes of a :func:`worker_processes` block (``n_jobs`` forked
processes), or of the caller's joblib configuration, and one after another in this process when
there is one job (joblib's default). Every piece is computed by the same code from the same inputs
either way, so the results do not depend on ``n_jobs``.

Why forked processes: the Python between the compiled parts holds the GIL, so two threads
made the Coulomb case of ``benchmarks/bench_diagnose.py`` only 10 % faster; forked workers
start in milliseconds with the parent's imports and compiled kernels, where joblib's default
``loky`` workers are fresh interpreters that import them again (2 s each on the project machine).
The workers are forked at the first map of a :func:`worker_processes` block, once the parent has
loaded the compiled replay, so that they inherit it. They are a plain ``multiprocessing`` pool:
joblib's ``"multiprocessing"`` backend, used before, starts loky's resource tracker for its
memmapping folders, which these pieces never use, and that tracker is one more fresh interpreter
importing joblib and numpy (0.4 s of CPU at the first map of every command).

Where forking is not safe, on macOS (Python's documentation: its system libraries may start
threads, and a forked child of such a process can crash; Python starts processes by ``spawn``
there since 3.8), or not available (Windows), the pieces go to joblib's default ``loky`` workers
instead: fresh interpreters, each piece pickled with the records it takes.
"""

from __future__ import annotations

import multiprocessing
import numbers
import os
import sys
import warnings
from collections.abc import Callable, Iterable, Iterator
from contextlib import ExitStack, contextmanager
from contextvars import ContextVar
from dataclasses import dataclass

from joblib import Parallel, cpu_count, delayed, effective_n_jobs, parallel_config

from agents.process_lifetime import die_with_parent

__all__ = ["check_n_jobs", "map_independent", "worker_processes", "workers_available"]

#: Whether this platform forks safely a process that has loaded numpy's BLAS (not macOS; no fork on Windows).
FORK_IS_SAFE = "fork" in multiprocessing.get_all_start_methods() and sys.platform != "darwin"


@dataclass(frozen=True)
class _Shared:
    """Stands, in a piece sent to a worker, for the block's shared object number ``index``."""

    index: int


class _Pool:
    """The ``n_jobs`` worker processes of one :func:`worker_processes` block, forked at the block's first map.

    Forking late lets the workers inherit what the parent loaded before it: the compiled
    kernels (:mod:`gbo_envs.physics.kernels`; loading them from numba's cache took each
    worker 0.4 s of CPU on the project machine), the modules imported on first use, and the
    block's ``shared`` objects, which a piece then names instead of carrying them pickled (the
    records: 1 MB in each of the 250 pieces of a diagnosis of 12 x 2,501 samples).
    """

    def __init__(self, stack: ExitStack, shared: tuple, n_jobs: int):
        self.owner = os.getpid()
        self.shared = shared
        self.n_jobs = n_jobs
        self._stack = stack
        self._processes = None

    def map(self, fn: Callable, args: list[tuple]) -> list:
        """``fn(*a)`` for each ``a`` of ``args`` in the workers, in order, one piece per dispatch (batches of
        pieces left a worker idle at a map's end: Coulomb case, 0.99 / 0.62 s of busy time on the two)."""
        if self._processes is None:
            # heavy dependency: numba (kept off the diagnose start-up path)
            from gbo_envs.physics.kernels import warm_up

            warm_up(("open_loop",))  # loaded once here, inherited by the workers
            # left by terminating the workers: every map has returned by then, or is abandoned by an error
            self._processes = self._stack.enter_context(multiprocessing.get_context("fork").Pool(
                self.n_jobs, initializer=die_with_parent, initargs=(os.getpid(),)))  # they end with this process
        pieces = [(fn, tuple(next((_Shared(i) for i, s in enumerate(self.shared) if a is s), a) for a in piece))
                  for piece in args]
        return self._processes.map(_with_shared, pieces, chunksize=1)


#: The pool of the innermost :func:`worker_processes` block (a forked worker inherits the variable, and runs
#: its own maps one by one: the pool belongs to the process that opened the block).
_POOL: ContextVar[_Pool | None] = ContextVar("agents_twin_worker_pool", default=None)


def check_n_jobs(n_jobs) -> int | None:
    """``n_jobs`` checked: ``None`` (joblib's active configuration, one process by default), a positive
    count of processes, at most the usable cores (:func:`joblib.cpu_count`: the CPU affinity and the
    container's quota; a larger count is capped, with a :class:`UserWarning`), or a negative one counted
    back from the cores (``-1``: all of them, ``-cores`` at most); :func:`worker_processes` warns of a cap."""
    if n_jobs is None:
        return None
    cores = max(1, cpu_count())
    if isinstance(n_jobs, bool) or not isinstance(n_jobs, numbers.Integral) or n_jobs == 0 or n_jobs < -cores:
        raise ValueError(f"n_jobs (--jobs): must be None, a number of processes from 1 to the {cores} usable cores "
                         f"or a negative one counted back from them, -1 (all) to -{cores}, got {n_jobs!r}")
    return min(int(n_jobs), cores)  # more processes than cores only share them, at the cost of their memory


@contextmanager
def worker_processes(n_jobs: int | None, shared: tuple = ()) -> Iterator[None]:
    """Within it, :func:`map_independent` uses ``n_jobs`` forked worker processes, forked once, at the
    first map (``None``: the caller's joblib configuration is left as it is). Where processes cannot
    be forked safely (:data:`FORK_IS_SAFE`: macOS, Windows), ``n_jobs`` of joblib's ``loky`` workers;
    where processes cannot nest (a worker, a thread), the pieces run one by one.

    ``shared`` objects (that do not change within the block) reach forked workers by the fork, not
    pickled with each piece that takes them as an argument.
    """
    jobs = check_n_jobs(n_jobs)
    if jobs is None:
        yield
        return
    if jobs != n_jobs and n_jobs > 0:
        warnings.warn(f"n_jobs (--jobs) = {n_jobs} is more than the {jobs} usable cores; using {jobs}", UserWarning,
                      stacklevel=3)
    n_jobs = jobs
    if not FORK_IS_SAFE:
        with parallel_config(backend="loky", n_jobs=n_jobs):
            yield
        return
    # joblib's rules for n_jobs: a negative count from the cores; one job in a daemon process or a thread
    with parallel_config(backend="multiprocessing", n_jobs=n_jobs), ExitStack() as stack:
        jobs = effective_n_jobs(None)
        if jobs == 1:
            yield
            return
        token = _POOL.set(_Pool(stack, tuple(shared), jobs))
        try:
            yield
        finally:
            _POOL.reset(token)


def _own_pool() -> _Pool | None:
    """The pool of the innermost :func:`worker_processes` block if this process opened it."""
    pool = _POOL.get()
    return pool if pool is not None and pool.owner == os.getpid() else None


def workers_available() -> bool:
    """Whether :func:`map_independent` would run two or more pieces in worker processes here: this process's
    own pool, or the caller's joblib configuration with more than one job."""
    return _own_pool() is not None or effective_n_jobs(None) > 1


def map_independent(fn: Callable, args: Iterable[tuple]) -> Iterator:
    """``fn(*a)`` for each ``a`` of ``args``, in order: all at once from the worker processes of
    :func:`worker_processes` (or of the active joblib configuration), or one by one as computed here
    when there is one job or one piece.

    ``fn`` and the arguments must pickle (a module-level function; numpy arrays, dataclasses).
    """
    args = list(args)
    if len(args) < 2 or not workers_available():
        return (fn(*a) for a in args)
    pool = _own_pool()
    if pool is not None:
        return iter(pool.map(fn, args))
    return iter(Parallel(batch_size=1)(delayed(fn)(*a) for a in args))  # the caller's joblib configuration


def _with_shared(piece: tuple):
    """``fn(*args)`` of ``piece = (fn, args)`` in a worker, each :class:`_Shared` name replaced by the object it
    inherited."""
    fn, args = piece
    shared = _POOL.get().shared
    return fn(*(shared[a.index] if isinstance(a, _Shared) else a for a in args))
