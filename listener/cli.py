"""``sfa listen``: the listener daemon (thin CLI over :mod:`listener.service`)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--track", help="SQLite track database (default: the bundled Jena tram network)")
    parser.add_argument("--port", type=int, help="UDP port for INPUT_PROTOCOL (default 48000)")
    parser.add_argument("--bind", help="address to bind the input socket to (default 0.0.0.0)")
    parser.add_argument("--obcu", metavar="HOST:PORT", help="where outputs go (default 127.0.0.1:48001)")
    parser.add_argument(
        "--config", help="TOML configuration file (example: listener/config/listener.example.toml)"
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one configuration key, e.g. --set link.max_rate_hz=50 (repeatable)",
    )
    parser.add_argument("--no-warm-up", action="store_true", help="skip compiling the filter before READY")


def _overrides(args: argparse.Namespace) -> list[str]:
    from listener.errors import ConfigError

    out = list(args.set)
    if args.track is not None:
        out.append(f'track="{args.track}"')
    if args.port is not None:
        out.append(f"input.port={args.port}")
    if args.bind is not None:
        out.append(f'input.bind="{args.bind}"')
    if args.obcu is not None:
        host, sep, port = args.obcu.rpartition(":")
        if not sep or not host or not port.isdigit():
            raise ConfigError(f"--obcu {args.obcu!r}: expected HOST:PORT")
        out.append(f'link.obcu_host="{host.strip("[]")}"')
        out.append(f"link.obcu_port={port}")
    return out


def run(args: argparse.Namespace) -> int:
    from listener.errors import ConfigError
    from sfa import engine

    # before the kernels are imported: no numba, no compile (sfa.engine)
    if not engine.prefer_compiled() and engine.required():
        raise ConfigError(f"{engine.ENV_MODE}=compiled but no compiled engine is usable: {engine.active()}")
    from listener.config import load_config
    from listener.jsonlog import JsonLogger
    from listener.pipeline import Pipeline
    from listener.service import ListenerService, run_service

    cfg = load_config(args.config, _overrides(args))
    from track_db import TrackDatabase, default_database_path

    track_path = cfg.track or str(default_database_path())
    try:
        track = TrackDatabase.open(track_path)
    except FileNotFoundError as exc:
        raise ConfigError(f"track {track_path}: no such file") from exc
    log = JsonLogger(
        level=cfg.log.level,
        warning_interval_s=cfg.log.warning_interval_s,
        priority_prefix=cfg.log.priority_prefix,
    )
    try:
        import time

        pipeline = Pipeline(track, cfg, start_epoch=int(time.time()) & 0xFFFFFFFF)
    except Exception as exc:
        from sfa.errors import SfaError

        if isinstance(exc, SfaError | KeyError):
            raise ConfigError(f"filter: {exc}") from exc
        raise
    service = ListenerService(pipeline, cfg, logger=log)
    rc = run_service(service, warm_up=not args.no_warm_up)
    # the interpreter's last garbage collection of the compiled filter's objects took 0.7 s at exit;
    # frozen, they are left to the OS and the process ends about 0.1 s after its exit event (a STOP
    # exits within 1 s: issue 20)
    import gc

    gc.freeze()
    return rc
