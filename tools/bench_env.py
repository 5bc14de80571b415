"""What ``sfa bench`` ran on: machine, load, versions, commit (recorded with every table)."""

from __future__ import annotations

import os
import platform
import subprocess
from datetime import UTC, datetime
from pathlib import Path


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load_average() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def _version(module: str) -> str:
    try:
        from importlib.metadata import version

        return version(module)
    except Exception:  # noqa: BLE001 - a missing package is reported as such
        return "not installed"


def commit(root: Path) -> str:
    try:
        out = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    head = out.stdout.strip() or "unknown"
    return head + ("+local changes" if dirty.stdout.strip() else "")


def environment(root: Path, mode: str) -> dict:
    """Machine, cores, memory, load, Python and library versions, C compiler, commit."""
    from tools.bench_replay import load_benchmark_module

    try:
        cc_mod = load_benchmark_module("c/cref")
        cc = cc_mod.find_compiler()
        cc_text = cc_mod.compiler_version(cc) if cc else "none"
    except Exception as exc:  # noqa: BLE001 - reported, not fatal
        cc_text = f"unavailable ({exc})"
    try:
        mem_kb = int(
            next(
                line.split()[1]
                for line in Path("/proc/meminfo").read_text().splitlines()
                if line.startswith("MemTotal")
            )
        )
        mem = f"{mem_kb / 1024 / 1024:.1f} GiB"
    except (OSError, StopIteration, ValueError):
        mem = "?"
    versions = {
        "python": platform.python_version(),
        **{
            m: _version(m)
            for m in ("numpy", "numba", "filterpy", "scipy", "pyproj", "shapely", "dpkt", "rich")
        },
        "cc": cc_text,
    }
    return {
        "mode": mode,
        "machine": f"{_cpu_model()}, {os.cpu_count()} logical cores, {mem}, {platform.system()} "
        f"{platform.release()}",
        "started_utc": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "load_start": load_average(),
        "commit": commit(root),
        "versions": versions,
        "versions_text": ", ".join(f"{k} {v}" for k, v in versions.items()),
    }
