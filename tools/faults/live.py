"""Live mode of a campaign: real processes on loopback (as ``sfa demo`` runs them, plus fault proxies).

    sfa sim --live --speed X -> [sfa faults proxy: input link] -> sfa listen -> [sfa faults proxy:
    output link] -> sfa obcu                       (acks come back through the output-link proxy)

Order: the listener first (its READY can take a while: the filter compiles), then the OBCU, the
proxies and the simulator, so the OBCU's misbehaviour windows and the proxies' blackout windows (both
measured from their start / first datagram, in wall seconds) line up with the start of the run.
Every process writes JSON lines on stderr; they are kept in ``out/<scenario>/*.log``. The listener's
resident memory is sampled from ``/proc`` while the run lasts.

Injections (forged datagrams, a garbage flood) do not come from the input proxy live: generating
50,000 datagrams/s in the process that forwards the real stream delays the real stream there, and the
latency figure would then measure the proxy. The proxy gets the forwarding impairments only (table
``input_proxy`` of ``links.toml``; forgeries posing as a real sender stay with it, they must leave from
that sender's upstream socket), and once the proxy logs its start a separate injector process
(``tools.faults.inject``, table ``input_injector``) sends the rest straight to the listener on the
proxy's schedule. Its counters are added to the proxy's.

Lag and age: each fresh output's lag is its arrival minus its epoch (scaled by the speed), up to an
unknown constant; ``age`` is the lag above the smallest lag of the outputs after the first epoch (the
outputs of the first epoch are the initialisation's, sent before the stream is paced: at speed 1 they
lead the steady stream by 57 to 85 ms, which taken as the reference added that much to every age).
``lag.csv`` keeps per fresh output its scheduled time (arrival - age, wall seconds from the
simulator's start), its arrival and its age. A row with injections also gets the p99 age of the outputs
scheduled inside the injector's actual window and inside the equally long stretch just before it.

Times in live mode are wall seconds: run blackout scenarios at ``speed = 1`` so that the link
timeouts (wall clock) and the windows mean the same as on the replay path.
"""

from __future__ import annotations

import functools
import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from tools.faults.config import Impairments
from tools.faults.errors import CampaignError
from tools.faults.evaluate import Observation
from tools.faults.spec import ScenarioSpec
from tools.faults.tomlwrite import dumps
from tools.processes import terminate

READY_TIMEOUT_S = 300.0  #: longest wait for the listener's READY (numba compiles on a cold cache) [s]


def free_udp_port(host: str = "127.0.0.1") -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


class LogReader(threading.Thread):
    """Copies a child's stderr to a file and keeps its JSON events (with the monotonic time read)."""

    def __init__(self, stream, sink: Path) -> None:
        super().__init__(daemon=True)
        self._stream = stream
        self._sink = sink
        self.events: list[tuple[float, dict]] = []
        self.ready = threading.Event()
        self.traceback = False

    def run(self) -> None:
        with open(self._sink, "w") as fh:
            for line in self._stream:
                fh.write(line)
                fh.flush()
                if line.startswith("Traceback"):
                    self.traceback = True
                text = line.strip()
                if not text.startswith("{"):
                    continue
                try:
                    ev = json.loads(text)
                except json.JSONDecodeError:
                    continue
                if not isinstance(ev, dict):
                    continue
                self.events.append((time.monotonic(), ev))
                if ev.get("event") in ("ready", "obcu_ready", "proxy_ready"):
                    self.ready.set()

    def last(self, kind: str) -> dict | None:
        for _, ev in reversed(self.events):
            if ev.get("event") == kind:
                return ev
        return None


def _sfa(*args: str) -> list[str]:
    return [sys.executable, "-m", "sfa", *args]


def rss_mb(pid: int) -> float | None:
    """Resident set size of a process [MB] (None where /proc is not readable)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def _windows_args(flag: str, windows) -> list[str]:
    out: list[str] = []
    for a, d in windows:
        out += [flag, f"{a}:{d}"]
    return out


def read_obcu_csv(path: Path) -> dict[str, np.ndarray]:
    import csv

    cols: dict[str, list[float]] = {k: [] for k in ("time_s", "seq", "epoch", "arc_length", "lo", "hi")}
    if path.exists():
        with open(path, newline="") as fh:
            for row in csv.DictReader(fh):
                try:
                    vals = (float(row["time_s"]), float(row["seq"]), float(row["epoch"]),
                            float(row["arc_length"]),
                            float(row["interval_low"]) if row.get("interval_low") else math.nan,
                            float(row["interval_high"]) if row.get("interval_high") else math.nan)
                except (KeyError, ValueError, TypeError):
                    continue  # a partly written last line
                for key, v in zip(cols, vals, strict=True):
                    cols[key].append(v)
    return {k: np.array(v, dtype=float) for k, v in cols.items()}


def fresh_mask(seq: np.ndarray) -> np.ndarray:
    """Which received outputs carry a SEQ newer (serial order) than every one before."""
    from listener.serial import serial_gt

    mask = np.zeros(seq.size, dtype=bool)
    newest = None
    for i, s in enumerate(seq.astype(int)):
        if newest is None or serial_gt(int(s), newest):
            newest = int(s)
            mask[i] = True
    return mask


#: the listener's priority in deploy/systemd/sfa-listener.service (``Nice=-5``): live rows run it as deployed,
#: while the simulator, the proxies and the OBCU mock keep the default 0 (the injector: INJECTOR_NICE)
LISTENER_NICE = -5


def _renice(increment: int) -> None:
    """preexec_fn body: add ``increment`` to the child's niceness where allowed (a negative one needs root
    or CAP_SYS_NICE), else leave it unchanged."""
    try:
        os.nice(increment)
    except OSError:
        pass


#: preexec_fn of the listener's process: the deployed niceness
_deployed_priority = functools.partial(_renice, LISTENER_NICE)


#: the flood injector's niceness: on the target the attacker's datagrams are generated on other machines;
#: here the injector shares the 2 cores with the system under test and with the processes in the measured
#: path (simulator, input proxy, OBCU mock), which it must not starve. Its achieved rate is in the notes.
INJECTOR_NICE = 10
#: the injector may take at most this times its window to send what the window schedules; slower, and the
#: latency_delta_ms check fails (the flood was thinner than configured)
FLOOD_SCHEDULE_SLACK = 1.05


def injection_window_s(imp: Impairments | None) -> float:
    """Length of the injection window the injector schedules its datagrams in (inf: no end) [s]."""
    return imp.inject_end_s - imp.inject_start_s if imp is not None else math.inf


def behind_schedule(sent_over_s: float, window_s: float) -> bool:
    """True when the injector needed more than FLOOD_SCHEDULE_SLACK x its window to send what the window
    schedules (a starved injector: the flood was thinner than configured)."""
    return math.isfinite(window_s) and sent_over_s > FLOOD_SCHEDULE_SLACK * window_s


#: preexec_fn of the injector's process: lower priority (any user may lower its own)
_attacker_priority = functools.partial(_renice, INJECTOR_NICE)


def _niceness(pid: int) -> int | None:
    """Niceness of process ``pid`` (None when it cannot be read)."""
    try:
        return os.getpriority(os.PRIO_PROCESS, pid)
    except OSError:
        return None


def split_injections(imp: Impairments) -> tuple[Impairments, Impairments | None]:
    """(what the input proxy does, what the injector process sends; None: nothing to inject).

    Garbage and forgeries from their own source go to the injector; forgeries posing as a real sender
    (``forge_on_stream``) stay in the proxy, which alone holds that sender's upstream socket, and so do
    shifted STROBEs (``strobe_shift``: dated on the stream's clock, which the proxy sees)."""
    import dataclasses

    # a forged STROBE is dated on the stream's clock, which only the proxy sees
    on_stream = (imp.forge_on_stream or imp.forge_kind == "strobe_shift") and imp.forge_rate_hz > 0
    proxy = dataclasses.replace(imp, garbage_rate_hz=0.0,
                                forge_rate_hz=imp.forge_rate_hz if on_stream else 0.0)
    forge = 0.0 if on_stream else imp.forge_rate_hz
    if forge <= 0 and imp.garbage_rate_hz <= 0:
        return proxy, None
    injector = Impairments(
        forge_rate_hz=forge, forge_count=imp.forge_count, forge_valid_fraction=imp.forge_valid_fraction,
        forge_kind=imp.forge_kind,
        garbage_rate_hz=imp.garbage_rate_hz, garbage_max_bytes=imp.garbage_max_bytes,
        inject_start_s=imp.inject_start_s, inject_end_s=imp.inject_end_s, blackouts=imp.blackouts,
    ).validate()
    return proxy, injector


def lag_ages(arrival: np.ndarray, epoch: np.ndarray, speed: float) -> np.ndarray:
    """Age of each fresh output [wall s]: its lag above the smallest lag after the first epoch.

    ``lag = arrival - (epoch - epoch[0]) / speed`` (unknown constant included). The outputs of the first
    epoch are the initialisation's, sent before the stream is paced: not a reference for the rest
    (if there are no others, they are their own reference)."""
    if arrival.size == 0:
        return np.array([])
    lag = arrival - (epoch - epoch[0]) / speed
    steady = epoch != epoch[0]
    best = lag[steady].min() if steady.any() else lag.min()
    return lag - best


def window_p99_ms(sched: np.ndarray, age: np.ndarray, lo: float, hi: float) -> tuple[float | None, int]:
    """p99 age [ms] of the outputs scheduled in [lo, hi) and how many there are."""
    sel = (sched >= lo) & (sched < hi) & np.isfinite(age)
    n = int(sel.sum())
    return (float(np.percentile(age[sel], 99) * 1000.0) if n else None), n


def run_live(spec: ScenarioSpec, out: Path) -> Observation:
    """Run ``spec`` with real processes on loopback and return what was observed."""
    from interface_modules.offline import generate
    from interface_modules.tracks import database_path
    from tools.faults.netns import Namespace
    from tools.faults.runner import build_scenario, fault_windows, listener_config

    sc = build_scenario(spec)
    track_path = database_path(sc)
    if track_path is None:
        raise CampaignError(f"{spec.name}: synthetic tracks have no database the listener can open")
    sim = generate(sc)  # the truth the live senders follow (same scenario, same seed)
    scenario_file = out / "scenario.toml"
    scenario_file.write_text(dumps(spec.scenario_dict()))
    links = {}
    inject_imp = None
    if spec.input_link is not None:
        links["input_link"] = spec.input_link.as_dict()  # the row's profile (the replay path's)
        proxy_imp, inject_imp = split_injections(spec.input_link)
        links["input_proxy"] = proxy_imp.as_dict()
        if inject_imp is not None:
            links["input_injector"] = inject_imp.as_dict()
    if spec.output_link is not None:
        links["output_link"] = spec.output_link.as_dict()
    (out / "links.toml").write_text(dumps(links))
    _, overrides = listener_config(spec, sc, track_path)
    auth_args: list[str] = []  # sfa obcu and sfa sim: the same master key file as the listener
    if spec.auth:  # authenticated links on both sides of the listener, per-module input keys
        from tools.faults.runner import campaign_master_key

        key_file = out / "master.key"
        key_file.write_text(campaign_master_key(spec).hex() + "\n")
        overrides = [*overrides, "auth.enabled=true", f"auth.key_file={key_file}"]
        auth_args = ["--auth-key-file", str(key_file)]

    notes: list[str] = []
    wall_s = spec.duration_s / spec.speed
    for which, imp in (("input_link", spec.input_link), ("output_link", spec.output_link)):
        injects = imp is not None and (imp.forge_rate_hz > 0 or imp.garbage_rate_hz > 0)
        late = [a for a, _ in (imp.blackouts if imp is not None else ()) if a >= wall_s]
        if injects and imp.inject_start_s >= wall_s:
            late.append(imp.inject_start_s)
        if late:  # live windows are wall seconds: a row run faster than real time may never reach them
            notes.append(f"{which}: a window starts at {min(late):g} s of wall time, after the live run's "
                         f"end ({wall_s:g} s at speed {spec.speed:g}): not exercised live (set speed = 1)")
    ns = Namespace.create(spec) if spec.netns else None
    host = "127.0.0.1"
    listen_host = ns.inner_addr if ns else host
    obcu_host = ns.outer_addr if ns else host
    listen_port = free_udp_port()
    obcu_port = free_udp_port(obcu_host)
    in_proxy_port = free_udp_port()
    out_proxy_port = free_udp_port(obcu_host) if spec.output_link is not None else None
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    procs: list[subprocess.Popen] = []
    readers: dict[str, LogReader] = {}
    rss: list[tuple[float, float]] = []

    def start(name: str, argv: list[str], preexec_fn=None) -> subprocess.Popen:
        p = subprocess.Popen(argv, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=env,
                             preexec_fn=preexec_fn)  # noqa: PLW1509 - os.nice wrappers only
        procs.append(p)
        reader = LogReader(p.stderr, out / f"{name}.log")
        reader.start()
        readers[name] = reader
        return p

    def wait_ready(name: str, p: subprocess.Popen, timeout_s: float) -> None:
        t = time.monotonic()
        while not readers[name].ready.wait(0.1):
            if p.poll() is not None:
                raise CampaignError(f"{spec.name}: {name} exited with status {p.returncode} before READY "
                                    f"(see {out / (name + '.log')})")
            if time.monotonic() - t > timeout_s:
                raise CampaignError(f"{spec.name}: {name} not ready after {timeout_s:.0f} s")

    try:
        obcu_target = f"{obcu_host}:{out_proxy_port or obcu_port}"
        listen_argv = _sfa("listen", "--bind", listen_host, "--port", str(listen_port), "--obcu", obcu_target,
                           "--set", "log.metrics_interval_s=1", "--set", f"clock.rate={spec.speed}",
                           *[a for o in overrides for a in ("--set", o)])
        if spec.restart is not None:  # the restarted process resumes from the first one's checkpoints
            if ns is not None:
                raise CampaignError(f"{spec.name}: restart rows do not run in a network namespace")
            ck_file = out / "listener-checkpoint.json"
            ck_file.unlink(missing_ok=True)
            listen_argv += ["--set", f'checkpoint.path="{ck_file}"']
        listener = start("listener", ns.wrap(listen_argv) if ns else listen_argv,
                         preexec_fn=_deployed_priority)
        wait_ready("listener", listener, READY_TIMEOUT_S)
        listener_pid = ns.child_pid(listener.pid) if ns else listener.pid
        nice = _niceness(listener_pid)
        if nice != LISTENER_NICE:
            notes.append(f"listener at nice {nice}, not the deployed {LISTENER_NICE} "
                         "(needs root or CAP_SYS_NICE)")
        obcu = start("obcu", _sfa("obcu", "--bind", obcu_host, "--port", str(obcu_port), "--csv",
                                  str(out / "obcu.csv"), "--quiet", "--idle-exit", "10",
                                  *_windows_args("--drop-acks", spec.obcu.drop_acks),
                                  *_windows_args("--silent", spec.obcu.silent),
                                  *[a for t in spec.obcu.restart_at_s for a in ("--restart-at", str(t))],
                                  *auth_args))
        wait_ready("obcu", obcu, 60.0)
        t_obcu = time.monotonic()  # the OBCU's clock (CSV time_s, misbehaviour windows) starts about here
        target = f"{listen_host}:{listen_port}"
        if spec.input_link is not None and ns is None:  # in a namespace, netem impairs the input link
            p = start("proxy_in", _sfa("faults", "proxy", "--listen", f"{host}:{in_proxy_port}", "--forward",
                                       target, "--profile", str(out / "links.toml"), "--table", "input_proxy",
                                       "--seed", str(spec.seed), "--idle-exit", "15", *auth_args))
            wait_ready("proxy_in", p, 60.0)
            target = f"{host}:{in_proxy_port}"
        if spec.output_link is not None:
            p = start("proxy_out", _sfa("faults", "proxy", "--listen", f"{obcu_host}:{out_proxy_port}",
                                        "--forward", f"{obcu_host}:{obcu_port}", "--profile",
                                        str(out / "links.toml"), "--table", "output_link",
                                        "--seed", str(spec.seed + 1), "--idle-exit", "15"))
            wait_ready("proxy_out", p, 60.0)
        base_rss = rss_mb(listener_pid)
        t_start = time.monotonic()
        simp = subprocess.Popen(
            _sfa("sim", str(scenario_file), "--live", "--target", target, "--speed", str(spec.speed),
                 "--ephemeral-ports", *auth_args),
            stdout=subprocess.DEVNULL, stderr=open(out / "sim.log", "w"), env=env,  # noqa: SIM115
        )
        procs.append(simp)
        budget = spec.duration_s / spec.speed + 90.0
        injector = None
        if inject_imp is not None and "proxy_in" not in readers:
            notes.append("injections not run: they go with the input proxy, which netns mode replaces")
            inject_imp = None
        kill_at = None if spec.restart is None else spec.restart.kill_at_s(spec.seed)
        t_kill = t_restart = None
        while listener.poll() is None or (t_kill is not None and t_restart is None):
            time.sleep(0.25 if kill_at is None else 0.02)
            if kill_at is not None and t_kill is None and time.monotonic() - t_start >= kill_at:
                os.kill(listener.pid, signal.SIGKILL)  # kill -9: no last checkpoint, nothing flushed
                t_kill = time.monotonic()
                listener.wait(timeout=10.0)
            if t_kill is not None and t_restart is None and time.monotonic() - t_kill >= spec.restart.down_s:
                t_restart = time.monotonic()  # the same command line, configuration and checkpoint file
                listener = start("listener2", listen_argv, preexec_fn=_deployed_priority)
                listener_pid = listener.pid
            if inject_imp is not None and injector is None:  # the proxy's clock started: inject on it
                t0 = [ev.get("t_monotonic") for _, ev in readers["proxy_in"].events
                      if ev.get("event") == "proxy_started"]
                if t0 and isinstance(t0[0], int | float):
                    injector = start("injector", [sys.executable, "-m", "tools.faults.inject", "--target",
                                                  f"{listen_host}:{listen_port}", "--profile",
                                                  str(out / "links.toml"), "--table", "input_injector",
                                                  "--seed", str(spec.seed), "--t0", repr(float(t0[0])),
                                                  "--duration", str(wall_s + 5.0)],
                                     preexec_fn=_attacker_priority)
            value = rss_mb(listener_pid)
            if value is not None:
                rss.append((time.monotonic() - t_start, value))
            if time.monotonic() - t_start > budget:
                notes.append(f"listener still running {budget:.0f} s after the start: terminated")
                listener.terminate()
                break
        listener.wait(timeout=30.0)
        simp.wait(timeout=30.0)
        time.sleep(1.0)  # the last outputs and acks
        if ns is not None and ns.netem:
            (out / "netem.txt").write_text(" ".join(ns.netem) + "\n" + ns.qdisc_stats())
            notes.append(f"input link by netem: {' '.join(ns.netem)} (counters in netem.txt)")
    finally:
        terminate(procs)
        for r in readers.values():
            r.join(timeout=5.0)
        if ns:
            ns.destroy()
    crashes = 0
    for name, reader in readers.items():
        if reader.traceback:
            crashes += 1
            notes.append(f"{name}: traceback (see {name}.log)")
    last_name = "listener2" if "listener2" in readers else "listener"
    if listener.returncode not in (0, None) and not readers[last_name].traceback:
        crashes += 1
        notes.append(f"listener exit status {listener.returncode}")
    lst = readers[last_name]  # after a restart: the restarted process's figures
    exit_ev = lst.last("exit") or lst.last("metrics") or {}
    metrics = {k: v for k, v in exit_ev.items() if k in ("input", "sequencing", "clock", "merge", "filter",
                                                          "link", "service", "senders", "resilience")}
    seen: dict[str, int] = {}
    for name in ("listener", "listener2"):  # the warning lines each process logged
        for _, ev in readers[name].events if name in readers else ():
            if ev.get("level") == "warning":
                seen[ev.get("event", "")] = seen.get(ev.get("event", ""), 0) + 1
    metrics["warnings_seen"] = dict(sorted(seen.items()))
    status_reasons: set[str] = set()
    for name in ("listener", "listener2"):
        for _, ev in readers[name].events if name in readers else ():
            if ev.get("event") == "status" and ev.get("status") != "nominal":
                status_reasons.update(ev.get("reasons") or ())
    transitions = [(t - t_start, ev.get("state", "")) for t, ev in lst.events
                   if ev.get("event") == "link_state" and t >= t_start]
    reasons: set[str] = set()
    for _, ev in lst.events:
        if ev.get("event") == "metrics":
            reasons.update(ev.get("filter", {}).get("reasons", []) or [])
    est = read_obcu_csv(out / "obcu.csv")
    mask = fresh_mask(est["seq"])
    t_arr, epoch = est["time_s"][mask], est["epoch"][mask]
    # one time axis, seconds from the simulator's start: the OBCU's clock started obcu_offset earlier;
    # the output proxy's windows count from its first datagram (the first output), the input proxy's
    # from the first sensor datagram (the simulator's start)
    obcu_offset = t_start - t_obcu
    arrival = t_arr - obcu_offset
    first_out = float(arrival[0]) if arrival.size else 0.0
    started = [t for t, ev in readers["proxy_out"].events if ev.get("event") == "proxy_started"] \
        if "proxy_out" in readers else []
    if started:  # the output proxy said when its clock started: exact, not the first arrival at the OBCU
        first_out = started[0] - t_start
    outages = tuple((a + first_out, d) for a, d in (spec.output_link.blackouts if spec.output_link else ()))
    outages += tuple((a - obcu_offset, d) for a, d in spec.obcu.silent + spec.obcu.drop_acks)
    started_in = [t for t, ev in readers["proxy_in"].events if ev.get("event") == "proxy_started"] \
        if "proxy_in" in readers else []
    first_in = started_in[0] - t_start if started_in else 0.0
    in_blackouts = tuple((a + first_in, d) for a, d in (spec.input_link.blackouts if spec.input_link else ()))
    age = lag_ages(t_arr, epoch, spec.speed)  # wall seconds
    sched = arrival - age  # when each output's epoch was due, on the arrival axis (s from the sim start)
    np.savetxt(out / "lag.csv", np.column_stack([sched, arrival, age * 1000.0]).reshape(-1, 3), delimiter=",",
               header="sched_s,arrival_s,age_ms", comments="", fmt="%.6f")
    proxies = {}
    for name in ("proxy_in", "proxy_out"):
        ev = readers[name].last("proxy_exit") if name in readers else None
        proxies[name] = {k: v for k, v in (ev or {}).items() if k != "event" and isinstance(v, int)}
        if name in readers and ev is None:
            notes.append(f"{name}: no exit counters")
    injected: dict = {}
    latency_window = None
    if "injector" in readers:
        ev = readers["injector"].last("injector_exit")
        if ev is None:
            notes.append("injector: no exit counters")
        else:
            injected = {k: v for k, v in ev.items() if k != "event"}
            for key in ("forged_valid", "forged_invalid", "forged_foreign", "garbage", "emitted"):
                proxies["proxy_in"][key] = proxies["proxy_in"].get(key, 0) + int(ev.get(key, 0))
            if ev.get("send_errors"):
                notes.append(f"injector: {ev['send_errors']} datagrams refused by sendto (not counted sent)")
            if isinstance(ev.get("t_first"), float) and isinstance(ev.get("t_last"), float):
                lo, hi = ev["t_first"] - t_start, ev["t_last"] - t_start
                planned = injection_window_s(inject_imp)
                behind = behind_schedule(hi - lo, planned)
                if hi > lo:
                    notes.append(f"injector (nice +{INJECTOR_NICE}): {int(ev.get('emitted', 0)):,} datagrams "
                                 f"in {hi - lo:.2f} s ({int(ev.get('emitted', 0)) / (hi - lo):,.0f}/s)")
                during, n_d = window_p99_ms(sched, age, lo, hi)
                before, n_b = window_p99_ms(sched, age, lo - (hi - lo), lo)
                latency_window = {"window_s": [lo, hi], "during_p99_ms": during, "during_n": n_d,
                                  "before_p99_ms": before, "before_n": n_b}
                if behind:
                    # a starved injector sends a thinner flood: the latency under it does not count
                    latency_window["behind_schedule"] = True
                    notes.append(f"injector fell behind its schedule ({hi - lo:.2f} s for a {planned:.2f} s "
                                 "window): latency_delta_ms not measured under the full rate")
                if during is not None and before is not None:
                    notes.append(f"lag p99 of the outputs due during the injection ({lo:.1f}-{hi:.1f} s) "
                                 f"{during:.1f} ms, in the {hi - lo:.1f} s before it {before:.1f} ms "
                                 f"({during - before:+.1f} ms)")
    elif inject_imp is not None:
        notes.append("injector: not started (the input proxy never logged its start)")
    restart: dict = {}
    if t_kill is not None:
        restart = {"kill_s": t_kill - t_start, "restart_s": (t_restart - t_start) if t_restart else None}
        all_arrival = est["time_s"] - obcu_offset
        seqs = est["seq"].astype(int)
        before = seqs[all_arrival < restart["restart_s"]] if t_restart else seqs
        if before.size:
            restart["last_seq_before"] = int(before[fresh_mask(before)][-1])
        after = seqs[all_arrival >= restart["restart_s"]] if t_restart else seqs[:0]
        if after.size:
            restart["first_seq_after"] = int(after[0])
        ready2 = [t for t, ev in readers["listener2"].events if ev.get("event") == "ready"] \
            if "listener2" in readers else []
        if ready2:
            notes.append(f"restarted listener READY {ready2[0] - t_restart:.2f} s after its start")
    stop_exit_s = None
    seen_stop = [ev.get("t_monotonic") for _, ev in readers["proxy_in"].events
                 if ev.get("event") == "proxy_stop_seen"] if "proxy_in" in readers else []
    exits = [t for t, ev in lst.events if ev.get("event") == "exit"]
    if seen_stop and exits and isinstance(seen_stop[-1], int | float):
        stop_exit_s = exits[-1] - float(seen_stop[-1])  # the STOP passing the proxy -> the exit line read
    growth = None
    if base_rss is not None and rss:
        growth = max(v for _, v in rss) - base_rss
    obs = Observation(
        name=spec.name, mode="live" + ("+netns" if ns else ""), simulated_s=float(sim.duration_s),
        truth_epoch=np.asarray(sim.truth["epoch"], float),
        truth_arc=np.asarray(sim.truth["arc_length"], float),
        start_epoch_s=sc.start_epoch_s,
        fresh_arrival=arrival, fresh_epoch=epoch,
        fresh_arc=est["arc_length"][mask], fresh_lo=est["lo"][mask], fresh_hi=est["hi"][mask],
        fresh_age=age, fresh_reasons=None, metrics=metrics, link_transitions=transitions,
        input_proxy=proxies["proxy_in"], output_proxy=proxies["proxy_out"],
        input_blackouts=in_blackouts,
        output_blackouts=outages,
        sensor_fault_windows=fault_windows(sc, sim), crashes=crashes,
        memory_growth_mb=growth, latency_p99_ms=float(np.percentile(age, 99) * 1000.0) if age.size else None,
        latency_delta_ms=(latency_window["during_p99_ms"] - latency_window["before_p99_ms"])
        if latency_window and latency_window["before_p99_ms"] is not None
        and not latency_window.get("behind_schedule")
        and latency_window["during_p99_ms"] is not None else None,
        reasons_seen=reasons, notes=notes,
        corruption=bool(spec.input_link and (spec.input_link.bitflip > 0 or spec.input_link.forge_on_stream)),
        restart=restart, stop_exit_s=stop_exit_s, status_reasons=status_reasons,
        run_s=float(sim.duration_s) / spec.speed,  # arrivals are wall seconds
    )
    if spec.auth:
        # live, the accepted datagrams cannot be matched one by one against the originals (the replay
        # path does that); the bound: no more accepted than the simulator sent through the proxy
        auth = exit_ev.get("auth") or {}
        originals = proxies["proxy_in"].get("received", 0) if "proxy_in" in readers else None
        accepted = int(auth.get("input_accepted", 0))
        obs.auth = {"accepted": accepted, "rejected": dict(auth.get("input_rejected", {})),
                    "bad": max(0, accepted - originals) if originals is not None else 0}
        notes.append("live auth_bad: accepted datagrams beyond the originals the simulator sent (a replay "
                     "accepted in place of a lost original is not visible live; the replay path checks each)")
    (out / "live.json").write_text(json.dumps({"metrics": metrics, "proxies": proxies, "injector": injected,
                                               "latency_window": latency_window, "rss_mb": rss[-50:],
                                               "base_rss_mb": base_rss}, indent=1, default=str))
    return obs

