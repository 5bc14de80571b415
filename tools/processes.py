"""Child-process helpers shared by the tools that orchestrate real processes (demo, fault campaigns)."""

from __future__ import annotations

import subprocess
import time


def terminate(procs: list[subprocess.Popen], grace_s: float = 10.0) -> None:
    """SIGTERM every live process, wait up to ``grace_s`` in total, then SIGKILL what is left."""
    for p in procs:
        if p.poll() is None:
            p.terminate()
    deadline = time.monotonic() + grace_s
    for p in procs:
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=5.0)
