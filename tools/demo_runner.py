"""Process orchestration of ``sfa demo`` (see :mod:`tools.demo`)."""

from __future__ import annotations

import csv
import json
import os
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tools.accuracy import accuracy
from tools.errors import ToolError
from tools.processes import terminate

READY_TIMEOUT_S = 180.0  #: longest wait for the listener's READY (numba compiles on a cold cache)


@dataclass(frozen=True)
class DemoOptions:
    scenario: str = "tram-urban"  #: shipped scenario name
    duration_s: float = 240.0  #: simulated seconds [s]
    speed: float = 4.0  #: simulated seconds per wall second
    seed: int | None = None  #: sensor error seed (None: the scenario's)
    out_dir: str = "demo-out"  #: report directory
    live_display: bool = True  #: show live progress


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _LineReader(threading.Thread):
    """Collects a child's stderr lines (JSON where possible) without blocking the demo."""

    def __init__(self, stream, sink_path: Path) -> None:
        super().__init__(daemon=True)
        self._stream = stream
        self._sink = open(sink_path, "w")  # noqa: SIM115 - closed in run()
        self.events: list[dict] = []
        self.ready = threading.Event()
        self.last_metrics: dict | None = None
        self.link_state = "idle"

    def run(self) -> None:
        try:
            for line in self._stream:
                self._sink.write(line)
                text = line.strip()
                if not text.startswith("{"):
                    continue
                try:
                    ev = json.loads(text)
                except json.JSONDecodeError:
                    continue
                kind = ev.get("event")
                if kind in ("ready", "obcu_ready"):
                    self.ready.set()
                elif kind in ("metrics", "exit"):
                    self.last_metrics = ev
                    self.link_state = ev.get("link", {}).get("state", self.link_state)
                elif kind == "link_state":
                    self.link_state = ev.get("state", self.link_state)
                if kind in ("exit", "obcu_exit", "ready", "warm_up"):
                    self.events.append(ev)
        finally:
            self._sink.close()


def _sfa(*args: str) -> list[str]:
    return [sys.executable, "-m", "sfa", *args]


def _read_obcu_csv(path: Path) -> dict[str, np.ndarray]:
    names = ("epoch", "arc_length", "speed", "lo", "hi", "seq", "status", "line_id")
    cols: dict[str, list[float]] = {k: [] for k in names}
    if not path.exists():
        return {k: np.array(v) for k, v in cols.items()}
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            try:
                cols["epoch"].append(float(row["epoch"]))
                cols["arc_length"].append(float(row["arc_length"]))
                cols["seq"].append(float(row["seq"]))
                cols["speed"].append(float(row["speed"]) if row.get("speed") else np.nan)
                cols["lo"].append(float(row["interval_low"]) if row.get("interval_low") else np.nan)
                cols["hi"].append(float(row["interval_high"]) if row.get("interval_high") else np.nan)
                cols["status"].append(float(row["status"]) if row.get("status") else np.nan)
                cols["line_id"].append(float(row["line_id"]) if row.get("line_id") else -1.0)
            except (KeyError, ValueError):
                continue  # a partially written last line while the OBCU is running
    return {k: np.array(v) for k, v in cols.items()}


def run_demo(opts: DemoOptions) -> int:
    from interface_modules.offline import generate
    from interface_modules.scenario import load_scenario

    if opts.speed <= 0 or opts.duration_s <= 0:
        raise ToolError("--speed and --duration must be > 0")
    out = Path(opts.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sc = load_scenario(opts.scenario)
    print(f"sfa demo: scenario {sc.name!r}: {sc.description}", flush=True)
    print(
        f"  truth: generating {opts.duration_s:.0f} s of simulated run (seed "
        f"{sc.seed if opts.seed is None else opts.seed}) ...",
        flush=True,
    )
    sim = generate(sc, seed=opts.seed, max_duration_s=opts.duration_s)
    truth_t = np.asarray(sim.truth["epoch"], dtype=float)
    truth_s = np.asarray(sim.truth["arc_length"], dtype=float)

    listen_port = _free_udp_port()
    obcu_port = _free_udp_port()
    obcu_csv = out / "obcu.csv"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    procs: list[subprocess.Popen] = []
    try:
        obcu = subprocess.Popen(
            _sfa("obcu", "--port", str(obcu_port), "--csv", str(obcu_csv), "--quiet", "--idle-exit", "5"),
            stderr=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            text=True,
            env=env,
        )
        procs.append(obcu)
        obcu_log = _LineReader(obcu.stderr, out / "obcu.log")
        obcu_log.start()
        listener = subprocess.Popen(
            _sfa(
                "listen",
                "--bind",
                "127.0.0.1",
                "--port",
                str(listen_port),
                "--obcu",
                f"127.0.0.1:{obcu_port}",
                "--set",
                "log.metrics_interval_s=1",
                "--set",
                "link.extended=true",
                "--set",
                f'filter.imu="{sc.imu.preset}"',
                "--set",
                f'filter.odometer="{sc.odometer.preset}"',
                "--set",
                f'filter.gps="{sc.gps.preset}"',
                "--set",
                f"clock.rate={opts.speed}",  # the simulated sensor clock runs --speed times faster
            ),
            stderr=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            text=True,
            env=env,
        )
        procs.append(listener)
        lst_log = _LineReader(listener.stderr, out / "listener.log")
        lst_log.start()
        print(
            f"  listener on 127.0.0.1:{listen_port}, mock OBCU on 127.0.0.1:{obcu_port}; "
            "waiting for READY (first run compiles the filter) ...",
            flush=True,
        )
        t_wait = time.monotonic()
        while not lst_log.ready.wait(0.2):
            if listener.poll() is not None:
                raise ToolError(
                    f"the listener exited with status {listener.returncode} before READY "
                    f"(see {out / 'listener.log'})"
                )
            if time.monotonic() - t_wait > READY_TIMEOUT_S:
                raise ToolError(f"the listener was not ready after {READY_TIMEOUT_S:.0f} s")
        seed_args = [] if opts.seed is None else ["--seed", str(opts.seed)]
        simp = subprocess.Popen(
            _sfa(
                "sim",
                sc.source or opts.scenario,
                "--live",
                "--target",
                f"127.0.0.1:{listen_port}",
                "--speed",
                str(opts.speed),
                "--duration",
                str(opts.duration_s),
                *seed_args,
            ),
            stdout=subprocess.DEVNULL,
            stderr=open(out / "sim.log", "w"),
            env=env,  # noqa: SIM115
        )
        procs.append(simp)
        wall_budget = opts.duration_s / opts.speed + 60.0
        t0 = time.monotonic()
        last_print = 0.0
        shown = 0
        while True:
            time.sleep(0.25)
            done = listener.poll() is not None
            if time.monotonic() - t0 > wall_budget:
                raise ToolError(f"the run did not finish within {wall_budget:.0f} s of wall time")
            now = time.monotonic()
            if opts.live_display and (now - last_print >= 1.0 or done):
                last_print = now
                est = _read_obcu_csv(obcu_csv)
                if est["epoch"].size and est["epoch"].size != shown:
                    shown = est["epoch"].size
                    e_t, e_s = est["epoch"][-1], est["arc_length"][-1]
                    err = float(e_s - np.interp(e_t, truth_t, truth_s))
                    v = est["speed"][-1]
                    print(
                        f"  t={e_t - truth_t[0]:7.1f} s  s={e_s:9.1f} m  v={v * 3.6:5.1f} km/h  "
                        f"error={err:+6.2f} m  outputs={est['epoch'].size:6d}  link={lst_log.link_state}",
                        flush=True,
                    )
            if done:
                break
        simp.wait(timeout=30.0)
        listener_rc = listener.returncode
        obcu.wait(timeout=30.0)
    finally:
        terminate(procs)
    lst_log.join(timeout=5.0)
    obcu_log.join(timeout=5.0)

    est = _read_obcu_csv(obcu_csv)
    if est["epoch"].size == 0:
        raise ToolError(f"the OBCU received no output (see {out}/listener.log and {out}/sim.log)")
    acc = accuracy(est["epoch"], est["arc_length"], truth_t, truth_s, est["lo"], est["hi"])
    metrics = lst_log.last_metrics or {}
    summary = {
        "scenario": sc.name,
        "seed": sim.seed,
        "simulated_s": float(truth_t[-1] - truth_t[0]),
        "distance_m": float(truth_s[-1] - truth_s[0]),
        "outputs_received_by_obcu": int(est["epoch"].size),
        "listener_exit_status": listener_rc,
        "accuracy": acc.as_dict(),
        "listener_metrics": metrics,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    print("  report: replaying the same datagrams offline for the innovations and reasons ...", flush=True)
    report = _write_report(out, sc, sim, est, acc, metrics, obcu_log.events)
    print()
    print(
        f"sfa demo: {sc.name}, {summary['simulated_s']:.0f} s simulated, "
        f"{summary['distance_m']:.0f} m travelled, {acc.n} estimates received by the OBCU"
    )
    cov = "n/a" if acc.coverage is None else f"{100 * acc.coverage:.1f} %"
    print(
        f"  along-track error: rms {acc.rms_m:.2f} m, p95 {acc.p95_m:.2f} m, max {acc.max_m:.2f} m; "
        f"95 % interval contains truth {cov}"
    )
    link = metrics.get("link", {})
    inp = metrics.get("input", {})
    print(
        f"  listener: {inp.get('received', '?')} datagrams received, {inp.get('rejected', 0)} rejected, "
        f"{link.get('outputs', '?')} outputs, {link.get('acks', '?')} acks, link {link.get('state', '?')}, "
        f"exit status {listener_rc}"
    )
    print(f"  report: {report}")
    return 0 if listener_rc == 0 else 1


def _live_estimates(est: dict[str, np.ndarray], track) -> dict[str, np.ndarray]:
    """The OBCU's received estimates as report columns; lat/lon from the track (not on the wire)."""
    n = est["epoch"].size
    status = np.nan_to_num(est["status"], nan=0.0).astype(np.int64)
    line_id = est["line_id"].astype(np.int64)
    lat, lon = np.full(n, np.nan), np.full(n, np.nan)
    for lid in np.unique(line_id[line_id >= 0]):
        sel = line_id == lid
        la, lo = track.line(int(lid)).latlon_at(est["arc_length"][sel])
        lat[sel], lon[sel] = la, lo
    return {
        "epoch": est["epoch"], "arc_length": est["arc_length"], "speed": est["speed"],
        "sigma": np.full(n, np.nan), "interval_low": est["lo"], "interval_high": est["hi"],
        "status": status, "line_id": line_id, "lat": lat, "lon": lon,
    }  # fmt: skip


def _gnss_fixes(sim) -> dict[str, np.ndarray]:
    from listener.codec import DecodeError, GpsFix, decode_input

    rows = []
    for p in sim.packets:
        if p.module != "gps":
            continue
        try:
            m = decode_input(p.payload)
        except DecodeError:
            continue
        if isinstance(m, GpsFix):
            q = -1 if m.fix_quality is None else m.fix_quality
            rows.append((p.arrival_s if m.epoch is None else m.epoch, m.lat, m.lon, q))
    arr = np.array(rows, dtype=float).reshape(-1, 4)
    return {"t": arr[:, 0], "lat": arr[:, 1], "lon": arr[:, 2], "fix_quality": arr[:, 3].astype(np.int64)}


def _write_report(out: Path, sc, sim, est, acc, metrics, obcu_events) -> Path:
    """report.html (tools.report, the replay's report) plus a short report.md pointing to it."""
    from interface_modules.capture import write_events_csv, write_pcap, write_truth_csv
    from listener.config import load_config
    from tools.replay import ReplayOptions, replay_capture
    from tools.replay_metrics import replay_metrics
    from tools.report import ReportData, fault_windows, nees_verdict, write_report
    from track_db import TrackDatabase, default_database_path

    write_pcap(sim, out / "capture.pcap")  # what the modules sent, as a capture: sfa replay takes it
    write_truth_csv(sim, out / "truth.csv")
    write_events_csv(sim, out / "events.csv")
    track = TrackDatabase.open(str(default_database_path()))
    cfg = load_config(None, [f'filter.imu="{sc.imu.preset}"', f'filter.odometer="{sc.odometer.preset}"',
                             f'filter.gps="{sc.gps.preset}"'])  # fmt: skip
    truth = {k: np.asarray(sim.truth[k], dtype=float) for k in ("epoch", "arc_length", "speed", "lat", "lon")}
    options = ReplayOptions(port=sc.network.listener_port, config=cfg)
    rep = replay_capture(out / "capture.pcap", track, options)
    rep_metrics = replay_metrics(rep, truth)
    live = _live_estimates(est, track)
    reasons = None
    rep_new, rep_reasons = rep.new_estimates(), rep.new_reasons()
    if rep_reasons is not None and rep_new["epoch"].size:  # the replay's reasons at each live estimate
        k = np.clip(np.searchsorted(rep_new["epoch"], live["epoch"], side="right") - 1, 0, None)
        reasons = rep_reasons[k]
    m: dict = {
        "rms_m": acc.rms_m, "p50_m": acc.p50_m, "p95_m": acc.p95_m, "max_m": acc.max_m,
        "interval_coverage": acc.coverage, "messages": len(sim.packets), "new_estimates": acc.n,
        "pipeline": metrics,
    }  # fmt: skip
    for key in ("nees_mean", "nees_band_95", "nees_samples"):  # sigma is not on the wire: the replay's
        if key in rep_metrics:
            m[key] = rep_metrics[key]
            m["nees_source"] = "offline replay of the same datagrams: sigma is not on the wire"
    link = dict(metrics.get("link", {}))
    link["outputs received by the OBCU"] = int(est["epoch"].size)
    link["distinct SEQs received"] = int(np.unique(est["seq"]).size)
    link["OBCU exit"] = next((e for e in obcu_events if e.get("event") == "obcu_exit"), None)
    end = float(live["epoch"][-1])
    data = ReportData(
        title=f"sfa demo: {sc.name}",
        kind="demo",
        estimates=live,
        reasons=reasons,
        reasons_note="offline replay of the same datagrams (reasons are not on the wire)",
        truth=truth,
        fixes=_gnss_fixes(sim),
        updates=rep.updates,
        updates_note="offline replay of the same datagrams",
        outages=[tuple(o) for o in rep_metrics.get("gnss_outages", [])],
        faults=[w for w in fault_windows(sim.events, end, float(truth["epoch"][0])) if w[0] <= end],
        metrics=m,
        link=link,
        track=track,
        files=["capture.pcap", "truth.csv", "events.csv", "obcu.csv", "summary.json", "listener.log"],
    )
    html_path = write_report(data, out)
    verdict, _ = nees_verdict(m)
    cov = "n/a" if acc.coverage is None else f"{100 * acc.coverage:.1f} %"
    (out / "report.md").write_text(
        f"# sfa demo: {sc.name}\n\nThe full report is [report.html](report.html) (figures embedded).\n\n"
        f"| figure | value |\n|---|---|\n"
        f"| estimates received by the OBCU | {acc.n} |\n"
        f"| rms along-track error | {acc.rms_m:.3f} m |\n"
        f"| p95 along-track error | {acc.p95_m:.3f} m |\n"
        f"| max along-track error | {acc.max_m:.3f} m |\n"
        f"| 95 % interval coverage | {cov} |\n"
        f"| NEES (offline replay of the same datagrams) | {verdict} |\n"
    )
    return html_path
