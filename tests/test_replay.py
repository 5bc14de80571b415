"""sfa replay: capture reading, determinism, outputs, metrics, bad files."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from helpers_capture import frame_ethernet, write_capture
from test_listener_pipeline import _datagrams, _feed, _pipeline

from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from listener.codec import decode_output
from sfa.synthetic import build_track_db, generate
from tools.capture_reader import CaptureStats, read_capture
from tools.errors import CaptureError, ToolError
from tools.replay import ReplayOptions, replay_capture
from tools.replay_metrics import read_truth_csv, replay_metrics
from track_db import TrackDatabase


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    d = tmp_path_factory.mktemp("replay")
    track_path = build_track_db(d / "synthetic.db")
    track = TrackDatabase.open(track_path)
    run = generate(
        track,
        1,
        30.0,
        IMU_PRESETS["mems-train"],
        ODOMETER_PRESETS["wheel-odometer"],
        GPS_PRESETS["standalone"],
        seed=4,
    )
    dgrams = _datagrams(run)
    t0 = 1.7e9  # capture times are POSIX times
    dgrams = [(t0 + t - 1000.0, a, p) for t, a, p in dgrams]
    cap = d / "capture.pcap"
    other = [
        (dgrams[10][0] + 1e-4, frame_ethernet(("127.0.0.1", 5353), 5353, b"mdns")),
        (dgrams[20][0] + 1e-4, b"\x00" * 14),
    ]  # another port; a frame with no IP payload
    write_capture(cap, dgrams, extra=other)
    truth = d / "truth.csv"
    with open(truth, "w") as fh:
        fh.write("epoch,arc_length,speed\n")
        for t, s, v in zip(run.t_s, run.s_m, run.v_mps, strict=True):
            fh.write(f"{float(t)!r},{float(s)!r},{float(v)!r}\n")
    return {
        "dir": d,
        "track_path": track_path,
        "track": track,
        "run": run,
        "dgrams": dgrams,
        "cap": cap,
        "truth": truth,
    }


def test_reader_returns_the_datagrams_and_counts_the_rest(world):
    stats = CaptureStats()
    got = list(read_capture(world["cap"], 48000, stats))
    assert [g.payload for g in got] == [p for _, _, p in world["dgrams"]]
    assert got[0].src == world["dgrams"][0][1]
    assert stats.skipped["other_port"] == 1 and stats.skipped["not_ip"] + stats.skipped["bad_frame"] == 1


def test_pcapng_reads_the_same(world, tmp_path):
    ng = tmp_path / "c.pcapng"
    write_capture(ng, world["dgrams"], pcapng=True)
    a = [(d.time_s, d.payload) for d in read_capture(world["cap"], 48000)]
    b = [(d.time_s, d.payload) for d in read_capture(ng, 48000)]
    assert [p for _, p in a] == [p for _, p in b]
    assert np.allclose([t for t, _ in a], [t for t, _ in b], atol=1e-6)


def test_replay_equals_the_live_pipeline_and_is_deterministic(world):
    opts = ReplayOptions(config=_pipeline(world["track"]).cfg)
    r1 = replay_capture(world["cap"], world["track"], opts)
    r2 = replay_capture(world["cap"], world["track"], opts)
    for k in r1.estimates:
        assert np.array_equal(r1.estimates[k], r2.estimates[k], equal_nan=True), k
    # the same datagrams fed to a pipeline directly (as the daemon does) give the same outputs
    live = [decode_output(o) for o in _feed(_pipeline(world["track"]), world["dgrams"])]
    new = r1.new_estimates()
    assert [m.seq for m in live] == list(new["seq"])
    assert [m.arc_length for m in live] == list(new["arc_length"])
    assert [m.epoch for m in live] == list(new["epoch"])


def test_cli_writes_every_file_and_byte_identical_estimates(world, tmp_path):
    outs = []
    for k in range(2):
        out = tmp_path / f"out{k}"
        subprocess.run(
            [
                sys.executable,
                "-m",
                "sfa",
                "replay",
                str(world["cap"]),
                "--track",
                str(world["track_path"]),
                "--out",
                str(out),
                "--truth",
                str(world["truth"]),
                "--quiet",
            ],
            check=True,
            capture_output=True,
            text=True,
            timeout=300,
        )
        outs.append(out)
    a, b = (o / "estimates.csv" for o in outs)
    assert a.read_bytes() == b.read_bytes()
    header = a.read_text().splitlines()[0].split(",")
    assert header[:2] == ["epoch", "arc_length"]
    m = json.loads((outs[0] / "metrics.json").read_text())
    for key in ("rms_m", "p95_m", "max_m", "messages", "interval_coverage", "nees_mean", "etcs_compliance"):
        assert key in m, key
    assert m["messages"] == len(world["dgrams"])
    assert m["p95_m"] < 2.0
    labels = [r["label"] for r in m["baselines"]]
    assert labels[0] == "sfa" and len(labels) == 4
    html = (outs[0] / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 5  # error, status, speed, innovations, map
    assert "Consistency (NEES)" in html and "<h2>OBCU link</h2>" not in html  # no OBCU in a replay
    pq = pytest.importorskip("pyarrow.parquet")
    table = pq.read_table(outs[0] / "estimates.parquet")
    assert table.column_names == header + ["reasons"]
    rows = a.read_text().splitlines()[1:]
    assert table.column("epoch").to_pylist() == [float(r.split(",")[0]) for r in rows]
    geo = json.loads((outs[0] / "estimates.geojson").read_text())
    assert geo["type"] == "FeatureCollection" and geo["features"][0]["geometry"]["type"] == "LineString"


def test_sweep_table(world, tmp_path):
    out = tmp_path / "sweep"
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "sfa",
            "replay",
            str(world["cap"]),
            "--track",
            str(world["track_path"]),
            "--out",
            str(out),
            "--truth",
            str(world["truth"]),
            "--quiet",
            "--no-report",
            "--no-baselines",
            "--sweep",
            "imu+odo,all",
            "--sweep",
            "gps_white_sigma_m=0.5,2",
            "--jobs",
            "2",
        ],
        check=True,
        capture_output=True,
        text=True,
        timeout=600,
    )
    rows = (out / "sweep.csv").read_text().splitlines()
    assert len(rows) == 1 + 4
    assert "imu+odometer" in rows[1] and "gps_white_sigma_m=0.5" in rows[1]
    assert "sweep: 4 configurations" in res.stdout


def test_metrics_against_truth(world):
    r = replay_capture(world["cap"], world["track"], ReplayOptions())
    truth = read_truth_csv(world["truth"])
    m = replay_metrics(r, truth)
    assert m["compared"] == m["new_estimates"]
    assert 0.0 <= m["interval_coverage"] <= 1.0
    assert m["etcs_compliance"] == 1.0  # errors of ~1 m are far inside 5 m + 5 %
    lo, hi = m["nees_band_95"]
    assert 0 < lo < 1 < hi


@pytest.mark.parametrize(
    "content, message",
    [
        (b"", "not a pcap"),
        (b"this is not a capture at all, just text\n" * 3, "not a pcap"),
    ],
)
def test_bad_capture_files(tmp_path, content, message):
    p = tmp_path / "bad.pcap"
    p.write_bytes(content)
    with pytest.raises(CaptureError, match=message):
        list(read_capture(p, 48000))


def test_truncated_capture_keeps_the_valid_part(world, tmp_path):
    data = world["cap"].read_bytes()
    p = tmp_path / "cut.pcap"
    p.write_bytes(data[: len(data) // 2 + 7])
    stats = CaptureStats()
    got = list(read_capture(p, 48000, stats))
    assert 0 < len(got) < len(world["dgrams"])
    assert stats.skipped["truncated_tail"] == 1
    assert [g.payload for g in got] == [x[2] for x in world["dgrams"][: len(got)]]


@pytest.mark.parametrize("cut", [1, 20, 60])  # inside the body (dpkt returns it short), or the header
def test_truncated_capture_counts_the_skipped_bytes_and_records(world, tmp_path, cut):
    data = world["cap"].read_bytes()
    p = tmp_path / "cut.pcap"
    p.write_bytes(data[:-cut])
    whole, stats = CaptureStats(), CaptureStats()
    n_whole = len(list(read_capture(world["cap"], 48000, whole)))
    got = list(read_capture(p, 48000, stats))
    last_record = 16 + len(frame_ethernet(world["dgrams"][-1][1], 48000, world["dgrams"][-1][2]))
    assert (stats.truncated_records, stats.truncated_bytes) == (1, last_record - cut)
    assert (len(got), stats.frames) == (n_whole - 1, whole.frames - 1)
    assert whole.truncated_records == 0 and whole.truncation_warning(world["cap"]) is None


def test_replay_of_a_truncated_capture_warns_with_the_counts(world, tmp_path):
    data = world["cap"].read_bytes()
    p = tmp_path / "cut.pcap"
    p.write_bytes(data[:-20])
    out = tmp_path / "o"
    args = ["replay", str(p), "--track", str(world["track_path"]), "--out", str(out), "--no-baselines",
            "--no-report", "--quiet"]  # fmt: skip
    res = subprocess.run([sys.executable, "-m", "sfa", *args], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    last_record = 16 + len(frame_ethernet(world["dgrams"][-1][1], 48000, world["dgrams"][-1][2]))
    assert res.stderr.strip().splitlines() == [
        f"sfa replay: compiled path not used (capture: record {len(world['dgrams']) + 1}: truncated record);"
        " ran the exact replay",  # (the exact reader keeps what comes before the damaged record)
        f"sfa replay: warning: {p}: capture truncated mid-record: skipped the last {last_record - 20} bytes"
        f" (1 incomplete record) after {len(world['dgrams']) + 1} complete records",
    ]
    capture = json.loads((out / "metrics.json").read_text())["capture"]
    assert (capture["truncated_records"], capture["truncated_bytes"]) == (1, last_record - 20)


def test_cli_errors_are_one_line(world, tmp_path):
    cases = [
        (["replay", str(tmp_path / "missing.pcap"), "--out", str(tmp_path / "o")], "cannot open"),
        (["replay", str(world["cap"]), "--out", str(tmp_path / "o"), "--port", "9"], "no UDP datagram"),
        (["replay", str(world["cap"]), "--out", str(tmp_path / "o"), "--events", "no.csv"], "--events no"),
        (
            ["replay", str(world["cap"]), "--out", str(tmp_path / "o"), "--track", str(tmp_path / "no.db")],
            "no such file",
        ),
        (
            [
                "replay",
                str(world["cap"]),
                "--track",
                str(world["track_path"]),
                "--out",
                str(tmp_path / "o"),
                "--sweep",
                "warp=1",
            ],
            "not a filter setting",
        ),
    ]
    for args, needle in cases:
        res = subprocess.run(
            [sys.executable, "-m", "sfa", *args], capture_output=True, text=True, timeout=300
        )
        assert res.returncode == 2, (args, res.stderr)
        assert needle in res.stderr
        assert len(res.stderr.strip().splitlines()) == 1, res.stderr


def test_bad_truth_files(tmp_path):
    cases = {
        "no_cols.csv": ("a,b\n1,2\n", "lacks the column"),
        "nan.csv": ("epoch,arc_length,speed\n1,nan,0\n2,1,0\n", "not finite"),
        "order.csv": ("epoch,arc_length,speed\n2,0,0\n1,1,0\n", "ascending"),
        "short.csv": ("epoch,arc_length,speed\n1,0,0\n", "at least two"),
        "text.csv": ("epoch,arc_length,speed\n1,x,0\n2,1,0\n", "bad arc_length"),
    }
    for name, (text, needle) in cases.items():
        p = tmp_path / name
        p.write_text(text)
        with pytest.raises(ToolError, match=needle):
            read_truth_csv(p)


def test_compiled_path_is_the_default_with_the_same_outputs(world, tmp_path):
    """``sfa replay`` runs the compiled path by default, ``--exact`` the per-datagram pipeline, ``--fast``
    is still accepted: the same estimates.csv (every output row, resends included) and Parquet file."""
    outs = {}
    for flag in ("", "--exact", "--fast"):
        out = tmp_path / f"o{flag}"
        res = subprocess.run(
            [sys.executable, "-m", "sfa", "replay", str(world["cap"]), "--track", str(world["track_path"]),
             "--out", str(out), "--quiet", "--no-report", "--no-baselines", *([flag] if flag else [])],
            check=True, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        path = json.loads((out / "metrics.json").read_text())["replay_path"]
        outs[flag] = (out, res, path)
    assert outs[""][2] == outs["--fast"][2] == "fast", outs[""][1].stderr
    assert outs["--exact"][2] == "exact"
    for flag in ("", "--exact", "--fast"):
        out, res, path = outs[flag]
        assert f"replay ({path})" in res.stdout
        assert "compiled path not used" not in res.stderr
        assert (out / "estimates.csv").read_bytes() == (outs["--exact"][0] / "estimates.csv").read_bytes()
    pq = pytest.importorskip("pyarrow.parquet")
    exact = pq.read_table(outs["--exact"][0] / "estimates.parquet")
    assert pq.read_table(outs[""][0] / "estimates.parquet").equals(exact)  # the reason bits too


def test_a_capture_the_compiled_path_declines_says_why_in_one_line(world, tmp_path):
    """A merge hold (the compiled path needs 0): the exact replay runs, and stderr says why, once."""
    out = tmp_path / "held"
    res = subprocess.run(
        [sys.executable, "-m", "sfa", "replay", str(world["cap"]), "--track", str(world["track_path"]),
         "--out", str(out), "--quiet", "--no-report", "--no-baselines", "--set", "merge.hold_s=0.05"],
        check=True, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.stderr.strip().splitlines() == [
        "sfa replay: compiled path not used (merge.hold_s = 0.05 (the fast path needs 0));"
        " ran the exact replay"
    ]
    assert json.loads((out / "metrics.json").read_text())["replay_path"] == "exact"
    assert "replay (exact)" in res.stdout


def test_outputs_after_a_seq_wrap_are_not_taken_for_retransmissions(world):
    from listener.config import LinkConfig, ListenerConfig

    opts = ReplayOptions(config=ListenerConfig(link=LinkConfig(start_seq=65000)))
    r = replay_capture(world["cap"], world["track"], opts)
    seqs = r.estimates["seq"]
    assert 0 in seqs and 65535 in seqs  # crossed the wrap
    assert int(r.estimates["retransmit"].sum()) == r.metrics["link"]["retransmits"]
