"""The replay process's memory policy: keep freed memory for reuse instead of returning it to the OS.

A compiled replay allocates and frees its large column arrays (tens of MB each) once per stage. With
glibc's defaults each such block is its own ``mmap``, returned by ``munmap`` when freed, and every
page of the next one is faulted in again by the kernel: on the benchmark's 92 min capture about
14,000 page faults per replay, and their system time varied from 0.05 to 0.59 s per run against a
constant 0.38-0.41 s of user time (docs/performance.md). ``mallopt`` can make the heap serve such
blocks and keep them: the replays after the first then fault about 1,100 pages each.

Only for processes that run replays and then exit or replay again (``sfa replay``, the replay
benchmark): the listener daemon keeps glibc's defaults, so that its resident memory falls back after
a peak (its unit's MemoryMax). A C library other than glibc: nothing changes.
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_TRIM_THRESHOLD = -1  #: glibc mallopt parameter: free memory at the heap's top kept up to this [bytes]
M_MMAP_THRESHOLD = -3  #: glibc mallopt parameter: blocks at least this large get their own mmap [bytes]
KEEP_BYTES = 1 << 30  #: both set to 1 GiB: the replay's blocks come from the heap and stay there


def keep_freed_memory() -> bool:
    """Apply the policy to this process; True when glibc took it."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt): the defaults stay
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, KEEP_BYTES)) and bool(mallopt(M_TRIM_THRESHOLD, KEEP_BYTES))
