"""tools.memory_policy: with the policy a freed large block is reused without page faults; without
it every new block is faulted in again (each case in its own process: the policy is process-wide)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

PROBE = """
import resource, sys
import numpy as np
if sys.argv[1] == "keep":
    from tools.memory_policy import keep_freed_memory
    assert keep_freed_memory()
faults = []
for _ in range(3):
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    a = np.ones(50 * 2**20 // 8)  # 50 MiB, every page written
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
    del a
print(*faults)
"""


def _faults(mode: str) -> list[int]:
    out = subprocess.run([sys.executable, "-c", PROBE, mode], check=True, capture_output=True, text=True,
                         timeout=60)
    return [int(v) for v in out.stdout.split()]


def test_freed_blocks_are_reused_without_page_faults():
    if not sys.platform.startswith("linux"):
        pytest.skip("glibc's mallopt: Linux only")
    keep = _faults("keep")
    default = _faults("default")
    # (page counts depend on the kernel's huge pages: numpy asks for them on large arrays)
    assert keep[0] > 0 and default[0] > 0  # the first block is faulted in either way
    assert min(default[1:]) > default[0] // 2  # glibc's default: mmap, munmap, fault again
    assert max(keep[1:]) < min(default[1:]) // 10  # with the policy: reused from the heap


def test_policy_turns_numpys_huge_page_requests_off():
    # (NumPy reads NUMPY_MADVISE_HUGEPAGE at import: 1 forces the requests on before the policy)
    code = ("from tools.memory_policy import huge_page_requests, keep_freed_memory\n"
            "before = huge_page_requests()\nkeep_freed_memory()\nprint(before, huge_page_requests())")
    out = subprocess.run([sys.executable, "-c", code, "x"], check=True, capture_output=True, text=True,
                         timeout=60, env={**os.environ, "NUMPY_MADVISE_HUGEPAGE": "1"})
    assert out.stdout.split() == ["True", "False"]
