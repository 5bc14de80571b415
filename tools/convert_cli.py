"""``sfa convert``: real sensor logs -> capture.pcap, track.db (+ truth.csv) for ``sfa replay``.

    sfa convert smartloc [SRC_DIR] -o OUT_DIR [--gnss synthetic|spp] [--seed N] [--gps-sigma M] [--evaluate]
    sfa convert dresden [SRC.csv] -o OUT_DIR [--speed-sigma S] [--latency S] [--position-lead S] [--evaluate]
                        [--eval-gps-gap START:END]

SRC defaults to the copies bundled in tools/data/. ``--evaluate`` then runs the capture through the
listener's pipeline core and prints what SFA achieves (and writes evaluation.json). What is real and
what is synthesised: docs/real-data.md.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from sfa.presets import PRESET_FAMILIES

    sub = parser.add_subparsers(dest="source", required=True, metavar="{smartloc,dresden}")
    sl = sub.add_parser(
        "smartloc", help="smartLoc Berlin Potsdamer Platz (odometer + truth; GNSS synthesised)"
    )
    sl.add_argument("src", nargs="?", help="directory with Berlin_Potsdamer_Platz_{GT,Input}.txt "
                                           "(default: the bundled copy)")
    sl.add_argument("--seed", type=int, default=1, help="seed of the synthesised GNSS errors (default 1)")
    sl.add_argument("--gnss", choices=("synthetic", "spp"), default="synthetic",
                    help="GNSS fixes: 'synthetic' (truth + seeded Gauss-Markov/white noise, default) or "
                         "'spp' (real: robust single-point solution from the dataset's pseudoranges)")
    sl.add_argument("--gps-sigma", type=float, metavar="M",
                    help="total synthesised GNSS error per horizontal axis, 1-sigma [m] (default: the "
                         "standalone preset, 1.118 m = 1.0 m Gauss-Markov + 0.5 m white)")
    dr = sub.add_parser("dresden", help="balzer82 Dresden car log (real IMU, GPS, speed; no truth)")
    dr.add_argument("src", nargs="?", help="Dresden CSV log (default: the bundled 2014-03-26-000-Data.csv)")
    dr.add_argument("--speed-sigma", type=float, default=0.3, metavar="MPS",
                    help="1-sigma written into each ODOMETER datagram [m/s] (default 0.3)")
    dr.add_argument("--latency", type=float, metavar="S",
                    help="age of the receiver's speed at its time tag, on the logger clock [s] (default: "
                         "estimated from the data)")
    dr.add_argument("--position-lead", type=float, metavar="S",
                    help="how much earlier than the speed the positions are valid [s] (default: estimated "
                         "from the data)")
    for p in (sl, dr):
        p.add_argument("-o", "--out", required=True, help="output directory")
        p.add_argument("--force", action="store_true", help="replace existing outputs in OUT")
        p.add_argument("--evaluate", action="store_true",
                       help="replay the capture through the listener pipeline and print the figures")
        p.add_argument("--eval-presets", choices=PRESET_FAMILIES, default=None,
                       help="filter preset family for --evaluate (default: the listener's, datasheet)")
        p.add_argument("--eval-set", action="append", default=[], metavar="FIELD=VALUE",
                       help="FilterConfig override for --evaluate, on top of the presets (repeatable)")
        p.add_argument("--eval-without", action="append", default=[], choices=("imu", "odometer", "gps"),
                       help="leave a sensor's datagrams out of --evaluate (repeatable)")
        p.add_argument("--eval-gps-gap", metavar="START:END",
                       help="--evaluate with the GNSS fixes withheld from START to END seconds after the "
                            "first fix (an outage); the figures then include the drift against them")
        p.add_argument("--eval-gap-odometer", action="store_true",
                       help="withhold the odometer in the --eval-gps-gap window too (Dresden: its speed "
                            "comes from the GNSS receiver, so a real outage loses both)")


def run(args: argparse.Namespace) -> int:
    import math
    from pathlib import Path

    from tools.adapters.common import MODULE_PORTS, write_json
    from tools.errors import ToolError

    if args.source == "smartloc":
        from tools.adapters.common import GnssNoise
        from tools.adapters.smartloc import SmartLocConfig, convert_smartloc

        noise = GnssNoise.from_preset("standalone")
        if args.gps_sigma is not None:
            noise = noise.scaled_to(args.gps_sigma)
        cfg = SmartLocConfig(seed=args.seed, gnss=noise, gnss_source=args.gnss)
        conv = convert_smartloc(args.src, args.out, cfg, overwrite=args.force)
    else:
        from tools.adapters.dresden import DresdenConfig, convert_dresden

        cfg = DresdenConfig(speed_sigma_mps=args.speed_sigma, gnss_latency_s=args.latency,
                            position_lead_s=args.position_lead)
        conv = convert_dresden(args.src, args.out, cfg, overwrite=args.force)
    print(f"convert {args.source}: {conv.packets} datagrams "
          f"({', '.join(f'{k} {v}' for k, v in conv.by_module.items())}) -> {conv.out_dir}")
    from tools.adapters.evaluate import listener_config_for, recommended_hold_s

    hold = recommended_hold_s(conv)
    replay = f"sfa replay {conv.capture} --track {conv.track} --out REPLAY_DIR"
    if conv.truth is not None:
        replay += f" --truth {conv.truth}"
    if hold is not None:
        replay += f" --set merge.hold_s={hold}"
    print(f"  replay: {replay}")
    if not args.evaluate:
        return 0

    from listener.config import ListenerConfig
    from sfa.errors import FilterConfigError
    from sfa.presets import config_for
    from tools.adapters.evaluate import (
        read_truth,
        run_pipeline,
        self_consistency,
        truth_figures,
        write_updates_csv,
    )
    from tools.field_values import parse_field_values

    overrides = parse_field_values(args.eval_set, "--eval-set")
    lcfg = listener_config_for(hold, ListenerConfig())
    sel = lcfg.filter
    try:
        fcfg = config_for(args.eval_presets or sel.presets, sel.imu, sel.odometer, sel.gps, **overrides)
    except FilterConfigError as exc:
        raise ToolError(f"--eval-set: {exc}") from None
    excluded = frozenset(MODULE_PORTS[m] for m in args.eval_without)
    reference = read_truth(conv.truth if conv.truth is not None else Path(conv.out_dir) / "gnss_on_track.csv")
    gap = None
    if args.eval_gps_gap:
        start, sep, end = args.eval_gps_gap.partition(":")
        try:
            a, b = float(start), float(end)
        except ValueError:
            a = b = math.nan
        if not sep or not (math.isfinite(a) and math.isfinite(b) and 0.0 <= a < b):
            raise ToolError(f"--eval-gps-gap expects START:END seconds with 0 <= START < END, "
                            f"got {args.eval_gps_gap!r}")
        t0 = float(reference["epoch"][0])
        gap = (t0 + a, t0 + b)
    gap_ports = {MODULE_PORTS["gps"]} | ({MODULE_PORTS["odometer"]} if args.eval_gap_odometer else set())
    result = run_pipeline(conv.capture, conv.track, lcfg, filter_config=fcfg, exclude_ports=excluded,
                          gps_gap=gap, gap_ports=frozenset(gap_ports))
    est = result["estimates"]
    if est["epoch"].size == 0:
        raise ToolError("the pipeline produced no estimate from this capture")
    if conv.truth is not None:
        figures = truth_figures(est, reference)
        print(f"  along-track error vs truth: rms {figures['rms_m']:.3f} m, p95 {figures['p95_m']:.3f} m, "
              f"max {figures['max_m']:.3f} m, interval coverage {figures['coverage']:.3f} "
              f"({figures['n']} estimates)")
        if gap is not None:
            inside = (reference["epoch"] >= gap[0]) & (reference["epoch"] < gap[1])
            if inside.sum() >= 2:
                g = truth_figures(est, {k: v[inside] for k, v in reference.items()})
                figures["gap"] = g
                print(f"  inside the GNSS gap {args.eval_gps_gap} s ({result['gps_withheld']} withheld): "
                      f"rms {g['rms_m']:.3f} m, p95 {g['p95_m']:.3f} m, max {g['max_m']:.3f} m")
    else:
        figures = self_consistency(est, reference, gap)
        print(f"  self-consistency (no truth): estimate - GNSS fix on track: rms "
              f"{figures['along_track_residual_rms_m']:.2f} m, "
              f"p50 {figures['along_track_residual_p50_m']:.2f} m, "
              f"p95 {figures['along_track_residual_p95_m']:.2f} m, "
              f"max {figures['along_track_residual_max_m']:.2f} m; backward output steps "
              f"{figures['backward_steps']}")
        if gap is not None and figures.get("gap_fixes"):
            what = "fixes and speeds" if args.eval_gap_odometer else "fixes"
            print(f"  GNSS withheld {args.eval_gps_gap} s ({result['gps_withheld']} {what}): estimate - "
                  f"withheld fix on track: p50 {figures['gap_residual_p50_m']:.2f} m, "
                  f"p95 {figures['gap_residual_p95_m']:.2f} m, max {figures['gap_residual_max_m']:.2f} m, "
                  f"at the end of the gap {figures['gap_residual_end_m']:.2f} m")
    filt = result["metrics"]["filter"]
    print(f"  filter outcomes: {', '.join(f'{k} {v}' for k, v in filt['outcomes'].items())}")
    write_updates_csv(Path(conv.out_dir) / "updates.csv", result["updates"])
    write_json(Path(conv.out_dir) / "evaluation.json", {
        "figures": figures, "filter_overrides": overrides, "without": sorted(args.eval_without),
        "listener_merge_hold_s": lcfg.merge.hold_s, "filter": filt,
        "gps_gap_s": args.eval_gps_gap, "gap_odometer": args.eval_gap_odometer,
        "withheld": result["gps_withheld"],
    })
    return 0
