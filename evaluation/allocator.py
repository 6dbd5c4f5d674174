"""Keep freed memory for reuse: glibc's allocator settings for the twin's fitting passes.

The grey-box fits (:func:`agents.twin.least_squares.fit_problems`) allocate and free arrays
of 1-25 MB several hundred times per diagnosis (simulation batches of up to 1,266 rows
of 2,501 samples). With glibc's defaults such blocks go back to the kernel (``mmap``
above a moving threshold, heap trimming, one arena per thread), so every new block is
fresh pages that the kernel must fault in and zero: ``gbo twin diagnose`` on 12 records
of DCMotorRig-v0 took 1.3 million page faults and 3-4 s of system time in 15.5-17.6 s.
With a fixed ``mmap`` threshold of 64 MiB, a trim threshold of 256 MiB and one arena
the same command took 49,000 faults, 0.9 s of system time and 12.3 s, at a peak
resident size of 480 MB instead of 1.1 GB, with the same output
(``benchmarks/bench_diagnose.py --command``).

The ``gbo`` command applies it to its own process; a Python session that fits twins may
call :func:`retain_freed_memory` too. Off glibc it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import platform

__all__ = ["retain_freed_memory"]

#: ``mallopt`` parameters (glibc's ``malloc.h``) and the values set.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -3, -8
_SETTINGS = ((_M_MMAP_THRESHOLD, 64 << 20), (_M_TRIM_THRESHOLD, 256 << 20), (_M_ARENA_MAX, 1))


def retain_freed_memory() -> bool:
    """Make glibc keep freed blocks up to 64 MiB for reuse (see the module doc); process-wide.

    Returns
    -------
    bool
        Whether every setting was taken (``False`` off glibc, where nothing is changed).
    """
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return all(mallopt(parameter, value) == 1 for parameter, value in _SETTINGS)
