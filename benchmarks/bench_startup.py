"""Start-up and footprint of ``sfa listen``: cold and warm first output, peak resident memory.

Runs a real ``sfa listen`` process on 127.0.0.1 fed by a real simulated stream (a shipped scenario's
datagrams, one UDP socket per interface module, paced at the nominal rates) and an OBCU stand-in
that acks once a second. For each start it records, from the moment of ``spawn``:

- ``bound``: the listener's input port appears in /proc/net/udp (the sender starts then, GROUND
  TRUTH first, as the interface modules of a train would be sending already);
- ``ready``: the listener's ``ready`` log line;
- ``first output``: the first OUTPUT_PROTOCOL datagram at the OBCU stand-in;
- peak RSS: the kernel's high-water mark of the listener's resident set (VmHWM in /proc/PID/status,
  read just before it is stopped, after ``--seconds`` of streaming).

Starts compared side by side in one run, each with a fresh, empty numba cache directory
(``SFA_NUMBA_CACHE_BASE`` and ``NUMBA_CACHE_DIR`` point at a new temporary directory), i.e. a machine
where the project was just installed:

- ``compiled``: the default ``sfa listen``, on the compiled engine built at install (sfa.engine);
- ``jit cold``: ``SFA_ENGINE=jit``, the previous start: numba compiles every kernel before READY;
- ``jit warm``: ``SFA_ENGINE=jit`` again on the cache the cold JIT start filled.

If no compiled engine was built for the current sources (a kernel edited since the install), the
``compiled`` start runs on the JIT too and the engine column says so.

    python benchmarks/bench_startup.py [--scenario tram-urban] [--seconds 8] [--repeat 1]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

SCENARIO = "tram-urban"
TARGET_FIRST_OUTPUT_S = 3.0  #: issue 17: first output within 3 s of spawn on an empty cache
TARGET_PEAK_RSS_MIB = 150e6 / 2**20  #: issue 17: listener peak RSS <= 150 MB (143.1 MiB)


def _udp_bound(port: int) -> bool:
    """Some socket is bound to UDP ``port`` (IPv4 or IPv6), per /proc/net/udp{,6}."""
    hexport = f":{port:04X}"
    for name in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(name) as fh:
                next(fh)
                for line in fh:
                    if line.split()[1].endswith(hexport):
                        return True
        except OSError:
            continue
    return False


def _files_under(path: Path) -> int:
    """Files in the directory tree ``path`` (0 when it does not exist)."""
    return sum(len(files) for _, _, files in os.walk(path))


def start_once(packets, cache_base: Path, tmp: Path, seconds: float, engine: str = "auto",
               timeout_s: float = 180.0, label: str = "run", track: str | None = None,
               sets: tuple[str, ...] = ()) -> dict:
    """Spawn ``sfa listen`` with its numba cache under ``cache_base``, stream ``packets`` at 1x from
    the moment its port is bound, and time its start; returns the figures (seconds since spawn)."""
    from tools.bench_live import obcu_ack_loop
    from tools.processes import free_udp_port, listen_argv, proc_status_kib, terminate

    lport = free_udp_port()
    obcu = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    obcu.bind(("127.0.0.1", 0))
    obcu.settimeout(0.05)
    argv = listen_argv(lport, obcu.getsockname()[1], "log.metrics_interval_s=1000", *sets, track=track)
    env = dict(os.environ)
    env["SFA_ENGINE"] = engine
    env["SFA_NUMBA_CACHE_BASE"] = str(cache_base)
    env["NUMBA_CACHE_DIR"] = str(cache_base)
    result: dict = {"label": label, "cache_files_at_spawn": _files_under(cache_base)}
    log_path = tmp / f"listener-{label}.log"
    first: list[float] = []
    outputs = [0]
    stop = threading.Event()

    def on_output(_data: bytes, now: float) -> None:
        if not first:
            first.append(now)
        outputs[0] += 1

    rx = threading.Thread(target=obcu_ack_loop, args=(obcu, stop, on_output), daemon=True)
    rx.start()
    socks: dict[int, socket.socket] = {}
    with open(log_path, "w") as log_fh:
        spawn = time.monotonic()
        proc = subprocess.Popen(argv, stderr=log_fh, stdout=subprocess.DEVNULL, env=env)
    try:
        deadline = spawn + timeout_s
        while not _udp_bound(lport):
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"listener did not bind: {log_path.read_text()[-500:]}")
            time.sleep(0.005)
        bound = time.monotonic()
        t0 = packets[0].arrival_s
        end = bound + seconds
        stream_end = False
        for p in packets:
            due = bound + (p.arrival_s - t0)
            if due > end:
                break
            if p.payload[0] == 10:  # STOP: the listener would exit; keep it running to its stop
                stream_end = True
                break
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            s = socks.get(p.src_port)
            if s is None:
                s = socks[p.src_port] = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                s.bind(("127.0.0.1", 0))
            s.sendto(p.payload, ("127.0.0.1", lport))
            if proc.poll() is not None:
                break
        while not first and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.01)  # a first output later than --seconds is still timed (the stream ended)
        result["peak_rss_mib"] = (proc_status_kib(proc.pid, "VmHWM") or 0) / 1024.0
        result["rss_end_mib"] = (proc_status_kib(proc.pid, "VmRSS") or 0) / 1024.0
        result["bound_s"] = bound - spawn
        result["first_output_s"] = first[0] - spawn if first else None
        result["stream_ended"] = stream_end
    finally:
        terminate([proc], grace_s=10.0)
        stop.set()
        rx.join(timeout=2.0)
        obcu.close()
        for s in socks.values():
            s.close()
    result["outputs"] = outputs[0]
    result["cache_files_after"] = _files_under(cache_base)
    for line in log_path.read_text().splitlines():
        if line.startswith("{") and '"event":"warm_up"' in line:
            ev = json.loads(line)
            result["warm_up_s"] = ev.get("seconds")
            result["engine"] = ev.get("engine", "jit")
    return result


#: (key, SFA_ENGINE, fresh cache, what it is)
STARTS = (
    ("compiled", "auto", True, "compiled engine (default), empty numba cache"),
    ("jit_cold", "jit", True, "JIT (previous start), empty numba cache"),
    ("jit_warm", "jit", False, "JIT, numba cache filled by the cold start"),
)


def measure(scenario: str, seconds: float, repeats: int, log=print) -> dict[str, list[dict]]:
    """``repeats`` rounds of the three starts; every round has its own fresh cache directories."""
    from interface_modules.offline import generate
    from interface_modules.scenario import load_scenario
    from interface_modules.tracks import database_path

    sc = load_scenario(scenario)
    run = generate(sc, max_duration_s=seconds + 30.0)
    track = str(database_path(sc))  # the scenario's network and presets, as the soak runs it
    sets = (f"filter.odometer={sc.odometer.preset}", f"filter.imu={sc.imu.preset}",
            f"filter.gps={sc.gps.preset}")
    out: dict[str, list[dict]] = {key: [] for key, *_ in STARTS}
    with tempfile.TemporaryDirectory(prefix="sfa-startup-") as tmp_name:
        tmp = Path(tmp_name)
        for k in range(repeats):
            cache = None
            for key, mode, fresh, what in STARTS:
                if fresh:
                    cache = tmp / f"cache-{key}-{k}"
                    cache.mkdir()
                log(f"startup: {what}, run {k + 1}/{repeats}")
                out[key].append(start_once(run.packets, cache, tmp, seconds, engine=mode, label=f"{key}-{k}",
                                           track=track, sets=sets))
    return out


def summary(results: dict[str, list[dict]]) -> dict[str, dict]:
    """Medians per start (``engine``: what the first run of it ran on)."""
    def med(rows, key):
        vals = [r[key] for r in rows if r.get(key) is not None]
        return statistics.median(vals) if vals else None

    out = {}
    for kind, rows in results.items():
        keys = ("bound_s", "first_output_s", "peak_rss_mib", "warm_up_s")
        out[kind] = {key: med(rows, key) for key in keys}
        out[kind]["engine"] = rows[0].get("engine", "?") if rows else "?"
        out[kind]["samples_first_output_s"] = tuple(r.get("first_output_s") for r in rows)
        out[kind]["samples_peak_rss_mib"] = tuple(r.get("peak_rss_mib") for r in rows)
        out[kind]["cache_files_at_spawn"] = max((r["cache_files_at_spawn"] for r in rows), default=None)
        out[kind]["cache_files_after"] = tuple(r.get("cache_files_after") for r in rows)
    return out


def _fmt(v, unit):
    return "-" if v is None else f"{v:.2f} {unit}"


def _ratio(a, b):
    return "-" if a is None or not b else f"{a / b:.2f}x"


def table(s: dict, scenario: str, repeats: int) -> str:
    """The side-by-side table printed by main()."""
    c, jc, jw = s["compiled"], s["jit_cold"], s["jit_warm"]
    lines = [
        f"sfa listen start-up, {scenario} streamed at 1x, median of {repeats} (seconds from spawn)",
        f"{'':22}{'compiled':>14}{'jit cold':>14}{'jit warm':>14}{'jit cold/compiled':>19}"
        f"{'jit warm/compiled':>19}",
    ]
    for key, unit, name in (
        ("bound_s", "s", "input port bound"),
        ("warm_up_s", "s", "warm-up (log)"),
        ("first_output_s", "s", "first output"),
        ("peak_rss_mib", "MiB", "peak RSS (VmHWM)"),
    ):
        lines.append(f"{name:22}{_fmt(c[key], unit):>14}{_fmt(jc[key], unit):>14}{_fmt(jw[key], unit):>14}"
                     f"{_ratio(jc[key], c[key]):>19}{_ratio(jw[key], c[key]):>19}")
    lines.append(f"engine: compiled start ran on {c['engine']}")
    lines.append(
        f"numba cache files at spawn (most of any run): compiled {c['cache_files_at_spawn']}, jit cold "
        f"{jc['cache_files_at_spawn']}, jit warm {jw['cache_files_at_spawn']}; written by the starts: "
        f"compiled {c['cache_files_after']}, jit cold {jc['cache_files_after']}"
    )
    fo, rss = c["first_output_s"], c["peak_rss_mib"]
    lines.append(
        f"target (compiled start): first output <= {TARGET_FIRST_OUTPUT_S:g} s: "
        f"{'met' if fo is not None and fo <= TARGET_FIRST_OUTPUT_S else 'NOT met'}; peak RSS <= 150 MB "
        f"({TARGET_PEAK_RSS_MIB:.1f} MiB): {'met' if rss and rss <= TARGET_PEAK_RSS_MIB else 'NOT met'}"
    )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default=SCENARIO)
    ap.add_argument("--seconds", type=float, default=8.0, help="seconds of streaming per start")
    ap.add_argument("--repeat", type=int, default=1, help="rounds of the three starts; medians are printed")
    ap.add_argument("--json", help="also write every run's figures here")
    args = ap.parse_args(argv)
    results = measure(args.scenario, args.seconds, args.repeat, log=lambda m: print(m, file=sys.stderr))
    print(table(summary(results), args.scenario, args.repeat))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    sys.exit(main())
