"""``sfa demo``: the whole system on loopback, on the bundled real tram track.

Starts three kinds of real processes: the mock OBCU (``sfa obcu``), the listener (``sfa listen``) and
the simulator's interface modules (``sfa sim --live``, one process per sensor), all on 127.0.0.1
with free ports. It shows live progress (position, speed, error against truth, link state), waits for
the scenario's STOP, then prints an accuracy summary against the simulator's truth and writes the
run report into the output directory: ``report.html`` (tools/report.py, the same page as ``sfa
replay``'s, with the OBCU link section), a short ``report.md``, the figures, and the datagrams the
modules sent as ``capture.pcap`` with ``truth.csv`` and ``events.csv`` (``sfa replay`` takes them). The
innovations and reasons come from an offline replay of that capture, labelled so: the live output
carries neither. No network beyond loopback.
"""

from __future__ import annotations

import argparse

DEFAULT_SCENARIO = "tram-urban"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scenario", default=DEFAULT_SCENARIO, help=f"shipped scenario (default {DEFAULT_SCENARIO})"
    )
    parser.add_argument(
        "--duration", type=float, default=240.0, help="simulated seconds of the scenario to run (default 240)"
    )
    parser.add_argument(
        "--speed",
        type=float,
        default=4.0,
        help="simulated seconds per wall second (default 4: about a minute of wall time)",
    )
    parser.add_argument("--seed", type=int, help="seed of the sensor errors (default: the scenario's)")
    parser.add_argument("--out", default="demo-out", help="directory for the report (default ./demo-out)")
    parser.add_argument("--quiet", action="store_true", help="no live display")


def run(args: argparse.Namespace) -> int:
    from tools.demo_runner import DemoOptions, run_demo

    opts = DemoOptions(
        scenario=args.scenario,
        duration_s=args.duration,
        speed=args.speed,
        seed=args.seed,
        out_dir=args.out,
        live_display=not args.quiet,
    )
    return run_demo(opts)
