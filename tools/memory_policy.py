"""The replay process's memory policy: keep freed memory for reuse instead of returning it to the OS.

A compiled replay allocates and frees its large column arrays (tens of MB each) once per stage. With
glibc's defaults each such block is its own ``mmap``, returned by ``munmap`` when freed, and every
page of the next one is faulted in again by the kernel: on the benchmark's 92 min capture about
14,000 page faults per replay, and their system time varied from 0.05 to 0.59 s per run against a
constant 0.38-0.41 s of user time (docs/performance.md). ``mallopt`` can make the heap serve such
blocks and keep them: the replays after the first then fault about 1,100 pages each.

NumPy also asks the kernel for transparent huge pages (``madvise(MADV_HUGEPAGE)``) on every array of
4 MB or more. Where the kernel honours that on request (``/sys/kernel/mm/transparent_hugepage`` set to
``madvise``, with defrag on ``madvise``), a first touch of such an array zeroes a 2 MB page and may
compact memory synchronously to find one: measured on the replay benchmark's capture, 0.70 s of system
time in a process's first replay and 0.21 s in its second (against 0.16 and 0.03-0.09 s with 4 KB
pages, user time within 3 %), and a slowest-of-ten that varied from run to run with it. The policy
turns that request off (NumPy's own switch, the one ``NUMPY_MADVISE_HUGEPAGE=0`` sets at import).

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
    """Apply the policy to this process; True when glibc took it (the huge-page request is turned off
    in any case, where NumPy has the switch)."""
    _no_huge_page_requests()
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


def _huge_page_switch():
    """NumPy's switch for its huge-page requests (it returns the previous state), or None."""
    try:
        from numpy._core import multiarray
    except ImportError:  # NumPy 1.x
        from numpy.core import multiarray
    return getattr(multiarray, "_set_madvise_hugepage", None)


def _no_huge_page_requests() -> None:
    """NumPy stops asking for transparent huge pages on its large arrays (module docstring)."""
    switch = _huge_page_switch()
    if switch is not None:
        switch(False)


def huge_page_requests() -> bool:
    """True while NumPy asks for huge pages on its large arrays."""
    switch = _huge_page_switch()
    if switch is None:
        return False
    state = bool(switch(False))
    switch(state)
    return state
