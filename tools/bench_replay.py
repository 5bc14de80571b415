"""Replay throughput rows of ``sfa bench``: one capture, five ways, in the same run.

The capture is issue 17's must-show form (:func:`make_capture`): the simulator's ``regional-long``
run (the whole 92 min in the full mode, its first ``quick_s`` seconds in the quick mode) with no epoch
in any IMU, odometer or GNSS datagram (STROBE-dated, the thesis's sensors' form) and 1 % of the
datagrams lost, 1 % duplicated and 1 % reordered (``interface_modules.capture.lossy``, seed 17, the
same function the golden and fast-replay tests use). On it, side by side:

- ``sfa replay``'s default path (``tools.fast_replay.try_fast_replay``: pcap scan, decode, exact
  prefix, the listener's sequence buffers, STROBE dating, compiled filter, result; the output files
  are not written), per CPU second of the replaying process, with its time split per stage; and the
  slowest of 10 such replays back to back (the sustained figure),
- filter core: ``sfa.batch.run_packed`` over the measurements the default replay hands the filter
  (recorded from its ``TrackFilter.run`` call: dated, sequenced and merged), decode excluded,
- C reference: benchmarks/c (the same filter step in C, ``cc -O2``) on the same arrays; the core's
  time is reported as a ratio to it, with the largest difference of their estimates,
- exact replay end to end: ``tools.replay.replay_capture`` (the listener's pipeline per datagram),
- naive: per message, dpkt reader + ``listener.codec.decode_input`` + the listener's STROBE clock for
  the measurements without epoch + the plain FilterPy EKF (``sfa.baselines.plain_filterpy_ekf``), the
  "naive per-message FilterPy" figure of issues 7 and 17.

Every rate on the must-show capture is per CPU second (user + system) of this process. The same
filter configuration (the listener's, ``sfa.presets.config_for`` of the scenario's sensors) runs in
every path. The Jena tram row (junctions and stops, with epochs, no loss; wall clock) is kept as a
check of the junction hand-over.
"""

from __future__ import annotations

import importlib.util
import math
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from tools.bench_table import Row, median_of, timed
from tools.errors import ToolError

SCENARIO = "regional-long"
SECTION = "replay"
SUSTAINED_RUNS = 10  #: fast replays back to back (the repeats included) for the sustained row
LOSSY_SEED = 17  #: interface_modules.capture.lossy seed of the must-show capture (as the tests)
CORE_TARGET = 2.0  #: issue 17: the filter core within 2x the C reference


def repo_root() -> Path:
    return Path(__file__).resolve().parent.parent


def load_benchmark_module(name: str):
    """Import ``benchmarks/<name>.py`` (scripts of the source tree, not an installed package)."""
    path = repo_root() / "benchmarks" / f"{name}.py"
    if not path.is_file():
        raise ToolError(f"{path}: not found (sfa bench runs from a source checkout)")
    spec = importlib.util.spec_from_file_location(f"sfa_benchmarks_{name.replace('/', '_')}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def simulate_capture(out_dir: Path, duration_s: float | None, scenario: str) -> Path:
    """``sfa sim SCENARIO --out-dir`` in a child process; returns the capture path."""
    cmd = [sys.executable, "-m", "sfa", "sim", scenario, "--out-dir", str(out_dir)]
    if duration_s is not None:
        cmd += ["--duration", f"{duration_s:g}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900, check=False)
    if proc.returncode != 0:
        raise ToolError(f"sfa sim {scenario} failed: {proc.stderr.strip()[-500:]}")
    return out_dir / "capture.pcap"


def make_capture(path: Path, duration_s: float | None, scenario: str = SCENARIO, seed: int = LOSSY_SEED):
    """Issue 17's must-show capture: ``scenario`` (its first ``duration_s`` seconds; None: the whole run)
    STROBE-dated (``interface_modules.capture.strobe_dated``) with 1 % loss, duplicates and reordering
    (``interface_modules.capture.lossy``, ``seed``), written as a classic pcap. Returns the scenario."""
    from interface_modules.assemble import Packet
    from interface_modules.capture import datagrams_of, lossy, strobe_dated, write_packets_pcap
    from interface_modules.offline import generate
    from interface_modules.scenario import load_scenario

    sc = strobe_dated(load_scenario(scenario))
    dgrams = lossy(datagrams_of(generate(sc, max_duration_s=duration_s)), seed=seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_packets_pcap([Packet(t, src[1], p) for t, src, p in dgrams], sc.network, path)
    return sc


def cpu_timed(fn) -> float:
    """CPU time (user + system) of this process over one call [s]."""
    c0 = time.process_time()
    fn()
    return time.process_time() - c0


def record_filter_inputs(capture: Path, track, opts):
    """One default replay of ``capture`` with its filter's packed inputs recorded (``try_fast_replay``'s
    ``filter_inputs``: the measurements as dated, sequenced and merged, after the exact prefix), behind
    the capture's first GROUND TRUTH packed by ``sfa.batch.pack``. Returns (kind, t_s, values, result,
    info); (None, reason) parts when the replay fell back."""
    from listener.codec import DecodeError, GroundTruth, decode_input
    from listener.pipeline import to_measurement
    from sfa.batch import pack
    from tools.capture_reader import read_capture
    from tools.fast_replay import try_fast_replay

    seen: dict = {}
    res, info = try_fast_replay(capture, track, opts, filter_inputs=seen)
    if res is None or not seen:
        return None, None, None, res, info
    for d in read_capture(capture, opts.port):
        try:
            msg = decode_input(d.payload)
        except DecodeError:
            continue
        if isinstance(msg, GroundTruth):
            init = pack([to_measurement(msg, msg.epoch)], track)
            break
    else:  # pragma: no cover - every simulator capture starts with a GROUND TRUTH
        raise ToolError(f"{capture}: no GROUND TRUTH datagram")
    kind = np.concatenate([init.kind, seen["kind"]]).astype(np.int64)
    t_s = np.concatenate([init.t_s, seen["t"]])
    vals = np.vstack([init.values, seen["vals"]])
    return kind, t_s, vals, res, info


def _naive(capture: Path, track, cfg, clock_cfg) -> int:
    """The naive per-message path: dpkt reader, codec per datagram, the listener's STROBE clock for a
    measurement without epoch, FilterPy EKF per message (arrival order: no sequence repair)."""
    from listener.clock import StrobeClock
    from listener.codec import DecodeError, Strobe, decode_input
    from listener.pipeline import to_measurement
    from sfa.baselines import plain_filterpy_ekf
    from tools.capture_reader import read_capture

    clock = StrobeClock(clock_cfg)
    meas = []
    n = 0
    for d in read_capture(capture, 48000):
        n += 1
        try:
            msg = decode_input(d.payload)
        except DecodeError:
            continue
        if isinstance(msg, Strobe):
            clock.on_strobe(msg.timestamp, d.time_s)
            continue
        if not hasattr(msg, "epoch"):
            continue
        epoch = msg.epoch if msg.epoch is not None else clock.to_sensor_time(d.time_s)
        if epoch is None:
            continue
        meas.append(to_measurement(msg, epoch))
    plain_filterpy_ekf(track, meas, cfg)
    return n


def replay_rows(tmp: Path, quick: bool, repeats: int, quick_s: float = 300.0, log=print) -> list[Row]:
    from interface_modules.tracks import database_path
    from sfa import layout as L
    from sfa.batch import run_packed
    from sfa.track_arrays import TrackArrays
    from tools.fast_replay import try_fast_replay
    from tools.memory_policy import keep_freed_memory
    from tools.replay import ReplayOptions, replay_capture
    from track_db import TrackDatabase

    duration = quick_s if quick else None
    what = f"first {quick_s:g} s" if quick else "whole run"
    log(f"replay: simulating the {SCENARIO} capture ({what}), STROBE-dated, 1 % loss/duplicates/reordering")
    capture = tmp / "replay" / "capture.pcap"
    sc = make_capture(capture, duration)
    db_path = database_path(sc)
    if db_path is None:  # pragma: no cover - the scenario ships with its GTFS source
        raise ToolError(f"{SCENARIO}: no track database")
    track = TrackDatabase.open(db_path)
    opts = ReplayOptions(config=_listener_config(sc))
    cfg_obj = opts.config.filter.filter_config()
    cfg = cfg_obj.to_array()
    log("replay: default replay once (compiled code loaded)")
    keep_freed_memory()  # as `sfa replay` does (tools.memory_policy): this first run grows the heap
    r0 = resource.getrusage(resource.RUSAGE_SELF)
    res, info = try_fast_replay(capture, track, opts)
    first_sys = resource.getrusage(resource.RUSAGE_SELF).ru_stime - r0.ru_stime
    rows: list[Row] = []
    if res is None:
        track.close()
        return [
            Row(SECTION, "fast replay end to end (must-show capture)", None, "datagrams/s",
                target=">= 1,000,000/s", note=f"the default replay fell back: {info.reason}")
        ]  # fmt: skip
    n_dg = res.datagrams
    seq = res.metrics["sequencing"]
    minutes = (float(res.estimates["arrival"][-1]) - float(res.estimates["arrival"][0])) / 60.0
    span = (
        f"{minutes:.0f} min STROBE-dated capture, {n_dg:,} datagrams, lost {seq['lost']:,}, duplicates "
        f"{seq['duplicates']:,}, reordered {seq['reordered']:,}"
    )
    del res  # nothing of the warm-up is kept through the timed runs (below)

    log(f"replay: default replay end to end, {SUSTAINED_RUNS} back to back")
    runs = []  # (wall, info, CPU = user + system) of each run
    user_sys = []  # (user, system) CPU seconds of each run

    def run_fast():
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        t0 = time.perf_counter()
        out = try_fast_replay(capture, track, opts)
        wall = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        user_sys.append((r1.ru_utime - r0.ru_utime, r1.ru_stime - r0.ru_stime))
        runs.append((wall, out[1], sum(user_sys[-1])))
        return runs[-1][2]

    # A process's first two replays grow its heap: the warm-up above (code loaded, every column
    # allocated), then the next one around what the first left allocated (module state, caches: 34,000
    # to 77,000 page faults measured, 0.06-0.72 s of system time on this virtual machine, where a fault
    # on a page the host has not backed yet costs 10 us); from the third on a replay reuses the heap
    # (about 1,100 faults, mostly the capture's memory map). The second is run here, outside the
    # sustained row, and printed beside it: "sustained" is the steady state of a process that replays
    # again and again. These runs come before the recording run and the core and C rows, which keep
    # their inputs and outputs (tens of MB): a replay after them grew the heap again. Per CPU second of
    # this (single-threaded) process: "on one core", and robust to other processes sharing the machine;
    # the wall-clock rate is printed next to it. The first ``repeats`` runs give the median row, all
    # SUSTAINED_RUNS (back to back) the sustained row
    faults0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    run_fast()
    settle_faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults0
    _, _, settle_cpu = runs.pop()
    settle_user, settle_sys = user_sys.pop()
    t_fast, t_fast_all = median_of(run_fast, repeats)
    for _ in range(max(0, SUSTAINED_RUNS - repeats)):
        run_fast()
    fast_rate = n_dg / t_fast
    wall_rate = n_dg / statistics.median(r[0] for r in runs[:repeats])
    split = _split_text(min(runs[:repeats], key=lambda r: abs(r[2] - t_fast))[1])
    cpu_all = [r[2] for r in runs]
    slowest = n_dg / max(cpu_all)

    log("replay: default replay once more, its filter inputs recorded (for the core and C rows)")
    kind, t_s, vals, res, _ = record_filter_inputs(capture, track, opts)
    n_meas = int(kind.size)
    line_id = int(vals[0, 2]) if math.isfinite(vals[0, 2]) else int(track.default_line_id)
    line = TrackArrays.from_line(track.line(line_id))
    geometry = (line.s_m, line.east_m, line.north_m, line.grade, line.curvature_inv_m)

    def fresh():
        return (
            np.zeros(L.NX),
            np.zeros((L.NX, L.NX)),
            np.zeros(L.NAUX),
            np.zeros(L.NCNT, dtype=np.int64),
            np.zeros(L.NMEM),
            np.zeros((n_meas, 4)),
            np.zeros((n_meas, 3), dtype=np.int64),
        )

    last = {}

    def run_core(fn, key):
        x, P, aux, cnt, mem, out_f, out_i = fresh()
        dt = cpu_timed(lambda: fn(kind, t_s, vals, x, P, aux, cnt, mem, cfg, *geometry, out_f, out_i))
        last[key] = (out_f, out_i, cnt)
        return dt

    run_core(run_packed, "numba")  # compile / load the cache outside the timing
    log(f"replay: filter core ({n_meas:,} measurements) x{repeats}")
    t_core, t_core_all = median_of(lambda: run_core(run_packed, "numba"), repeats)
    core_rate = n_meas / t_core
    fresh_ok = _core_is_fresh(kind, t_s, vals, cfg, geometry, last["numba"])
    c_row = None
    c_rate = None
    c_name = f"filter core time / C reference time (same inputs; target within {CORE_TARGET:g}x)"
    try:
        cref = load_benchmark_module("c/cref").build()
    except Exception as exc:  # noqa: BLE001 - any build problem skips the comparison with its reason
        cref = None
        c_note = f"C reference skipped: {exc}"
    if cref is not None:
        run_core(cref.run_packed, "c")
        log(f"replay: C reference x{repeats}")
        t_c, t_c_all = median_of(lambda: run_core(cref.run_packed, "c"), repeats)
        fa, ia, ca = last["numba"]
        fb, ib, cb = last["c"]
        diff_s = float(np.nanmax(np.abs(fa[:, 1] - fb[:, 1])))
        same_outcomes = bool(np.array_equal(ia, ib) and np.array_equal(ca, cb))
        ratio = t_core / t_c
        c_rate = n_meas / t_c
        c_row = Row(
            SECTION,
            c_name,
            ratio,
            "x",
            compared=f"C {c_rate:,.0f} meas/s ({cref.compiler}); max |s_numba - s_C| = "
            f"{diff_s:.1e} m; outcomes and counters identical: {same_outcomes}",
            target=f"<= {CORE_TARGET:g}x",
            met=ratio <= CORE_TARGET,
            repeats=repeats,
            samples=tuple(a / b for a, b in zip(t_core_all, t_c_all, strict=True)),
            note="" if ratio <= CORE_TARGET else _core_note(),
        )
    rows.append(
        Row(
            SECTION,
            f"filter core alone, sfa.batch.run_packed, on the default replay's filter inputs ({span})",
            core_rate,
            "meas/s",
            compared=f"C reference {'(see next row)' if c_row else 'skipped'}; equal to a freshly "
            f"compiled loop of the same kernels: {fresh_ok}",
            repeats=repeats,
            samples=tuple(n_meas / t for t in t_core_all),
        )
    )
    rows.append(c_row or Row(SECTION, c_name, None, "x", target=f"<= {CORE_TARGET:g}x", note=c_note))

    slow_repeats = 1  # minutes per run on the whole capture: one run, said in the table
    log(f"replay: exact replay end to end x{slow_repeats} (slow)")
    holder = {}

    def run_exact():
        holder["exact"] = replay_capture(capture, track, opts)

    t_exact, t_exact_all = median_of(lambda: cpu_timed(run_exact), slow_repeats)
    exact_rate = n_dg / t_exact
    equal = _same_new_estimates(holder["exact"], res)
    log(f"replay: naive per-message FilterPy x{slow_repeats} (slow)")
    clock_cfg = opts.config.clock
    t_naive, t_naive_all = median_of(
        lambda: cpu_timed(lambda: _naive(capture, track, cfg_obj, clock_cfg)), slow_repeats
    )
    naive_rate = n_dg / t_naive
    rows.append(
        Row(
            SECTION,
            f"sfa replay default path, fast replay end to end ({span}), per CPU second",
            fast_rate,
            "datagrams/s",
            compared=f"wall clock {wall_rate:,.0f}/s; "
            f"exact replay {exact_rate:,.0f}/s ({fast_rate / exact_rate:.0f}x); "
            f"naive per-message FilterPy {naive_rate:,.0f}/s ({fast_rate / naive_rate:.1f}x); "
            f"new estimates identical to the exact replay: {equal}; "
            f"{info.exact_prefix:,} datagrams through the exact prefix, "
            f"{info.compiled / n_dg:.1%} compiled; time split: {split}",
            target=">= 1,000,000/s",
            met=fast_rate >= 1e6,
            repeats=repeats,
            samples=tuple(n_dg / t for t in t_fast_all),
            note=""
            if fast_rate >= 1e6
            else _throughput_note(core_rate, c_rate, n_meas, n_dg, split, fast_rate),
        )
    )
    rows.append(
        Row(
            SECTION,
            f"sfa replay default path, {len(cpu_all)} runs back to back in one process: the slowest, "
            "per CPU second (sustained)",
            slowest,
            "datagrams/s",
            compared=f"median {n_dg / statistics.median(cpu_all):,.0f}/s, "
            f"fastest {n_dg / min(cpu_all):,.0f}/s; user CPU per run "
            f"{min(u for u, _ in user_sys):.3f}-{max(u for u, _ in user_sys):.3f} s, system "
            f"{min(y for _, y in user_sys):.3f}-{max(y for _, y in user_sys):.3f} s (page faults: the "
            "replay process keeps freed memory, tools.memory_policy); before them the process's first "
            f"replay, the warm-up, grew the heap with {first_sys:.3f} s of system time, and its second "
            f"ran at {n_dg / settle_cpu:,.0f}/s (user {settle_user:.3f} s, system {settle_sys:.3f} s, "
            f"{settle_faults:,} page faults)",
            target=">= 1,000,000/s",
            met=slowest >= 1e6,
            repeats=len(cpu_all),
            samples=tuple(n_dg / c for c in cpu_all),
        )
    )
    ratio_naive = fast_rate / naive_rate
    rows.append(
        Row(
            SECTION,
            "sfa replay default path / naive per-message FilterPy EKF (same capture, CPU seconds)",
            ratio_naive,
            "x",
            compared=f"naive {naive_rate:,.0f} datagrams/s (dpkt + codec + STROBE clock + FilterPy per "
            f"message); the sustained (slowest) replay gives {slowest / naive_rate:.1f}x",
            target=">= 20x",
            met=ratio_naive >= 20.0,
            repeats=1,
            note="" if ratio_naive >= 20.0 else _naive_note(core_rate, c_rate, naive_rate, n_meas, n_dg),
        )
    )
    rows.append(_junction_row(tmp, quick, repeats, log))
    rows.append(
        Row(
            SECTION,
            "exact replay end to end (listener pipeline per datagram, same capture), per CPU second",
            exact_rate,
            "datagrams/s",
            compared=f"naive per-message FilterPy {naive_rate:,.0f}/s",
            repeats=1,
            samples=tuple(n_dg / t for t in t_exact_all),
        )
    )
    rows.append(
        Row(
            SECTION,
            "naive per-message FilterPy EKF end to end (same capture), per CPU second",
            naive_rate,
            "datagrams/s",
            compared="the reference of the >= 20x target",
            repeats=1,
            samples=tuple(n_dg / t for t in t_naive_all),
        )
    )
    track.close()
    return rows


def _listener_config(sc):
    from listener.config import FilterSelection, ListenerConfig

    return ListenerConfig(
        filter=FilterSelection(imu=sc.imu.preset, odometer=sc.odometer.preset, gps=sc.gps.preset)
    )


def new_rows(result) -> np.ndarray:
    """Rows of ``result.estimates`` that are new estimates, told apart from retransmissions by content:
    a retransmission repeats the newest output of its SEQ (same SEQ, epoch and arc length).

    Independent of the ``retransmit`` column, which tools.replay derives from SEQ values seen so far
    and therefore flags every output as a retransmission once SEQ has wrapped (65,536 outputs)."""
    est = result.estimates
    last: dict[int, tuple[float, float]] = {}
    keep = np.ones(est["seq"].size, dtype=bool)
    rows = zip(est["seq"].tolist(), est["epoch"].tolist(), est["arc_length"].tolist(), strict=True)
    for i, (seq, epoch, s) in enumerate(rows):
        if last.get(seq) == (epoch, s):
            keep[i] = False
        last[seq] = (epoch, s)
    return keep


def _same_new_estimates(exact, fast) -> bool:
    ka, kb = new_rows(exact), new_rows(fast)
    for k in exact.estimates:
        if k == "retransmit":
            continue
        x = np.asarray(exact.estimates[k][ka], dtype=float)
        y = np.asarray(fast.estimates[k][kb], dtype=float)
        if x.shape != y.shape or not np.array_equal(x, y, equal_nan=True):
            return False
    return True


def _core_is_fresh(kind, t_s, vals, cfg, geometry, result) -> bool:
    """run_packed's outputs equal those of tools.fast_loop (same kernels, never disk-cached): False means
    numba's disk cache of sfa.batch.run_packed predates a change of sfa/kernels.py (numba keys the cache
    on the caller's file only); delete sfa/__pycache__/batch.* to refresh it."""
    from sfa import layout as L
    from tools.fast_loop import run_replay_loop

    n = kind.size
    out_f = np.zeros((n, 5))
    out_i = np.zeros((n, 4), dtype=np.int64)
    run_replay_loop(
        kind,
        t_s,
        vals,
        np.zeros(L.NX),
        np.zeros((L.NX, L.NX)),
        np.zeros(L.NAUX),
        np.zeros(L.NCNT, dtype=np.int64),
        np.zeros(L.NMEM),
        cfg,
        *geometry,
        -np.inf,
        np.nan,
        out_f,
        out_i,
    )
    fa, ia, _ = result
    return bool(np.array_equal(fa, out_f[:, :4], equal_nan=True) and np.array_equal(ia, out_i[:, :3]))


def _naive_note(core_rate, c_rate, naive_rate, n_meas, n_dg) -> str:
    return (
        "the naive path runs a 4-state FilterPy model without integrity, sequence repair or output rule, a "
        "much smaller filter than SFA's 11 states with gyro, slip and GNSS fault handling; the compiled "
        f"core alone runs {core_rate * n_dg / n_meas / naive_rate:.0f}x the naive figure (in datagrams)"
    )


def _core_note() -> str:
    return (
        "the C reference is a line-by-line transliteration of sfa/kernels.py (bit-identical results); what "
        "is left between them is numba's code generation for the small fixed-size loops (array strides "
        "and index wraparound checks that the C compiler does not have)"
    )


def _throughput_note(
    core_rate: float, c_rate: float | None, n_meas: int, n_dg: int, split: str, fast_rate: float
) -> str:
    ceiling = core_rate * n_dg / n_meas
    c_text = "" if c_rate is None else f"; the C reference of the same step runs {c_rate:,.0f} measurements/s"
    return (
        f"the compiled filter core alone (sfa.batch.run_packed, one hypothesis) runs {core_rate:,.0f} "
        f"measurements/s on the same inputs, i.e. {ceiling:,.0f} datagrams/s with everything else free; the "
        f"replay reaches {fast_rate / ceiling:.0%} of that{c_text}. Time split of the replay (wall, stages "
        f"of at least 5 ms): {split} ('checks' holds the listener's sequence buffers over every datagram "
        "after the first gap, tools.fast_replay._sequence); the rest is outside the named stages"
    )


def _split_text(info) -> str:
    """Seconds per stage of one fast replay, largest first."""
    parts = sorted(info.timing.items(), key=lambda kv: -kv[1])
    return ", ".join(f"{k} {v:.2f} s" for k, v in parts if v >= 0.005)


JUNCTION_SCENARIO = "tram-urban"


def _junction_row(tmp: Path, quick: bool, repeats: int, log) -> Row:
    """The fast replay on the Jena tram (junctions, stops) against the exact replay of the same capture."""
    from interface_modules.scenario import load_scenario
    from interface_modules.tracks import database_path
    from tools.fast_replay import try_fast_replay
    from tools.replay import ReplayOptions, replay_capture
    from track_db import TrackDatabase

    sc = load_scenario(JUNCTION_SCENARIO)
    db_path = database_path(sc)
    name = f"fast replay end to end, wall clock, junctions and stops ({JUNCTION_SCENARIO}"
    if db_path is None:  # pragma: no cover - the scenario ships with its track source
        return Row(SECTION, name + ")", None, "datagrams/s", note="no track database")
    track = TrackDatabase.open(db_path)
    try:
        duration = 120.0 if quick else None
        log(f"replay: simulating the {JUNCTION_SCENARIO} capture ({'first 120 s' if quick else 'whole run'})")
        capture = simulate_capture(tmp / "replay-junctions", duration, JUNCTION_SCENARIO)
        opts = ReplayOptions(config=_listener_config(sc))
        res, info = try_fast_replay(capture, track, opts)
        if res is None:
            return Row(
                SECTION, name + ")", None, "datagrams/s", note=f"the fast path fell back: {info.reason}"
            )
        n_dg = res.datagrams
        log(f"replay: {JUNCTION_SCENARIO} fast replay x{repeats}, exact replay x1")
        t_fast, t_all = median_of(lambda: timed(lambda: try_fast_replay(capture, track, opts)), repeats)
        holder = {}
        t_exact = timed(lambda: holder.setdefault("exact", replay_capture(capture, track, opts)))
        equal = _same_new_estimates(holder["exact"], res)
        fr = res.metrics["fast_replay"]
        return Row(
            SECTION,
            f"{name}, {n_dg:,} datagrams)",
            n_dg / t_fast,
            "datagrams/s",
            compared=f"exact replay {n_dg / t_exact:,.0f}/s ({t_exact / t_fast:.0f}x); new estimates "
            f"identical to the exact replay: {equal}; {info.compiled / n_dg:.1%} of the datagrams compiled, "
            f"{info.python_steps:,} measurements through TrackFilter.process "
            f"(junction windows, branches spawned by TrackFilter.run: {fr['handed_back_at_junctions']})",
            repeats=repeats,
            samples=tuple(n_dg / t for t in t_all),
        )
    finally:
        track.close()


def finite(x) -> bool:
    return x is not None and math.isfinite(x)
