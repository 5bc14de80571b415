"""Child-process helpers shared by the tools that orchestrate real processes (demo, fault campaigns,
the listener benchmarks and the live tests)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

from tools.errors import ToolError


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port the kernel just handed out on ``host`` (free at the time of the call)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def process_cpu_s(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far [s] (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def proc_status_kib(pid: int, key: str) -> int | None:
    """A ``/proc/PID/status`` figure in KiB (``VmRSS``, ``VmHWM``, ...); None when unreadable."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def listen_argv(port: int, obcu_port: int, *sets: str, track: str | None = None,
                host: str = "127.0.0.1") -> list[str]:
    """``sfa listen`` on ``host:port`` sending to the OBCU at ``host:obcu_port``, with ``--set`` overrides."""
    argv = [sys.executable, "-m", "sfa", "listen", "--bind", host, "--port", str(port),
            "--obcu", f"{host}:{obcu_port}"]
    if track:
        argv += ["--track", str(track)]
    for item in sets:
        argv += ["--set", item]
    return argv


def start_listener(argv: list[str], log_path: Path, timeout_s: float, preexec_fn=None) -> subprocess.Popen:
    """Start ``argv`` (an ``sfa listen``) with stderr to ``log_path`` and wait for its READY log event.

    Raises ToolError (with the log's tail) if it exits or is not ready within ``timeout_s``."""
    with open(log_path, "w") as log_fh:
        proc = subprocess.Popen(argv, stderr=log_fh, stdout=subprocess.DEVNULL,
                                preexec_fn=preexec_fn)  # noqa: PLW1509 - callers pass os.nice only
    deadline = time.monotonic() + timeout_s
    while '"event":"ready"' not in log_path.read_text():
        if proc.poll() is not None or time.monotonic() > deadline:
            terminate([proc], grace_s=2.0)
            raise ToolError(f"listener failed to start: {log_path.read_text()[-2000:]}")
        time.sleep(0.05)
    return proc


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
