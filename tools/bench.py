"""``sfa bench [--quick]``: the benchmark suite, one table, every figure beside its comparison.

Sections (each a module of its own, see their docstrings for what exactly is compared):

- accuracy on the shipped scenarios: SFA against odometer-only, raw GPS projection and a plain
  per-message FilterPy EKF, with the interval coverage (tools/bench_accuracy.py),
- replay throughput on issue 17's must-show capture (regional-long, STROBE-dated, 1 % loss, duplicates
  and reordering): sfa replay's default path end to end (median and slowest of 10 back to back), the
  filter core alone on its filter inputs and its ratio to the C reference of the same step, exact
  replay end to end, the naive per-message FilterPy path, all per CPU second (tools/bench_replay.py),
- listener latency and drops at 1x / 10x / 100x nominal rates and CPU at 1x (tools/bench_live.py),
- listener memory over a soak at 1x (10 min; 1 min in --quick), run in the background while the
  in-process sections run (it is not timing-sensitive; said in the table),
- track queries per second (tools/bench_queries.py),
- start-up: ``sfa listen``'s first output after spawn and its peak RSS on an empty numba cache, the
  compiled engine against the JIT on an empty and a warm cache (tools/bench_startup.py).

Every figure is the median over ``--repeat`` runs (the slow comparisons on the whole 1 h capture run
once; the table says how many runs each figure is over). The machine, its load at start and end, and
the versions are recorded. Writes the table as markdown and JSON (``--out``), and with ``--docs`` the
generated block of docs/performance.md.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

SECTIONS = ("accuracy", "generalisation", "replay", "listener", "memory", "track", "startup")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--quick", action="store_true", help="smoke run for CI: under 2 minutes, small inputs"
    )
    parser.add_argument("--out", default="bench-results", help="directory for bench.md and bench.json")
    parser.add_argument(
        "--docs",
        metavar="PATH",
        help="also rewrite the generated table block of this file (docs/performance.md)",
    )
    parser.add_argument(
        "--repeat", type=int, default=None, help="runs per figure (default 3; 1 with --quick)"
    )
    parser.add_argument(
        "--only", action="append", choices=SECTIONS, help="run only these sections (repeatable)"
    )
    parser.add_argument(
        "--seeds", type=int, default=None, help="accuracy: seeds per scenario (default 3; 1 quick)"
    )
    parser.add_argument(
        "--scenario", action="append", help="accuracy: only this shipped scenario (repeatable; default all)"
    )
    parser.add_argument(
        "--soak-s", type=float, default=None, help="memory soak length [s] (default 600; 45 quick)"
    )


def run(args: argparse.Namespace) -> int:
    from tools.bench_env import environment, load_average
    from tools.bench_replay import repo_root
    from tools.bench_table import print_rich, to_json, to_markdown, update_doc
    from tools.errors import ToolError

    quick = bool(args.quick)
    repeats = args.repeat if args.repeat is not None else (1 if quick else 3)
    if repeats < 1:
        raise ToolError("--repeat must be >= 1")
    seeds = args.seeds if args.seeds is not None else (1 if quick else 3)
    if seeds < 1:
        raise ToolError("--seeds must be >= 1")
    soak_s = args.soak_s if args.soak_s is not None else (45.0 if quick else 600.0)
    if soak_s < 10.0:
        raise ToolError("--soak-s must be >= 10 s")
    only = set(args.only or SECTIONS)
    out_dir = Path(args.out)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ToolError(f"--out {out_dir}: {exc.strerror or exc}") from exc
    if args.scenario:
        from interface_modules.scenario import scenario_names

        unknown = sorted(set(args.scenario) - set(scenario_names()))
        if unknown:
            raise ToolError(f"unknown scenario {', '.join(unknown)} (shipped: {', '.join(scenario_names())})")
    env = environment(repo_root(), "quick" if quick else "full")

    def log(msg: str) -> None:
        print(f"[bench] {msg}", file=sys.stderr, flush=True)

    rows = []
    with tempfile.TemporaryDirectory(prefix="sfa-bench-") as tmp_name:
        tmp = Path(tmp_name)
        soak = None
        if "memory" in only:
            from tools.bench_live import SoakRun

            (tmp / "soak").mkdir()
            soak = SoakRun(tmp / "soak", soak_s).start()
            log(f"memory: {soak_s:g} s soak started in the background (sfa listen + sfa sim --live)")
        try:
            if "accuracy" in only:
                from tools.bench_accuracy import accuracy_rows

                rows += accuracy_rows(
                    quick, seeds, max_duration_s=120.0 if quick else None, names=args.scenario, log=log
                )
            if "generalisation" in only:
                from tools.bench_generalisation import generalisation_rows

                rows += generalisation_rows(1 if quick else 20, 120.0 if quick else 300.0, log=log,
                                            real=not quick)
            if "replay" in only:
                from tools.bench_replay import replay_rows

                rows += replay_rows(tmp, quick, repeats, quick_s=120.0, log=log)
            if "track" in only:
                from tools.bench_queries import query_rows

                rows += query_rows(20_000 if quick else 200_000, repeats, log=log)
        except BaseException:
            if soak is not None:
                soak.abort()  # no orphaned listener/simulator processes on an error or Ctrl-C
            raise
        if soak is not None:
            rows.append(soak.join(log=log))
        if "listener" in only:
            from tools.bench_live import latency_rows

            rows += latency_rows(tmp, 3.0 if quick else 20.0, repeats, log=log)
        if "startup" in only:  # timed from spawn: alone, after the soak, like the latency section
            from tools.bench_startup import startup_rows

            rows += startup_rows(repeats, quick, log=log)
    from datetime import UTC, datetime

    env["load_end"] = load_average()
    env["finished_utc"] = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    env["concurrency"] = (
        "the memory soak (sfa listen + sfa sim --live at 1x) runs in the background during the accuracy, "
        "replay and track sections; the listener latency and start-up sections run alone after it"
    )
    md = to_markdown(rows, env)
    (out_dir / "bench.md").write_text(md)
    (out_dir / "bench.json").write_text(to_json(rows, env))
    if args.docs:
        update_doc(Path(args.docs), md)
    print_rich(rows, env)
    print(
        f"written: {out_dir / 'bench.md'}, {out_dir / 'bench.json'}" + (f", {args.docs}" if args.docs else "")
    )
    return 0
