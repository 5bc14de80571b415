"""sfa bench: the C reference builds and agrees with the compiled kernels; --quick writes a complete table.

Functional checks only: no timing threshold is asserted anywhere (figures belong to the bench).
"""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from sfa import batch
from sfa import layout as L
from sfa.presets import datasheet_config_for, filter_config_for
from sfa.synthetic import Faults, build_track_db, generate
from sfa.track_arrays import TrackArrays
from tools.bench_table import DOC_BEGIN, DOC_END, Row, to_markdown, update_doc
from track_db import TrackDatabase

ROOT = Path(__file__).resolve().parent.parent


def _cref():
    spec = importlib.util.spec_from_file_location("sfa_bench_cref", ROOT / "benchmarks" / "c" / "cref.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_layout_header_names_every_slot_with_its_value():
    header = _cref().layout_header()
    for name in (
        "NX",
        "S",
        "V",
        "SF",
        "NMEM",
        "A_T_STATE",
        "C_SLIP_REWIND",
        "K_Z_INTERVAL",
        "MEM_H0",
        "R_SLIP",
    ):
        assert f"#define {name} {getattr(L, name)}\n" in header
    from sfa.config import CFG_SLOTS

    for i, name in enumerate(CFG_SLOTS):  # every configuration slot, numbered from FilterConfig
        assert f"#define {name} {i}\n" in header
    assert f"#define NCFG {len(CFG_SLOTS)}\n" in header
    assert f"#define NVALS {batch.NV}\n" in header


def _packed_run(tmp_path, faults=None):
    db = TrackDatabase.open(build_track_db(tmp_path / "t.db"))
    run = generate(
        db,
        1,
        120.0,
        IMU_PRESETS["mems-train"],
        ODOMETER_PRESETS["wheel-odometer"],
        GPS_PRESETS["standalone"],
        seed=11,
        faults=faults,
    )
    packed = batch.pack(run.measurements, db)
    line = TrackArrays.from_line(db.line(1))
    return db, packed, line


def _run(fn, packed, line, cfg):
    n = packed.kind.size
    st = [
        np.zeros(L.NX),
        np.zeros((L.NX, L.NX)),
        np.zeros(L.NAUX),
        np.zeros(L.NCNT, dtype=np.int64),
        np.zeros(L.NMEM),
    ]
    out_f = np.zeros((n, 4))
    out_i = np.zeros((n, 3), dtype=np.int64)
    fn(
        packed.kind,
        packed.t_s,
        packed.values,
        *st,
        cfg,
        line.s_m,
        line.east_m,
        line.north_m,
        line.grade,
        line.curvature_inv_m,
        out_f,
        out_i,
    )
    return out_f, out_i, st


def test_c_reference_agrees_with_the_compiled_kernels(tmp_path):
    mod = _cref()
    if mod.find_compiler() is None:
        pytest.skip("no C compiler on this machine")
    ref = mod.build(tmp_path / "cache")
    db, packed, line = _packed_run(tmp_path)
    cfg = filter_config_for().to_array()
    fa, ia, sa = _run(batch.run_packed, packed, line, cfg)
    fb, ib, sb = _run(ref.run_packed, packed, line, cfg)
    db.close()
    assert packed.kind.size > 10000
    # same branches taken everywhere: outcomes, status, reason bits and every counter identical
    np.testing.assert_array_equal(ia, ib)
    np.testing.assert_array_equal(sa[3], sb[3])
    assert sa[3][L.C_GPS_OK] > 50 and sa[3][L.C_ODO_OK] > 1000 and sa[3][L.C_INIT] == 1
    # values: the C follows the kernels operation by operation (same order, same association): every
    # estimate, sigma and the final covariance are bit-identical
    np.testing.assert_array_equal(fb, fa)
    np.testing.assert_array_equal(sb[1], sa[1])
    # the library is cached by source hash: a second build loads the same file
    assert mod.build(tmp_path / "cache").path == ref.path


def test_c_reference_agrees_with_the_datasheet_configuration(tmp_path):
    """The datasheet presets: the adaptive GNSS error model (sfa.gnss_noise), the map terms of the
    gyro and the registration noise, with the gyro on so that its branches run too."""
    mod = _cref()
    if mod.find_compiler() is None:
        pytest.skip("no C compiler on this machine")
    ref = mod.build(tmp_path / "cache")
    db, packed, line = _packed_run(tmp_path)
    cfg = datasheet_config_for(use_gyro=True, gps_fit_standstill=True).to_array()
    assert cfg[L.K_AD_WINDOW] > 0.0
    fa, ia, sa = _run(batch.run_packed, packed, line, cfg)
    fb, ib, sb = _run(ref.run_packed, packed, line, cfg)
    db.close()
    np.testing.assert_array_equal(ia, ib)
    np.testing.assert_array_equal(sa[3], sb[3])
    # the model moved off the preset (so the adaptive branches ran), identically in both
    assert sa[2][L.A_GM_TAU] != cfg[L.K_GM_TAU] and sa[2][L.A_AD_W] > cfg[L.K_AD_PRIOR]
    assert cfg[L.K_AD_STILL] != 0.0 and sa[2][L.A_AD_DW + 1] > 0.0  # the standstill moments ran
    assert cfg[L.K_GYRO_AD_M] > 0.0 and sa[2][L.A_GY_LAM_DEN] > 0.0  # the learned curvature scale ran
    np.testing.assert_array_equal(sb[2][L.A_GM_SIG:L.A_WK_PHT], sa[2][L.A_GM_SIG:L.A_WK_PHT])
    np.testing.assert_array_equal(fb, fa)
    np.testing.assert_array_equal(sb[1], sa[1])


def test_c_reference_agrees_with_the_maximum_likelihood_gnss_model(tmp_path):
    """The datasheet presets with the GNSS error model estimated by the maximum-likelihood bank
    (gps_adaptive_ml): its prior from the preset's expected statistics, and every point's filter."""
    mod = _cref()
    if mod.find_compiler() is None:
        pytest.skip("no C compiler on this machine")
    ref = mod.build(tmp_path / "cache")
    db, packed, line = _packed_run(tmp_path)
    cfg = datasheet_config_for(gps_adaptive_ml=True).to_array()
    fa, ia, sa = _run(batch.run_packed, packed, line, cfg)
    fb, ib, sb = _run(ref.run_packed, packed, line, cfg)
    db.close()
    np.testing.assert_array_equal(ia, ib)
    np.testing.assert_array_equal(sa[3], sb[3])
    # the bank took fixes and moved the model off the preset, identically in both
    assert sa[2][L.A_ML_N] > 2.0 * cfg[L.K_AD_PRIOR] and sa[2][L.A_GM_TAU] != cfg[L.K_GM_TAU]
    np.testing.assert_array_equal(sb[2][L.A_GM_SIG:L.A_WK_PHT], sa[2][L.A_GM_SIG:L.A_WK_PHT])
    np.testing.assert_array_equal(fb, fa)
    np.testing.assert_array_equal(sb[1], sa[1])


def test_c_reference_agrees_through_sensor_faults(tmp_path):
    """Slip (rewind), a 0.3 m/s^2 accelerometer bias step (a slip that GNSS arbitrates: re-anchor,
    accelerometer declared faulty) and a stuck IMU: the fault-handling branches of the C
    transliteration take the same path as numba."""
    mod = _cref()
    if mod.find_compiler() is None:
        pytest.skip("no C compiler on this machine")
    ref = mod.build(tmp_path / "cache")
    db, packed, line = _packed_run(tmp_path, faults=Faults(odo_slips=((30.0, 34.0, 1.2),)))
    t0 = packed.t_s[0]
    imu = packed.kind == L.M_IMU
    step = imu & (packed.t_s - t0 > 45.0) & (packed.t_s - t0 < 80.0)
    packed.values[step, 0] += 0.3  # accelerometer bias step on f_x
    stuck = np.flatnonzero(imu & (packed.t_s - t0 > 90.0) & (packed.t_s - t0 < 95.0))
    packed.values[stuck] = packed.values[stuck[0]]  # the IMU repeats one sample for 5 s
    cfg = filter_config_for().to_array()
    fa, ia, sa = _run(batch.run_packed, packed, line, cfg)
    fb, ib, sb = _run(ref.run_packed, packed, line, cfg)
    db.close()
    cnt = sa[3]
    assert cnt[L.C_SLIP] >= 2 and cnt[L.C_IMU_STUCK] > 400 and cnt[L.C_IMU_FAULT] >= 1
    np.testing.assert_array_equal(ia, ib)
    np.testing.assert_array_equal(sa[3], sb[3])
    np.testing.assert_array_equal(fb, fa)
    assert np.any(ia[:, 2] & L.R_IMU_STUCK) and np.any(ia[:, 2] & L.R_IMU_FAULT)
    # the bias step is told from a slip by GNSS arbitration (fixes held off while they vote), well
    # before slip_max_s: that branch, too, runs in both
    assert cnt[L.C_GPS_HELD] > 0
    assert fa[np.flatnonzero(ia[:, 2] & L.R_IMU_FAULT)[0], 0] - t0 < 45.0 + 10.0


def test_c_reference_build_reports_a_missing_compiler(tmp_path, monkeypatch):
    mod = _cref()
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.delenv("CC", raising=False)
    with pytest.raises(mod.CReferenceUnavailable, match="no C compiler"):
        mod.build(tmp_path / "cache")


def test_markdown_table_and_doc_block(tmp_path):
    rows = [
        Row(
            "replay",
            "fast replay",
            123456.0,
            "datagrams/s",
            compared="exact 5,000/s",
            target=">= 1,000,000/s",
            met=False,
            note="why and what closes it",
            repeats=3,
        ),
        Row("track", "queries", None, "queries/s", target=">= 20,000/s", note="not run"),
    ]
    md = to_markdown(rows, {"machine": "m", "mode": "quick"})
    assert (
        "| replay | fast replay | 123,456 datagrams/s (3 runs) | exact 5,000/s | "
        ">= 1,000,000/s | **NOT met** |" in md
    )
    assert "| track | queries | not measured |" in md and "NOT measured" in md
    assert "- *replay, fast replay*: why and what closes it" in md
    doc = tmp_path / "performance.md"
    doc.write_text(f"# Title\n\nintro\n\n{DOC_BEGIN}\nold table\n{DOC_END}\n\n## Notes kept\n")
    update_doc(doc, md)
    text = doc.read_text()
    assert "old table" not in text and "intro" in text and "## Notes kept" in text and md in text


def test_bench_quick_writes_a_complete_table(tmp_path):
    doc = tmp_path / "performance.md"
    doc.write_text("# Performance\n")
    out = tmp_path / "out"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "sfa",
            "bench",
            "--quick",
            "--out",
            str(out),
            "--docs",
            str(doc),
            "--scenario",
            "tram-urban",
            "--soak-s",
            "10",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    data = json.loads((out / "bench.json").read_text())
    rows = data["rows"]
    env = data["environment"]
    for key in ("machine", "versions", "commit", "load_start", "load_end", "mode"):
        assert env[key], key
    assert env["mode"] == "quick"
    names = [f"{r['section']}: {r['name']}" for r in rows]

    def find(*words):
        hits = [r for r, n in zip(rows, names, strict=True) if all(w in n for w in words)]
        assert hits, (words, names)
        return hits[0]

    required = [
        ("accuracy", "tram-urban", "p95"),
        ("accuracy", "coverage"),
        ("generalisation", "rtk", "p95"),
        ("generalisation", "long-outage", "coverage"),
        ("generalisation", "field-ring", "p95"),
        ("replay", "filter core alone"),
        ("replay", "C reference"),
        ("replay", "fast replay end to end"),
        ("replay", "naive"),
        ("replay", "exact replay"),
        ("listener", "1x"),
        ("listener", "10x"),
        ("listener", "100x"),
        ("listener", "CPU"),
        ("memory", "RSS"),
        ("track", "vectorised"),
        ("startup", "first output", "empty numba cache"),
        ("startup", "peak RSS"),
    ]
    for words in required:
        row = find(*words)
        # every row is either measured or says why not; a target always comes with met / not met
        assert row["value"] is not None or row["note"], words
        if row["target"] and row["value"] is not None:
            assert row["met"] in (True, False), words
    acc = find("accuracy", "p95")
    assert (
        "odometer only" in acc["compared"] and "raw GPS" in acc["compared"] and "FilterPy" in acc["compared"]
    )
    gen = find("generalisation", "jena-tram", "p95")
    assert "plain FilterPy EKF" in gen["compared"] and "odometer only" in gen["compared"]
    assert "information bound" in gen["compared"]
    fast = find("replay", "fast replay end to end")
    assert "identical to the exact replay: True" in fast["compared"]
    # issue 17's must-show capture: STROBE-dated, with the losses, duplicates and reorderings it repaired
    assert "STROBE-dated" in fast["name"]
    for word in ("lost", "duplicates", "reordered"):
        assert re.search(rf"\b{word} [1-9]", fast["name"]), (word, fast["name"])
    sustained = find("replay", "back to back", "slowest")
    assert len(sustained["samples"]) == 10 and sustained["value"] == pytest.approx(min(sustained["samples"]))
    assert sustained["met"] == (sustained["value"] >= 1e6)
    assert (
        find("replay", "C reference")["value"] is not None
        or "C reference skipped" in find("replay", "C reference")["note"]
    )
    start = find("startup", "first output")
    assert "JIT on an empty cache" in start["compared"] and "JIT on a warm cache" in start["compared"]
    assert "numba cache empty at spawn in every cold start: True" in start["compared"]
    md = (out / "bench.md").read_text()
    assert md.count("\n| ") == len(rows) + 1  # header + one line per row (separator starts with |-)
    text = doc.read_text()
    assert text.startswith("# Performance\n") and DOC_BEGIN in text and DOC_END in text
    assert "| section | figure | value (median)" in proc.stdout or "sfa bench (quick)" in proc.stdout


def test_new_rows_tells_retransmissions_by_content_across_a_seq_wrap():
    from types import SimpleNamespace

    from tools.bench_replay import new_rows

    seq = np.array([65534, 65535, 65535, 0, 1, 65534, 65534], dtype=np.int64)
    epoch = np.array([1.0, 2.0, 2.0, 3.0, 4.0, 5.0, 5.0])
    arc = np.array([10.0, 11.0, 11.0, 12.0, 13.0, 14.0, 14.0])
    res = SimpleNamespace(estimates={"seq": seq, "epoch": epoch, "arc_length": arc})
    # row 2 resends row 1; row 5 reuses SEQ 65534 after the wrap with a new estimate; row 6 resends it
    np.testing.assert_array_equal(new_rows(res), [True, True, False, True, True, True, False])
