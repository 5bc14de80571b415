"""Vital supervision intervention times, live: p50 / p99 / max over N silent windows per sensor.

A real ``sfa listen`` on 127.0.0.1, a fake sensor set (one UDP socket per interface module, a seeded
synthetic run in real time) and a fake OBCU (acks every output). In each window one module (or all of
them) falls silent; measured on the wall clock of this host from its last datagram to (1) the
listener's own ``status`` log line naming the reason and (2) the OBCU receiving the extended output
with that status. See tools/vital_live.py; docs/reliability.md, "Intervention-time budget", has the
results. Targets (issue 19): a dead IMU <= 0.6 s at p99 to the OBCU, any other sensor its
``*_timeout_s`` + 0.1 s.

    python benchmarks/bench_vital.py [--runs 20] [--out vital.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    from tools.vital_live import KINDS, run_live, table

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20, help="silent windows per sensor kind")
    ap.add_argument("--out", help="write the rows and the summary as JSON")
    ap.add_argument("--work", help="keep the track, the listener's log here (default: a temporary directory)")
    args = ap.parse_args(argv)
    if args.work:
        res = run_live(list(KINDS), args.runs, Path(args.work))
    else:
        with tempfile.TemporaryDirectory() as tmp:
            res = run_live(list(KINDS), args.runs, Path(tmp))
    print(table(res["summary"]))
    ok = True
    for kind, e in res["summary"].items():
        target = 0.6 if kind == "imu" else e["timeout_s"] + 0.1
        met = e.get("obcu_s_p99", float("inf")) <= target and not e.get("obcu_s_missing", 1)
        ok &= met
        print(f"{kind}: OBCU p99 {e.get('obcu_s_p99', float('nan')):.3f} s, target {target:.1f} s: "
              f"{'met' if met else 'MISSED'}")
    if args.out:
        Path(args.out).write_text(json.dumps(res, indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from sfa.cli import configure_numba_cache

    configure_numba_cache()  # keyed on the sources: never a stale compiled kernel after an edit
    raise SystemExit(main())
