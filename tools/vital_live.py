"""Live intervention times of the vital supervision: a real ``sfa listen`` process, a fake sensor set and a
fake OBCU on 127.0.0.1, and sensors falling silent on purpose.

A seeded synthetic run (``sfa.synthetic``, a slow train on the synthetic track) is encoded as the four
interface modules send it (one socket each: IMU, odometer, GNSS, control with STROBE and GROUND TRUTH)
and sent in real time. In scheduled windows one module (``imu``, ``odometer``, ``gnss``) or every sensor
(``all``) is silent, then resumes. For each window this records, on the wall clock of this one host:

- ``last``: when the last datagram of the silenced module(s) left the sender,
- ``event``: the ``ts`` of the listener's own ``status`` log line that reports the change (DEGRADED
  naming the module's time-out reason; for ``all`` the LOST line, ``no_motion_sensor``),
- ``obcu``: when the fake OBCU received the first extended output carrying that status.

The listener runs with the extended output (the 18-byte one has no status: docs/protocol.md) and
``vital.decay_on_lost = false`` so that each ``all`` window can be measured (a latched decay state would
already say LOST). ``python -m tools.vital_live --runs 20 --out vital.json`` prints the table of
docs/reliability.md ("Intervention-time budget"); tests/test_listener_vital_live.py runs a few windows.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

KINDS = ("imu", "odometer", "gnss", "all")
_TYPES = {"imu": (1,), "odometer": (2,), "gnss": (3,), "all": (1, 2, 3)}
#: status code the OBCU must see and the reason the listener must name, per kind
_EXPECT = {
    "imu": (2, "imu_timeout"),
    "odometer": (2, "odometer_timeout"),
    "gnss": (2, "gnss_timeout"),
    "all": (3, "no_motion_sensor"),
}
#: silent window and the settling time after it [s]
_WINDOW = {"imu": (1.0, 2.0), "odometer": (1.5, 2.5), "gnss": (4.5, 3.0), "all": (1.5, 4.0)}
WARM_UP_S = 10.0  #: sensor time before the first window (initialisation, filter NOMINAL)


@dataclass
class Window:
    kind: str
    start: float  #: run-relative [s]
    end: float
    last: float | None = None  #: wall time the last datagram of the silenced module(s) was sent
    event: float | None = None  #: wall time of the listener's status line
    event_record: dict[str, Any] = field(default_factory=dict)
    obcu: float | None = None  #: wall time the OBCU received the status
    status_before: str | None = None  #: the listener's status when the window began (from its log)

    def row(self, timeouts: dict[str, float]) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "timeout_s": timeouts[self.kind],
            "event_s": None if self.event is None or self.last is None else self.event - self.last,
            "obcu_s": None if self.obcu is None or self.last is None else self.obcu - self.last,
            "status_before": self.status_before,
            "event": self.event_record.get("event"),
            "reasons": self.event_record.get("reasons"),
            "source": self.event_record.get("source"),
            "since_heard_s": self.event_record.get("since_heard_s"),
        }


def schedule(kinds: list[str], runs: int) -> list[Window]:
    """Windows cycling through ``kinds``, ``runs`` of each, after the warm-up."""
    out, t = [], WARM_UP_S
    for _ in range(runs):
        for k in kinds:
            silent, settle = _WINDOW[k]
            out.append(Window(k, t, t + silent))
            t += silent + settle
    return out


def build_stream(work: Path, duration_s: float, seed: int = 11):
    """(track path, datagrams [(t_rel, module, bytes)]) of a slow seeded synthetic run."""
    from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
    from listener.codec import GpsFix, GroundTruth, ImuSample, OdometerSample, Strobe, encode_input
    from sfa.measurements import GpsMeas, ImuMeas, InitMeas, OdoMeas
    from sfa.synthetic import Profile, build_track_db, generate
    from track_db import TrackDatabase

    track_path = work / "synthetic.db"
    if not track_path.exists():
        build_track_db(track_path)
    with TrackDatabase.open(track_path) as track:
        run = generate(
            track, 1, duration_s, IMU_PRESETS["mems-train"], ODOMETER_PRESETS["wheel-odometer"],
            GPS_PRESETS["standalone"], seed=seed, profile=Profile(segments=((4.0, 0.5), (1e6, 0.0))),
        )
    seqs = {"imu": 0, "odo": 0, "gps": 0, "ctl": 0}
    t0 = run.measurements[0].t_s
    out: list[tuple[float, str, bytes]] = []

    def emit(mod: str, msg, t: float) -> None:
        out.append((t - t0, mod, encode_input(msg)))

    def seq(mod: str) -> int:
        q = seqs[mod]
        seqs[mod] = (q + 1) & 0xFFFF
        return q

    next_strobe = math.floor(t0)
    for m in run.measurements:
        while next_strobe <= m.t_s:
            emit("ctl", Strobe(seq("ctl"), float(next_strobe)), next_strobe)
            next_strobe += 1.0
        if isinstance(m, InitMeas):
            gt = GroundTruth(seq("ctl"), m.speed_mps, 0.0, 0.0, m.arc_length_m, m.line_id, m.t_s)
            emit("ctl", gt, m.t_s)
        elif isinstance(m, ImuMeas):
            emit("imu", ImuSample(seq("imu"), *m.f_mps2, *m.w_radps, m.t_s), m.t_s)
        elif isinstance(m, OdoMeas):
            emit("odo", OdometerSample(seq("odo"), m.speed_mps, m.sigma_mps, m.t_s), m.t_s)
        elif isinstance(m, GpsMeas):
            fix = GpsFix(seq("gps"), m.lat_deg, m.lon_deg, m.alt_m, 1, 12, m.sigma_h_m or 1.5, m.t_s)
            emit("gps", fix, m.t_s)
    out.sort(key=lambda r: r[0])
    return track_path, out


_MOD_TYPE = {"imu": 1, "odo": 2, "gps": 3, "ctl": 8}


class FakeObcu(threading.Thread):
    """Receives the listener's outputs on 127.0.0.1, acks each, records (wall time, status)."""

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.received: list[tuple[float, int]] = []  # (wall, status; -1 for the 18-byte form)
        self._halt = threading.Event()

    def run(self) -> None:
        from listener.codec import DecodeError, decode_output_any, encode_ack

        while not self._halt.is_set():
            try:
                data, addr = self.sock.recvfrom(2048)
            except (TimeoutError, BlockingIOError):
                continue
            except OSError:
                return
            wall = time.time()
            try:
                msg = decode_output_any(data)
            except DecodeError:
                continue
            self.received.append((wall, getattr(msg, "status", -1)))
            try:
                self.sock.sendto(encode_ack(msg.seq), addr)
            except OSError:
                pass

    def stop(self) -> None:
        self._halt.set()
        self.join(timeout=2)
        self.sock.close()


class LogTail(threading.Thread):
    """Reads the listener's JSON log lines from its stderr pipe as they come."""

    def __init__(self, stream, sink: Path) -> None:
        super().__init__(daemon=True)
        self.stream = stream
        self.sink = sink
        self.records: list[dict[str, Any]] = []

    def run(self) -> None:
        with open(self.sink, "w") as fh:
            for line in iter(self.stream.readline, ""):
                fh.write(line)
                fh.flush()
                text = line.strip()
                if text.startswith("<") and ">" in text[:4]:
                    text = text[text.index(">") + 1 :]
                if text.startswith("{"):
                    try:
                        self.records.append(json.loads(text))
                    except ValueError:
                        pass

    def wait_for(self, event: str, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if any(r.get("event") == event for r in list(self.records)):
                return True
            time.sleep(0.05)
        return False


def send(port: int, dgrams, windows: list[Window], end_s: float) -> None:
    """Paced real-time sender, one socket per module; silent in the windows; records ``Window.last``."""
    socks = {}
    for mod in _MOD_TYPE:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        socks[mod] = s
    start = time.monotonic()
    wi = 0
    try:
        for t, mod, data in dgrams:
            if t > end_s:
                break
            while wi < len(windows) and t >= windows[wi].end:
                wi += 1
            w = windows[wi] if wi < len(windows) else None
            if w is not None and w.start <= t < w.end and _MOD_TYPE[mod] in _TYPES[w.kind]:
                continue
            delay = t - (time.monotonic() - start)
            if delay > 0:
                time.sleep(delay)
            socks[mod].sendto(data, ("127.0.0.1", port))
            if w is not None and t < w.start and _MOD_TYPE[mod] in _TYPES[w.kind]:
                w.last = time.time()  # the newest datagram of the module(s) before the window
    finally:
        for s in socks.values():
            s.close()


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_live(kinds: list[str], runs: int, work: Path, extra_set: tuple[str, ...] = ()) -> dict[str, Any]:
    """Start ``sfa listen``, send the schedule, return the rows and the summary (times in seconds)."""
    work.mkdir(parents=True, exist_ok=True)
    windows = schedule(kinds, runs)
    end_s = windows[-1].end + _WINDOW[windows[-1].kind][1]
    track_path, dgrams = build_stream(work, end_s + 1.0)
    obcu = FakeObcu()
    obcu.start()
    lport = _free_port()
    argv = [
        sys.executable, "-m", "sfa", "listen", "--track", str(track_path), "--bind", "127.0.0.1",
        "--port", str(lport), "--obcu", f"127.0.0.1:{obcu.port}",
        "--set", "link.extended=true", "--set", "vital.decay_on_lost=false",
        "--set", "log.metrics_interval_s=5",
    ]
    for item in extra_set:
        argv += ["--set", item]
    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    tail = LogTail(proc.stderr, work / "listener.log")
    tail.start()
    try:
        if not tail.wait_for("ready", 180.0):
            raise RuntimeError(f"listener not ready: see {work / 'listener.log'}")
        send(lport, dgrams, windows, end_s)
        time.sleep(0.5)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:  # pragma: no cover
            proc.kill()
            proc.wait(timeout=5)
        tail.join(timeout=5)
        obcu.stop()
    return evaluate(windows, tail.records, obcu.received)


def evaluate(windows: list[Window], records: list[dict], received: list[tuple[float, int]]) -> dict[str, Any]:
    from listener.config import FilterSelection

    fc = FilterSelection().filter_config()  # the listener's default filter
    timeouts = {"imu": fc.imu_timeout_s, "odometer": fc.odo_timeout_s, "gnss": fc.gps_timeout_s,
                "all": max(fc.imu_timeout_s, fc.odo_timeout_s)}
    # the change is a status line, or a reasons line when the status was already that bad
    status_lines = [r for r in records if r.get("event") in ("status", "reasons")]
    rx_t = np.array([t for t, _ in received]) if received else np.zeros(0)
    rx_s = np.array([s for _, s in received]) if received else np.zeros(0, dtype=int)
    for w in windows:
        if w.last is None:
            continue
        code, reason = _EXPECT[w.kind]
        name = {2: "degraded", 3: "lost"}[code]
        before = [r for r in status_lines if r["ts"] <= w.last]
        w.status_before = before[-1]["status"] if before else None
        for r in status_lines:
            if r["ts"] > w.last and r["status"] == name and reason in r.get("reasons", []):
                w.event, w.event_record = r["ts"], r
                break
        # the OBCU's change: the first STATUS of that code after the last NOMINAL one it got since then
        after = (rx_t > w.last)
        hit = np.flatnonzero(after & (rx_s == code))
        if hit.size and w.status_before == "nominal":
            w.obcu = float(rx_t[hit[0]])
    rows = [w.row(timeouts) for w in windows if w.last is not None]
    return {"rows": rows, "summary": summarise(rows), "timeouts_s": timeouts}


def summarise(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per kind: p50/p99/max of the windows that began NOMINAL (a window that began DEGRADED for another
    reason has no status change to see: counted in ``not_nominal_at_onset``)."""
    out = {}
    for kind in KINDS:
        every = [r for r in rows if r["kind"] == kind]
        if not every:
            continue
        mine = [r for r in every if r["status_before"] == "nominal"]
        entry: dict[str, Any] = {"runs": len(mine), "timeout_s": every[0]["timeout_s"],
                                 "not_nominal_at_onset": len(every) - len(mine)}
        for key in ("event_s", "obcu_s"):
            vals = np.array([r[key] for r in mine if r[key] is not None], dtype=float)
            entry[f"{key}_missing"] = len(mine) - vals.size
            if vals.size:
                entry[f"{key}_p50"] = float(np.percentile(vals, 50))
                entry[f"{key}_p99"] = float(np.percentile(vals, 99))
                entry[f"{key}_max"] = float(vals.max())
        out[kind] = entry
    return out


def table(summary: dict[str, dict[str, Any]]) -> str:
    lines = [
        "| silent | time-out | target | last datagram -> status line p50 / p99 / max | "
        "-> OBCU sees it p50 / p99 / max | runs | not NOMINAL at onset |",
        "|---|---|---|---|---|---|---|",
    ]
    for kind, e in summary.items():
        target = 0.6 if kind == "imu" else e["timeout_s"] + 0.1

        def fmt(key: str, e=e) -> str:
            if f"{key}_p50" not in e:
                return "missing"
            miss = f" ({e[f'{key}_missing']} missing)" if e[f"{key}_missing"] else ""
            return f"{e[f'{key}_p50']:.3f} / {e[f'{key}_p99']:.3f} / {e[f'{key}_max']:.3f} s{miss}"

        lines.append(
            f"| {kind} | {e['timeout_s']:.1f} s | {target:.1f} s | {fmt('event_s')} | {fmt('obcu_s')} "
            f"| {e['runs']} | {e['not_nominal_at_onset']} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tools.vital_live", description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20, help="windows per kind (default 20)")
    ap.add_argument("--kinds", default=",".join(KINDS), help="comma-separated: imu,odometer,gnss,all")
    ap.add_argument("--work", default="vital-live", help="directory for the track, log and results")
    ap.add_argument("--out", help="JSON file for the rows and the summary")
    args = ap.parse_args(argv)
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    bad = [k for k in kinds if k not in KINDS]
    if bad or args.runs < 1:
        print(f"vital_live: bad --kinds {bad} or --runs {args.runs}", file=sys.stderr)
        return 2
    res = run_live(kinds, args.runs, Path(args.work))
    if args.out:
        Path(args.out).write_text(json.dumps(res, indent=1))
    print(table(res["summary"]))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
