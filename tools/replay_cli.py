"""``sfa replay``: offline replay of a capture through the listener's pipeline core."""

from __future__ import annotations

import argparse

from track_db.cli import count_from_1


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("capture", help="pcap or pcapng capture taken on the listener's host")
    parser.add_argument("--track", help="SQLite track database (default: the bundled Jena tram network)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--truth", help="truth CSV (epoch, arc_length, speed) for accuracy figures")
    parser.add_argument(
        "--events",
        help="events CSV of sfa sim (epoch, kind, detail): fault windows shaded in the report "
        "(default: events.csv beside --truth, if there is one)",
    )
    parser.add_argument("--port", type=int, help="listener port to take from the capture (default 48000)")
    parser.add_argument("--config", help="listener TOML configuration (see listener/config/)")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a listener configuration key (repeatable)",
    )
    parser.add_argument("--imu", help="IMU preset of the filter (default mems-train)")
    parser.add_argument("--odometer", help="odometer preset of the filter (default wheel-odometer)")
    parser.add_argument("--gps", help="GNSS preset of the filter (default standalone)")
    parser.add_argument(
        "--sweep",
        action="append",
        default=[],
        metavar="SPEC",
        help="sweep axis: sensor sets 'imu+odo,imu+gps,all' or 'FIELD=v1,v2' (repeatable)",
    )
    parser.add_argument("--sweep-file", help="TOML file of [[config]] tables to sweep")
    parser.add_argument(
        "--jobs", type=count_from_1, default=None, help="parallel replays for sweeps (default: all cores)"
    )
    parser.add_argument("--no-baselines", action="store_true", help="skip the baseline estimators")
    parser.add_argument("--no-report", action="store_true", help="skip figures and report.html")
    path = parser.add_mutually_exclusive_group()
    path.add_argument(
        "--exact",
        action="store_true",
        help="the exact replay: the listener's pipeline datagram by datagram, even where the compiled "
        "path could run (the default is the compiled path, with the same outputs, where the capture allows)",
    )
    path.add_argument(
        "--fast",
        action="store_true",
        help="the compiled path where the capture allows it (the default now; the flag is kept for "
        "compatibility)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    import os
    import sys
    import time
    from pathlib import Path

    from listener.config import load_config
    from tools.errors import ToolError
    from tools.estimates_schema import write_estimates_parquet
    from tools.replay import ReplayOptions, replay_capture
    from tools.replay_metrics import read_truth_csv, replay_metrics
    from tools.replay_report import write_estimates_csv, write_geojson, write_metrics_json
    from track_db import TrackDatabase, default_database_path

    overrides = list(args.set)
    for key, value in (("imu", args.imu), ("odometer", args.odometer), ("gps", args.gps)):
        if value:
            overrides.append(f'filter.{key}="{value}"')
    cfg = load_config(args.config, overrides)
    track_path = args.track or cfg.track or str(default_database_path())
    if not Path(track_path).is_file():
        raise ToolError(f"track {track_path}: no such file")
    track = TrackDatabase.open(track_path)
    truth = read_truth_csv(args.truth) if args.truth else None
    if args.events and not Path(args.events).is_file():
        raise ToolError(f"--events {args.events}: no such file")
    port = args.port if args.port is not None else cfg.input.port
    if not 1 <= port <= 65535:
        raise ToolError(f"--port {port}: must be in 1..65535")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    options = ReplayOptions(port=port, config=cfg)

    t0 = time.perf_counter()
    result = None
    path_used = "exact"
    declined = None
    if not args.exact:  # the compiled path (tools.fast_replay): the same outputs where it runs
        from tools.fast_replay import try_fast_replay
        from tools.memory_policy import keep_freed_memory

        keep_freed_memory()

        result, info = try_fast_replay(args.capture, track, options)
        if result is None:
            declined = info.reason
        else:
            path_used = "fast"
    if result is None:
        result = replay_capture(
            args.capture, track, options, show_progress=not args.quiet and sys.stderr.isatty()
        )
    if declined is not None:  # (said once the exact replay ran: a capture it cannot read fails alone)
        print(f"sfa replay: compiled path not used ({declined}); ran the exact replay", file=sys.stderr)
    wall = time.perf_counter() - t0
    for warning in result.capture.get("warnings", ()):
        print(f"sfa replay: warning: {warning}", file=sys.stderr)
    metrics = replay_metrics(result, truth)
    metrics["replay_wall_s"] = wall
    metrics["replay_path"] = path_used
    metrics["datagrams_per_s"] = result.datagrams / wall if wall > 0 else None

    comparison = None
    baselines: dict = {}
    if not args.no_baselines:
        from tools.baselines import run_baselines

        comparison, baselines = run_baselines(args.capture, track, options, truth, metrics)
        metrics["baselines"] = comparison
    write_estimates_csv(result, out / "estimates.csv")
    if write_estimates_parquet(result, out / "estimates.parquet") is None:
        print("sfa replay: estimates.parquet not written: pyarrow is not installed "
              "(pip install 'sfa-positioning[parquet]')", file=sys.stderr)  # fmt: skip
    write_metrics_json(metrics, out / "metrics.json")
    write_geojson(result, out / "estimates.geojson")
    if not args.no_report:
        from tools.report import read_events_csv, replay_report_data, write_report

        events_path = args.events or (Path(args.truth).with_name("events.csv") if args.truth else None)
        events = read_events_csv(events_path) if events_path and Path(events_path).is_file() else None
        data = replay_report_data(
            result, metrics, truth, track, baselines, comparison, events,
            title=f"sfa replay: {Path(args.capture).name}",
        )  # fmt: skip
        write_report(data, out)

    if args.sweep or args.sweep_file:
        from tools.sweep import configs_from_axes, configs_from_file, parse_axes, run_sweep, write_table

        configs = configs_from_file(args.sweep_file) if args.sweep_file else []
        if args.sweep:
            configs += configs_from_axes(parse_axes(args.sweep))
        jobs = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
        rows = run_sweep(args.capture, track_path, options, configs, truth, jobs)
        csv_path, md_path = write_table(rows, out)
        print(md_path.read_text(), end="")
        print(f"sweep: {len(rows)} configurations -> {csv_path}, {md_path}")

    acc = ""
    if truth is not None and "p95_m" in metrics:
        acc = (
            f", along-track error rms {metrics['rms_m']:.3f} m, p95 {metrics['p95_m']:.3f} m, "
            f"max {metrics['max_m']:.3f} m"
        )
    print(
        f"replay ({path_used}): {result.datagrams} datagrams, {metrics['new_estimates']} estimates "
        f"in {wall:.2f} s "
        f"({metrics['datagrams_per_s']:.0f} datagrams/s){acc} -> {out}"
    )
    return 0
