"""Speed of the SFA filter: measurements per second, measured side by side in one run.

Compared on the same seeded synthetic run (``sfa.synthetic``: 100 Hz IMU, 20 Hz odometer, 1 Hz GNSS):

- ``batch``: ``sfa.batch.run_packed`` (the compiled kernels in a compiled loop, packing excluded),
- ``per-message``: ``TrackFilter.process`` + ``estimate`` after every message (the listener's path),
- ``filterpy``: the plain per-message FilterPy EKF baseline (``sfa.baselines.plain_filterpy_ekf``),
  a smaller model (4 states, no integrity), as the reference for "pure Python/numpy" speed.

Compilation is excluded (``warm_up`` first). Prints messages/s and the ratios between the paths.
Usage: python benchmarks/bench_filter_speed.py [--duration 600] [--repeat 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CLOCK = time.perf_counter  #: wall time; --cpu switches to this process's CPU time


def best_of(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = CLOCK()
        fn()
        best = min(best, CLOCK() - t0)
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=600.0, help="simulated seconds [s]")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cpu", action="store_true",
                    help="time with this process's CPU time (less sensitive to other load)")
    args = ap.parse_args(argv)
    global CLOCK
    if args.cpu:
        CLOCK = time.process_time

    from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
    from sfa import batch, layout
    from sfa.baselines import plain_filterpy_ekf
    from sfa.filter import TrackFilter
    from sfa.presets import filter_config_for
    from sfa.synthetic import build_track_db, generate
    from sfa.track_arrays import TrackArrays
    from track_db import TrackDatabase

    with tempfile.TemporaryDirectory() as tmp:
        db = TrackDatabase.open(build_track_db(Path(tmp) / "speed.db"))
        cfg = filter_config_for()
        run = generate(db, 1, args.duration, IMU_PRESETS["mems-train"], ODOMETER_PRESETS["wheel-odometer"],
                       GPS_PRESETS["standalone"], seed=1)
        meas = run.measurements
        n = len(meas)
        TrackFilter(db, cfg).warm_up()
        packed = batch.pack(meas, db)
        line = TrackArrays.from_line(db.line(1))
        cfg_arr = cfg.to_array()

        def run_batch():
            x = np.zeros(layout.NX)
            P = np.zeros((layout.NX, layout.NX))
            aux = np.zeros(layout.NAUX)
            cnt = np.zeros(layout.NCNT, dtype=np.int64)
            mem = np.zeros(layout.NMEM)
            out_f = np.zeros((n, 4))
            out_i = np.zeros((n, 3), dtype=np.int64)
            batch.run_packed(packed.kind, packed.t_s, packed.values, x, P, aux, cnt, mem, cfg_arr, line.s_m,
                             line.east_m, line.north_m, line.grade, line.curvature_inv_m, out_f, out_i)

        def run_per_message():
            f = TrackFilter(db, cfg)
            for m in meas:
                f.process(m)
                f.estimate()

        def run_filterpy():
            plain_filterpy_ekf(db, meas, cfg)

        t_batch = best_of(run_batch, args.repeat)
        t_msg = best_of(run_per_message, max(1, args.repeat - 1))
        t_fp = best_of(run_filterpy, 1)
        db.close()
    print(f"# SFA filter speed: {n} measurements ({args.duration:.0f} s simulated), best of {args.repeat}, "
          f"{'CPU' if args.cpu else 'wall'} time")
    print(f"{'path':<14} {'time [s]':>9} {'msg/s':>12}")
    for name, t in (("batch", t_batch), ("per-message", t_msg), ("filterpy", t_fp)):
        print(f"{name:<14} {t:9.3f} {n / t:12.0f}")
    print(f"batch vs per-message: {t_msg / t_batch:.1f}x; per-message vs plain FilterPy EKF: "
          f"{t_fp / t_msg:.1f}x; batch vs FilterPy: {t_fp / t_batch:.1f}x")
    print(f"batch replay faster than real time by {args.duration / t_batch:.0f}x")
    return 0


if __name__ == "__main__":
    from sfa.cli import configure_numba_cache

    configure_numba_cache()  # keyed on the sources: never a stale compiled kernel after an edit
    sys.exit(main())
