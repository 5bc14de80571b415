"""Benchmark: offline generation time of the long (>= 1 h) scenario.

Measures, in one run and side by side:
  1. ``generate`` (truth, sensors, datagrams; the library path the Monte-Carlo benchmarks use),
  2. writing the classic pcap,
  3. writing truth.csv,
and prints each figure, the total, the simulated-time / wall-time ratio, and the total scaled to one
simulated hour against the target (< 60 s per simulated hour on this machine). A second seed is
generated too, to show the per-seed cost once the track database and numba kernels are warm.

    /work/.venv/bin/python benchmarks/bench_sim.py [--scenario regional-long] [--out-dir DIR]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

TARGET_S_PER_HOUR = 60.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="regional-long")
    parser.add_argument(
        "--out-dir", help="where to write the capture and truth (default: a temporary directory)"
    )
    args = parser.parse_args(argv)

    from interface_modules.capture import write_pcap, write_truth_csv
    from interface_modules.offline import generate
    from interface_modules.scenario import load_scenario
    from interface_modules.tracks import open_line

    sc = load_scenario(args.scenario)
    t = time.perf_counter()
    open_line(sc)  # builds the cached track database on first use; not part of a generation
    t_track = time.perf_counter() - t

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out_dir or tmp)
        out.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        run = generate(sc)
        t1 = time.perf_counter()
        write_pcap(run, out / "capture.pcap")
        t2 = time.perf_counter()
        write_truth_csv(run, out / "truth.csv")
        t3 = time.perf_counter()
        run2 = generate(sc, seed=sc.seed + 1)
        t4 = time.perf_counter()
        pcap_mb = (out / "capture.pcap").stat().st_size / 1e6

    sim_s = run.duration_s
    total = t3 - t0
    per_hour = total * 3600.0 / sim_s
    print(
        f"scenario {sc.name}: {sim_s:.0f} s simulated ({sim_s / 3600:.2f} h), {len(run.packets)} datagrams, "
        f"capture {pcap_mb:.1f} MB"
    )
    print(f"  track database open/build : {t_track:8.2f} s (cached after the first run)")
    print(f"  generate (seed {run.seed:<3})       : {t1 - t0:8.2f} s")
    print(f"  write pcap                : {t2 - t1:8.2f} s")
    print(f"  write truth.csv           : {t3 - t2:8.2f} s")
    print(f"  total offline run         : {total:8.2f} s  -> simulated/wall = {sim_s / total:6.0f}x")
    again = t4 - t3
    print(
        f"  generate again (seed {run2.seed:<3}): {again:8.2f} s  -> simulated/wall = {sim_s / again:6.0f}x"
    )
    verdict = "meets" if per_hour < TARGET_S_PER_HOUR else "MISSES"
    print(
        f"  per simulated hour        : {per_hour:8.2f} s  ({verdict} the < {TARGET_S_PER_HOUR:.0f} s target)"
    )
    return 0 if per_hour < TARGET_S_PER_HOUR else 1


if __name__ == "__main__":
    from sfa.cli import configure_numba_cache

    configure_numba_cache()  # keyed on the sources: never a stale compiled kernel after an edit
    sys.exit(main())
