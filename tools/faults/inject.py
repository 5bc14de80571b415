"""The live campaign's injector: forged and garbage datagrams from a process of their own.

    python -m tools.faults.inject --target HOST:PORT --profile links.toml --table input_injector \
        --seed N --t0 MONOTONIC [--duration S]

On the replay path the input link's :class:`~tools.faults.core.FaultCore` makes the injections; live,
generating a 50,000 datagrams/s flood inside the proxy process that also forwards the real stream
delays the real stream in the proxy, so the campaign's latency figure would measure the proxy. The
live runner therefore gives the proxy only the forwarding impairments (and forgeries that pose as a
real sender: they must leave from that sender's upstream socket) and starts this process for the rest.

Schedule, as the core's: the k-th forgery is due at ``t0 + inject_start_s + k / forge_rate_hz`` (at most
``forge_count``), the k-th garbage datagram at ``t0 + inject_start_s + k / garbage_rate_hz``, none at or
after ``t0 + inject_end_s`` nor inside a blackout window. ``t0`` is a ``time.monotonic()`` value (the
proxy's start, which it logs): CLOCK_MONOTONIC is shared by the processes of one machine. Forged
datagrams come from ``numpy.random.default_rng([seed, 1])`` (:func:`~tools.faults.forge.forge_valid` /
:func:`~tools.faults.forge.forge_invalid`), garbage from ``default_rng([seed, 2])``
(:func:`~tools.faults.forge.garbage_batch`, drawn in blocks before it is due so that the sending loop
only sends): two generators, so the sequence of datagrams a seed gives does not depend on how the
sends fall into rounds. Everything leaves from one socket of its own (as the proxy's ``FORGE_SENDER``).

Counted: only what ``sendto`` accepted (``forged_valid``, ``forged_invalid``, ``garbage``, ``emitted``);
refusals are ``send_errors``. On exit (schedule done, ``--duration``, SIGTERM or SIGINT) one JSON line
``{"event": "injector_exit", ..., "t_first": ..., "t_last": ...}`` goes to stderr (monotonic times of
the first and last datagram sent).
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import socket
import sys
import time
from typing import Any

import numpy as np

from tools.faults.config import Impairments
from tools.faults.forge import forge_invalid, forge_targeted, forge_valid, garbage_batch

TICK_S = 0.0005  #: sleep between sending rounds (datagrams due meanwhile go out together) [s]
BLOCK = 4096  #: garbage datagrams drawn per block [count]


class Injector:
    """Sends the injections of ``imp`` to ``target`` from t0 on; :meth:`run` returns the counters."""

    def __init__(self, imp: Impairments, seed: int, target: tuple[str, int], t0: float,
                 bind_host: str | None = None) -> None:
        self.imp = imp.validate()
        self.seed = seed
        self.target = target
        self.t0 = t0
        self.rng = np.random.default_rng([seed, 1])  # forgeries
        self.garbage_rng = np.random.default_rng([seed, 2])
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((bind_host or target[0], 0))
        self.counters: dict[str, int] = dict.fromkeys(
            ("forged_valid", "forged_invalid", "forged_foreign", "garbage", "emitted", "send_errors",
             "skipped_blackout"), 0
        )
        self.t_first: float | None = None
        self.t_last: float | None = None
        self._stop = False
        imp = self.imp
        start, end = t0 + imp.inject_start_s, t0 + imp.inject_end_s
        self._start, self._end = start, end
        n_forge = 0
        if imp.forge_rate_hz > 0:
            n_forge = math.ceil((end - start) * imp.forge_rate_hz) if math.isfinite(end) else 2**62
            if imp.forge_count:
                n_forge = min(n_forge, imp.forge_count)
        n_garbage = 0
        if imp.garbage_rate_hz > 0:
            n_garbage = math.ceil((end - start) * imp.garbage_rate_hz) if math.isfinite(end) else 2**62
        self._total = {"forge": n_forge, "garbage": n_garbage}
        self._done = {"forge": 0, "garbage": 0}
        self._pool: list[bytes] = []

    def stop(self, *_: Any) -> None:
        self._stop = True

    def _due(self, kind: str, rate: float, now: float) -> int:
        """How many datagrams of ``kind`` are due by ``now`` (all earlier ones included)."""
        if rate <= 0 or now < self._start:
            return self._done[kind]
        k = math.floor((min(now, self._end) - self._start) * rate) + 1
        while k > 0 and self._start + (k - 1) / rate >= self._end:
            k -= 1
        return min(k, self._total[kind])

    def _in_blackout(self, k: int, rate: float) -> bool:
        t = self.imp.inject_start_s + k / rate
        return any(a <= t < a + d for a, d in self.imp.blackouts)

    def _send(self, data: bytes, kind: str) -> None:
        try:
            self.sock.sendto(data, self.target)
        except OSError:
            self.counters["send_errors"] += 1
            return
        self.counters[kind] += 1
        self.counters["emitted"] += 1
        now = time.monotonic()
        if self.t_first is None:
            self.t_first = now
        self.t_last = now

    def _round(self, now: float) -> None:
        imp = self.imp
        due = self._due("forge", imp.forge_rate_hz, now)
        while self._done["forge"] < due:
            k = self._done["forge"]
            self._done["forge"] += 1
            if self._in_blackout(k, imp.forge_rate_hz):
                self.counters["skipped_blackout"] += 1
                continue
            valid = self.rng.random() < imp.forge_valid_fraction
            if valid and imp.forge_kind in ("ground_truth", "stop"):  # from the injector's own socket
                self._send(forge_targeted(self.rng, imp.forge_kind), "forged_foreign")
            elif valid:
                self._send(forge_valid(self.rng), "forged_valid")
            else:
                self._send(forge_invalid(self.rng), "forged_invalid")
        due = self._due("garbage", imp.garbage_rate_hz, now)
        while self._done["garbage"] < due:
            if not self._pool:
                self._pool = garbage_batch(self.garbage_rng, BLOCK, imp.garbage_max_bytes)[::-1]
            data = self._pool.pop()
            k = self._done["garbage"]
            self._done["garbage"] += 1
            if self.imp.blackouts and self._in_blackout(k, imp.garbage_rate_hz):
                self.counters["skipped_blackout"] += 1
                continue
            self._send(data, "garbage")

    def finished(self) -> bool:
        return all(self._done[k] >= self._total[k] for k in self._done)

    def run(self, duration_s: float | None = None) -> dict[str, Any]:
        """Send the schedule (or until :meth:`stop` or ``duration_s`` after t0); returns the counters."""
        if self.imp.garbage_rate_hz > 0:  # drawn before the first one is due
            self._pool = garbage_batch(self.garbage_rng, BLOCK, self.imp.garbage_max_bytes)[::-1]
        deadline = math.inf if duration_s is None else self.t0 + duration_s
        try:
            while not self._stop and not self.finished():
                now = time.monotonic()
                if now >= deadline:
                    break
                self._round(now)
                wait = TICK_S if now >= self._start else min(self._start - now, 0.25)
                time.sleep(max(wait, TICK_S))
        finally:
            self.sock.close()
        return self.stats()

    def stats(self) -> dict[str, Any]:
        return {**self.counters, "t_first": self.t_first, "t_last": self.t_last, "t0": self.t0,
                "seed": self.seed}


def _address(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    try:
        value = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected HOST:PORT") from None
    if not host or not 0 < value < 65536:
        raise argparse.ArgumentTypeError(f"{text!r}: expected HOST:PORT")
    return host, value


def main(argv: list[str] | None = None) -> int:
    from tools.faults.config import load_profile
    from tools.faults.errors import FaultConfigError

    ap = argparse.ArgumentParser(prog="python -m tools.faults.inject", description=__doc__.splitlines()[0])
    ap.add_argument("--target", type=_address, required=True, help="HOST:PORT the injections go to")
    ap.add_argument("--profile", required=True, help="TOML profile (Impairments fields)")
    ap.add_argument("--table", default=None, help="table of the profile file to use")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--t0", type=float, default=None,
                    help="time.monotonic() the injection window counts from (default: now)")
    ap.add_argument("--duration", type=float, default=None, help="stop this long after t0 at the latest [s]")
    args = ap.parse_args(argv)
    try:
        imp = load_profile(args.profile, args.table)
    except FaultConfigError as exc:
        print(f"inject: {exc}", file=sys.stderr)
        return 2
    inj = Injector(imp, args.seed, args.target, time.monotonic() if args.t0 is None else args.t0)
    signal.signal(signal.SIGTERM, inj.stop)
    signal.signal(signal.SIGINT, inj.stop)
    print(json.dumps({"event": "injector_ready", "target": f"{args.target[0]}:{args.target[1]}",
                      "seed": args.seed, "t0": inj.t0, "now": time.monotonic()}), file=sys.stderr, flush=True)
    stats = inj.run(args.duration)
    print(json.dumps({"event": "injector_exit", **stats}), file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
