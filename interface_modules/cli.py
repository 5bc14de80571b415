"""``sfa sim SCENARIO``: the train and sensor simulator (offline capture or live interface modules).

Offline (default): writes ``capture.pcap``, ``truth.csv`` and ``events.csv`` into ``--out-dir``
(default ``./sim-<scenario name>``), or only the files named by ``--pcap`` / ``--truth``.
Live (``--live --target HOST:PORT``): one process per module sends to the listener in real time
(``--speed`` > 1 for faster than real time); Ctrl-C or the end of the scenario sends STOP.
"""

from __future__ import annotations

import argparse
import socket
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``sfa sim``."""
    parser.add_argument("scenario", nargs="?", help="shipped scenario name or path to a scenario TOML file")
    parser.add_argument("--list", action="store_true", help="list the shipped scenarios and exit")
    parser.add_argument("--pcap", metavar="OUT", help="write the capture (classic pcap) to OUT")
    parser.add_argument("--truth", metavar="OUT", help="write truth.csv to OUT")
    parser.add_argument(
        "--out-dir", metavar="DIR", help="write capture.pcap, truth.csv and events.csv into DIR"
    )
    parser.add_argument("--live", action="store_true", help="send live from one process per module")
    parser.add_argument(
        "--target", metavar="HOST:PORT", help="listener address for --live (default 127.0.0.1:48000)"
    )
    parser.add_argument(
        "--speed", type=float, default=1.0, help="live: simulated seconds per wall second (default 1)"
    )
    parser.add_argument(
        "--seed", type=int, help="seed of the sensor and network errors (default: the scenario's)"
    )
    parser.add_argument(
        "--duration", type=float, metavar="S", help="stop the scenario after S simulated seconds"
    )
    parser.add_argument(
        "--ephemeral-ports",
        action="store_true",
        help="live: bind ephemeral source ports instead of the scenario's",
    )
    parser.add_argument(
        "--auth-key-file",
        metavar="FILE",
        help="live: authenticated input link; FILE is the listener's auth.key_file (hex master key), each "
        "module wraps with its own derived key modules->listener:<KEY_ID> (control 0, imu 1, odometer 2, "
        "gps 3)",
    )
    parser.add_argument(
        "--auth-module-key",
        metavar="NAME=KEY_ID:FILE",
        action="append",
        default=[],
        help="live: module NAME wraps with the key in FILE (hex, `python -m listener.auth_link MASTER "
        "KEY_ID` prints it) and KEY_ID; repeat per module (takes precedence over --auth-key-file)",
    )
    parser.add_argument(
        "--auth-tag-bytes",
        type=int,
        default=16,
        help="live: tag length [bytes] (auth.tag_bytes)",
    )


def _target(text: str | None, default_port: int) -> tuple[str, int]:
    from .errors import SimError

    if not text:
        return ("127.0.0.1", default_port)
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise SimError(f"--target must be HOST:PORT, not {text!r}")
    try:
        value = int(port)
    except ValueError:
        raise SimError(f"--target port must be an integer, not {port!r}") from None
    if not 1 <= value <= 65535:
        raise SimError(f"--target port must be in 1..65535, not {value}")
    host = host.strip("[]")
    try:  # before any module process starts: a bad name is one line, not a traceback per module
        socket.getaddrinfo(host, value, type=socket.SOCK_DGRAM)
    except OSError as exc:
        why = exc.strerror or exc
        raise SimError(f"--target {text!r}: cannot resolve the host {host!r} ({why})") from None
    return (host, value)


def run(args: argparse.Namespace) -> int:
    """Execute ``sfa sim``."""
    import time
    from pathlib import Path

    from .capture import write_events_csv, write_pcap, write_truth_csv
    from .errors import SimError
    from .offline import generate
    from .scenario import load_scenario, scenario_names

    if args.list:
        for name in scenario_names():
            sc = load_scenario(name)
            print(f"{name}: {sc.description}")
        return 0
    if not args.scenario:
        raise SimError("a scenario name or file is required (see --list)")
    if args.duration is not None and args.duration <= 0:
        raise SimError("--duration must be > 0")
    if args.speed <= 0:
        raise SimError("--speed must be > 0")
    if args.live and (args.pcap or args.out_dir):
        raise SimError("--live sends datagrams; use an offline run for --pcap / --out-dir")
    if args.target and not args.live:
        raise SimError("--target is only used with --live")
    authenticated = bool(args.auth_key_file or args.auth_module_key)
    if authenticated and not args.live:
        raise SimError("--auth-key-file / --auth-module-key are only used with --live")
    if not 16 <= args.auth_tag_bytes <= 32:
        raise SimError("--auth-tag-bytes must be in 16..32")
    sc = load_scenario(args.scenario)
    target = _target(args.target, sc.network.listener_port) if args.live else None
    t0 = time.perf_counter()
    run_ = generate(sc, seed=args.seed, max_duration_s=args.duration)
    gen_s = time.perf_counter() - t0
    counts = {m: len(run_.packets_of(m)) for m in run_.ports}
    summary = ", ".join(f"{m} {n}" for m, n in counts.items())
    print(
        f"{sc.name}: {run_.duration_s:.1f} s simulated, {len(run_.packets)} datagrams ({summary}), "
        f"seed {run_.seed}, generated in {gen_s:.2f} s",
        file=sys.stderr,
    )
    if args.live:
        from .live import module_auth, run_live

        auth = None
        if authenticated:  # the epoch starts at the wall-clock second: a re-run never reuses (epoch, SEQ)
            auth = module_auth(
                list(run_.ports),
                master_key_file=args.auth_key_file,
                module_keys=args.auth_module_key,
                start_epoch=int(time.time()),
                tag_bytes=args.auth_tag_bytes,
            )
        if args.truth:
            write_truth_csv(run_, args.truth)
        report = run_live(run_, target, speed=args.speed, ephemeral_ports=args.ephemeral_ports, auth=auth)
        state = "interrupted, STOP sent" if report.interrupted else "complete"
        sent = ", ".join(f"{m} {n}" for m, n in sorted(report.sent.items()))
        print(
            f"live run {state}: sent {sent} to {target[0]}:{target[1]} in {report.wall_s:.1f} s",
            file=sys.stderr,
        )
        return 130 if report.interrupted else 0
    pcap, truth, events = args.pcap, args.truth, None
    if not (pcap or truth) or args.out_dir:
        out = Path(args.out_dir or f"sim-{sc.name}")
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SimError(f"cannot create {str(out)!r}: {exc}") from exc
        pcap = pcap or out / "capture.pcap"
        truth = truth or out / "truth.csv"
        events = out / "events.csv"
    if pcap:
        write_pcap(run_, pcap)
        print(f"capture: {pcap}", file=sys.stderr)
    if truth:
        write_truth_csv(run_, truth)
        print(f"truth: {truth}", file=sys.stderr)
    if events:
        write_events_csv(run_, events)
        print(f"events: {events}", file=sys.stderr)
    print(f"total {time.perf_counter() - t0:.2f} s", file=sys.stderr)
    return 0
