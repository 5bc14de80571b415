"""``sfa obcu``: the mock on-board control unit (asyncio layer over :mod:`listener.obcu`).

Receives OUTPUT_PROTOCOL datagrams, acks the newest SEQ once a second (configurable) to the sender,
writes every output to a CSV file, shows the live position, and misbehaves on request for tests:
``--drop-acks START:DURATION``, ``--silent START:DURATION``, ``--restart-at T`` (seconds from start).
It exits on SIGTERM/SIGINT, or after ``--duration`` seconds, or ``--idle-exit`` seconds without
outputs once some arrived.
"""

from __future__ import annotations

import argparse


def _window(text: str) -> tuple[float, float]:
    start, sep, dur = text.partition(":")
    try:
        a, b = float(start), float(dur)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected START:DURATION in seconds") from None
    if not sep or a < 0 or b <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected START:DURATION, START >= 0, DURATION > 0")
    return a, b


def _opt(value: object) -> str:
    return "" if value is None else repr(value)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", type=int, default=None, help="UDP port for outputs (default 48001)")
    parser.add_argument("--bind", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    parser.add_argument("--ack-interval", type=float, default=1.0, help="seconds between acks (default 1)")
    parser.add_argument("--csv", help="write every received output to this CSV file")
    parser.add_argument(
        "--drop-acks",
        type=_window,
        action="append",
        default=[],
        metavar="START:DURATION",
        help="receive but do not ack in this window (seconds from start; repeatable)",
    )
    parser.add_argument(
        "--silent",
        type=_window,
        action="append",
        default=[],
        metavar="START:DURATION",
        help="ignore everything in this window (repeatable)",
    )
    parser.add_argument(
        "--restart-at",
        type=float,
        action="append",
        default=[],
        metavar="T",
        help="forget all state at T seconds from start (repeatable)",
    )
    parser.add_argument("--auth-key-file", help="authenticated links (extension): master key file, hex")
    parser.add_argument("--duration", type=float, help="exit after this many seconds")
    parser.add_argument("--idle-exit", type=float, help="exit after this many seconds without outputs")
    parser.add_argument(
        "--receive-buffer",
        type=int,
        default=4 * 1024 * 1024,
        metavar="BYTES",
        help="SO_RCVBUF to ask for (default 4 MiB, as the listener's input): the listener's outputs come in "
        "bursts (a STOP flushes what it held), and a burst larger than the buffer is dropped by the kernel, "
        "counted as kernel_drops in the exit line",
    )
    parser.add_argument("--quiet", action="store_true", help="no live display")


def run(args: argparse.Namespace) -> int:
    import asyncio
    import csv
    import json
    import signal
    import sys

    from listener.config import read_master_key
    from listener.defaults import DEFAULT_OBCU_PORT
    from listener.errors import ConfigError
    from listener.netaddr import kernel_drops, open_udp
    from listener.obcu import MockObcu, ObcuConfig

    port = DEFAULT_OBCU_PORT if args.port is None else args.port
    if not 0 <= port <= 65535:
        raise ConfigError(f"--port {port}: must be in 0..65535")
    if args.ack_interval <= 0:
        raise ConfigError("--ack-interval must be > 0")
    if args.receive_buffer < 4096:
        raise ConfigError(f"--receive-buffer {args.receive_buffer}: must be >= 4096 bytes")
    cfg = ObcuConfig(
        bind=args.bind,
        port=port,
        ack_interval_s=args.ack_interval,
        drop_acks=tuple(args.drop_acks),
        silent=tuple(args.silent),
        restart_at_s=tuple(args.restart_at),
        auth_master_key=None if not args.auth_key_file else read_master_key(args.auth_key_file),
    )

    csv_file = open(args.csv, "w", newline="") if args.csv else None  # noqa: SIM115 - closed below
    writer = csv.writer(csv_file) if csv_file else None
    if writer:
        writer.writerow(
            [
                "time_s",
                "seq",
                "epoch",
                "arc_length",
                "size",
                "speed",
                "interval_low",
                "interval_high",
                "status",
                "line_id",
            ]
        )

    async def main() -> int:
        loop = asyncio.get_running_loop()
        start = loop.time()
        core = MockObcu(cfg, start=start)
        done = asyncio.Event()
        state: dict = {"timer": None, "last_rx": None}

        class Proto(asyncio.DatagramProtocol):
            def connection_made(self, transport):
                self.transport = transport

            def datagram_received(self, data, addr):
                now = loop.time()
                rec = core.receive(data, addr, now)
                if rec is not None:
                    state["last_rx"] = now
                    if writer:
                        writer.writerow(
                            [
                                f"{now - start:.6f}",
                                rec.seq,
                                repr(rec.epoch),
                                repr(rec.arc_length),
                                rec.size,
                                _opt(rec.speed),
                                _opt(rec.interval_low),
                                _opt(rec.interval_high),
                                _opt(rec.status),
                                _opt(rec.line_id),
                            ]
                        )
                rearm()

            def error_received(self, exc):
                pass

        sock, granted = open_udp(cfg.bind, cfg.port, args.receive_buffer, "OBCU socket (--bind, --port)")
        transport, proto = await loop.create_datagram_endpoint(Proto, sock=sock)

        def on_timer():
            state["timer"] = None
            for payload, addr in core.handle_timer(loop.time()):
                try:
                    transport.sendto(payload, addr)
                except OSError:
                    pass
            rearm()

        def rearm():
            when = core.next_timer()
            if state["timer"] is not None:
                state["timer"].cancel()
                state["timer"] = None
            if when is not None:
                state["timer"] = loop.call_at(when, on_timer)

        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, done.set)
        bound = transport.get_extra_info("sockname")
        print(
            json.dumps(
                {"event": "obcu_ready", "bind": bound[0], "port": bound[1], "receive_buffer_bytes": granted}
            ),
            file=sys.stderr,
            flush=True,
        )

        async def supervise():
            while not done.is_set():
                await asyncio.sleep(0.5)
                now = loop.time()
                if args.duration is not None and now - start >= args.duration:
                    done.set()
                if (
                    args.idle_exit is not None
                    and state["last_rx"] is not None
                    and now - state["last_rx"] >= args.idle_exit
                ):
                    done.set()
                if not args.quiet and core.newest is not None:
                    n = core.newest
                    print(
                        f"\robcu: seq {n.seq:5d}  epoch {n.epoch:.2f}  s {n.arc_length:10.2f} m  "
                        f"rx {core.stats.received}  acks {core.stats.acks_sent}",
                        end="",
                        file=sys.stderr,
                        flush=True,
                    )
                if csv_file:
                    csv_file.flush()

        sup = asyncio.ensure_future(supervise())
        await done.wait()
        sup.cancel()
        drops = kernel_drops(sock)
        transport.close()
        st = core.stats
        print(
            ("\n" if not args.quiet else "")
            + json.dumps(
                {
                    "event": "obcu_exit",
                    "received": st.received,
                    "malformed": st.malformed,
                    "duplicates": st.duplicates,
                    "acks_sent": st.acks_sent,
                    "acks_dropped": st.acks_dropped,
                    "ignored_silent": st.ignored_silent,
                    "auth_rejected": st.auth_rejected,
                    "restarts": st.restarts,
                    "kernel_drops": drops,
                    "sizes": {str(k): v for k, v in st.by_size.items()},
                }
            ),
            file=sys.stderr,
            flush=True,
        )
        return 0

    try:
        return asyncio.run(main())
    finally:
        if csv_file:
            csv_file.close()
