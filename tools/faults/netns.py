"""Network-namespace mode of a live campaign row: the listener behind a veth pair with ``tc netem``.

Needs root and iproute2 (``ip``, ``tc``) and, for impairments, the kernel's netem qdisc. Creates a
namespace ``sfaF<pid>_<n>``, a veth pair whose host end is ``10.213.<k>.1/30`` and whose namespace
end is ``10.213.<k>.2/30`` (addresses that exist only on this pair), and applies the row's input-link
impairments as netem on the host end (egress towards the listener). Everything is removed on exit.
Where any step is impossible the row is skipped with the reason (:class:`NetnsUnavailable`).
"""

from __future__ import annotations

import itertools
import os
import shutil
import subprocess

from tools.faults.config import Impairments
from tools.faults.errors import ModeUnsupported

_COUNTER = itertools.count()


class NetnsUnavailable(ModeUnsupported):
    """Namespace mode cannot run on this machine (the message says why); the row is skipped."""


def _run(argv: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(argv, capture_output=True, text=True, timeout=20.0, check=False)


def netem_args(imp: Impairments | None) -> list[str]:
    """The netem parameters equivalent to the profile's loss, delay, jitter, duplication, reordering
    and corruption (percentages and milliseconds, as ``tc`` takes them)."""
    if imp is None:
        return []
    args: list[str] = []
    if imp.delay_s > 0 or imp.jitter_s > 0 or imp.reorder > 0:
        delay_ms = max(imp.delay_s * 1000.0, 1.0 if imp.reorder > 0 else 0.0)
        args += ["delay", f"{delay_ms:.3f}ms"]
        if imp.jitter_s > 0:
            args.append(f"{imp.jitter_s * 1000.0:.3f}ms")
    if imp.loss > 0:
        args += ["loss", f"{imp.loss * 100.0:.4f}%"]
    if imp.duplicate > 0:
        args += ["duplicate", f"{imp.duplicate * 100.0:.4f}%"]
    if imp.reorder > 0:
        args += ["reorder", f"{imp.reorder * 100.0:.4f}%"]
    if imp.bitflip > 0:
        args += ["corrupt", f"{imp.bitflip * 100.0:.4f}%"]
    return args


class Namespace:
    """One namespace + veth pair, created by :meth:`create`, removed by :meth:`destroy`."""

    def __init__(self, name: str, host_if: str, k: int) -> None:
        self.name = name
        self.host_if = host_if
        self.outer_addr = f"10.213.{k}.1"
        self.inner_addr = f"10.213.{k}.2"
        self.netem: list[str] = []

    @classmethod
    def create(cls, spec) -> Namespace:
        if os.geteuid() != 0:
            raise NetnsUnavailable("netns mode skipped: needs root (network namespaces, veth, tc)")
        for tool in ("ip", "tc"):
            if shutil.which(tool) is None:
                raise NetnsUnavailable(f"netns mode skipped: `{tool}` (iproute2) not found")
        n = next(_COUNTER)
        k = (os.getpid() * 7 + n) % 250 + 1
        ns = cls(f"sfaF{os.getpid()}_{n}", f"sfF{os.getpid() % 100000}{n}", k)
        inner_if = ns.host_if + "i"
        steps = [
            ["ip", "netns", "add", ns.name],
            ["ip", "link", "add", ns.host_if, "type", "veth", "peer", "name", inner_if],
            ["ip", "link", "set", inner_if, "netns", ns.name],
            ["ip", "addr", "add", f"{ns.outer_addr}/30", "dev", ns.host_if],
            ["ip", "link", "set", ns.host_if, "up"],
            ["ip", "-n", ns.name, "addr", "add", f"{ns.inner_addr}/30", "dev", inner_if],
            ["ip", "-n", ns.name, "link", "set", inner_if, "up"],
            ["ip", "-n", ns.name, "link", "set", "lo", "up"],
        ]
        for argv in steps:
            res = _run(argv)
            if res.returncode != 0:
                ns.destroy()
                raise NetnsUnavailable(f"netns mode skipped: `{' '.join(argv)}` failed: {res.stderr.strip()}")
        ns.netem = netem_args(spec.input_link)
        if ns.netem:
            argv = ["tc", "qdisc", "add", "dev", ns.host_if, "root", "netem", *ns.netem]
            res = _run(argv)
            if res.returncode != 0:
                ns.destroy()
                raise NetnsUnavailable(f"netns mode skipped: tc netem unavailable ({res.stderr.strip()})")
        return ns

    def wrap(self, argv: list[str]) -> list[str]:
        """``argv`` run inside the namespace (``ip netns exec`` execs it: same pid)."""
        return ["ip", "netns", "exec", self.name, *argv]

    def child_pid(self, pid: int) -> int:
        return pid

    def qdisc_stats(self) -> str:
        res = _run(["tc", "-s", "qdisc", "show", "dev", self.host_if])
        return res.stdout

    def destroy(self) -> None:
        _run(["ip", "link", "del", self.host_if])
        _run(["ip", "netns", "del", self.name])
