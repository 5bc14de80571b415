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

from tools.accuracy import accuracy, along_track_errors
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
    cols: dict[str, list[float]] = {"epoch": [], "arc_length": [], "speed": [], "lo": [], "hi": [], "seq": []}
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
    truth_v = np.asarray(sim.truth["speed"], dtype=float)

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
    err = along_track_errors(est["epoch"], est["arc_length"], truth_t, truth_s)
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
    report = _write_report(out, sc.name, est, err, truth_t, truth_v, acc, metrics)
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


def _write_report(out: Path, name, est, err, truth_t, truth_v, acc, metrics) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = est["epoch"] - truth_t[0]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    ax1.plot(t, err, lw=0.8, label="estimate - truth")
    if np.isfinite(est["lo"]).any():
        truth_s = est["arc_length"] - err
        ax1.fill_between(t, est["lo"] - truth_s, est["hi"] - truth_s, alpha=0.25, label="95 % interval")
    ax1.axhline(0, color="k", lw=0.5)
    ax1.set_ylabel("along-track error [m]")
    ax1.legend(loc="upper right")
    ax1.set_title(f"sfa demo: {name}")
    ax2.plot(truth_t - truth_t[0], truth_v * 3.6, lw=0.8, label="truth")
    if np.isfinite(est["speed"]).any():
        ax2.plot(t, est["speed"] * 3.6, lw=0.8, label="estimate")
    ax2.set_ylabel("speed [km/h]")
    ax2.set_xlabel("time [s]")
    ax2.legend(loc="upper right")
    fig.tight_layout()
    png = out / "demo.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    cov = "n/a" if acc.coverage is None else f"{100 * acc.coverage:.1f} %"
    md = out / "report.md"
    md.write_text(
        f"# sfa demo: {name}\n\n"
        f"| figure | value |\n|---|---|\n"
        f"| estimates received by the OBCU | {acc.n} |\n"
        f"| rms along-track error | {acc.rms_m:.3f} m |\n"
        f"| p95 along-track error | {acc.p95_m:.3f} m |\n"
        f"| max along-track error | {acc.max_m:.3f} m |\n"
        f"| 95 % interval coverage | {cov} |\n\n"
        f"![error and speed](demo.png)\n\n"
        f"Listener metrics at exit:\n\n```json\n{json.dumps(metrics, indent=2, default=str)}\n```\n"
    )
    return md
