"""sfa demo: real OBCU, listener and interface-module processes on loopback, with a report."""

import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow


def test_demo_runs_end_to_end(tmp_path):
    out = tmp_path / "demo"
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "sfa",
            "demo",
            "--duration",
            "60",
            "--speed",
            "6",
            "--quiet",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=400,
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "along-track error" in res.stdout and "report:" in res.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["listener_exit_status"] == 0
    acc = summary["accuracy"]
    assert acc["n"] > 3000  # one output per filter update at ~120 updates per simulated second
    assert acc["p95_m"] < 3.0
    m = summary["listener_metrics"]
    assert m["input"]["rejected"] == 0 and m["sequencing"]["lost"] == 0
    assert m["link"]["acks"] > 0
    assert (out / "report.md").exists()
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 5  # the replay's report: error, status, speed, ...
    assert "<h2>OBCU link</h2>" in page and "Consistency (NEES)" in page
    for name in ("capture.pcap", "truth.csv", "map.png", "innovations.png"):
        assert (out / name).stat().st_size > 1000, name
    assert (out / "events.csv").read_text().startswith("epoch,kind,detail\n")
