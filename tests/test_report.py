"""tools.report: the run report, checked on the figures' data (a screenshot-level check without pixels).

A real run: the simulator's tram-faults scenario (multipath step, standstill) through the listener's
pipeline (tools.replay), with a 10 s GNSS outage made by dropping the GNSS datagrams, the baselines on
the same measurements, and the simulator's events as fault windows.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from interface_modules.offline import generate
from tools.baselines import baseline_estimates
from tools.replay import ReplayOptions, replay_datagrams
from tools.replay_metrics import replay_metrics
from tools.report import (
    FIGURES,
    MAP_MARGIN,
    build_figures,
    fault_windows,
    map_limits,
    nees_verdict,
    replay_report_data,
    write_report,
)
from track_db import TrackDatabase, default_database_path

OUTAGE = (40.0, 50.0)  # seconds after the start: GNSS datagrams dropped


@pytest.fixture(scope="module")
def run():
    sim = generate("tram-faults", max_duration_s=120.0)
    t_start = float(sim.truth["epoch"][0])
    dgrams = [
        (p.arrival_s, ("127.0.0.1", p.src_port), p.payload)
        for p in sim.packets
        if not (p.module == "gps" and OUTAGE[0] <= p.arrival_s - t_start <= OUTAGE[1])
    ]
    track = TrackDatabase.open(str(default_database_path()))
    result = replay_datagrams(dgrams, track, ReplayOptions(record_measurements=True))
    truth = {k: np.asarray(sim.truth[k], dtype=float) for k in ("epoch", "arc_length", "speed", "lat", "lon")}
    metrics = replay_metrics(result, truth)
    baselines = baseline_estimates(track, result.measurements)
    data = replay_report_data(result, metrics, truth, track, baselines, None, sim.events, title="t")
    figures = build_figures(data)
    yield {"sim": sim, "result": result, "truth": truth, "metrics": metrics, "data": data, "figs": figures}
    import matplotlib.pyplot as plt

    for fig in figures.values():
        plt.close(fig)


def _extent(lon, lat):
    ok = np.isfinite(lon) & np.isfinite(lat)
    return lon[ok].min(), lon[ok].max(), lat[ok].min(), lat[ok].max()


def test_every_figure_is_present_with_data(run):
    figs = run["figs"]
    assert tuple(figs) == FIGURES
    for name, fig in figs.items():
        ax = fig.axes[0]
        assert ax.lines or ax.collections, name
        assert ax.get_xlabel() and ax.get_ylabel() or name == "status", name


def test_map_is_zoomed_to_the_run(run):
    """The map's extent is within 20 % of the run's (estimates and true path), not the whole network."""
    ax = run["figs"]["map"].axes[0]
    new = run["result"].new_estimates()
    lon = np.concatenate((new["lon"], run["truth"]["lon"]))
    lat = np.concatenate((new["lat"], run["truth"]["lat"]))
    x0, x1, y0, y1 = _extent(lon, lat)
    assert (x1 - x0) * 111e3 * math.cos(math.radians(y0)) > 200.0  # the train moved: a real extent
    (ax0, ax1), (ay0, ay1) = ax.get_xlim(), ax.get_ylim()
    for lo, hi, a, b in ((x0, x1, ax0, ax1), (y0, y1, ay0, ay1)):
        assert a <= lo and hi <= b  # the whole run is shown
        assert 1.0 <= (b - a) / (hi - lo) <= 1.2, ((b - a) / (hi - lo))
    assert (ax1 - ax0) / (x1 - x0) == pytest.approx(1 + 2 * MAP_MARGIN)
    labels = {line.get_label() for line in ax.lines}
    assert {"estimates", "true path", "GNSS fixes"} <= labels
    track_line = next(line for line in ax.lines if line.get_label().startswith("track line"))
    tx = track_line.get_xdata()
    assert tx.min() < ax0 or tx.max() > ax1  # the line runs beyond the view: it is zoomed, not fitted


def test_map_limits_of_a_train_standing_still_are_not_degenerate():
    (x0, x1), (y0, y1) = map_limits((11.6, 11.6, 50.9, 50.9))
    assert (y1 - y0) * 111_320 == pytest.approx(40.0 * (1 + 2 * MAP_MARGIN))
    assert x1 > x0


def test_error_figure_shades_outages_and_fault_windows(run):
    ax = run["figs"]["error"].axes[0]
    data = run["data"]
    t0 = data.t0
    spans = [p for p in ax.patches]  # axvspan: one patch per outage and per window of non-zero length
    windows = [w for w in data.faults if w[1] > w[0]]
    assert len(spans) == len(data.outages) + len(windows)
    starts = sorted(round(float(p.get_x()), 3) for p in spans)  # axvspan's Rectangle
    expect = sorted([round(a - t0, 3) for a, _ in data.outages] + [round(a - t0, 3) for a, _, _ in windows])
    assert starts == expect
    # the dropped GNSS datagrams are found as an outage covering the 10 s gap
    assert any(a - t0 <= OUTAGE[0] + 1.5 and b - t0 >= OUTAGE[1] - 1.5 for a, b in data.outages)
    assert any(label.startswith("multipath_step") for _, _, label in windows)


def test_held_baseline_is_drawn_as_steps_and_labelled(run):
    ax = run["figs"]["error"].axes[0]
    held = [line for line in ax.lines if "held" in line.get_label()]
    assert len(held) == 1 and held[0].get_label().startswith("GNSS projection")
    assert held[0].get_drawstyle() == "steps-post"
    b = run["data"].baselines["GNSS projection"]
    n_fresh = 1 + int(np.count_nonzero(np.diff(b["arc_length"])))
    assert held[0].get_xdata().size == n_fresh < b["epoch"].size / 5  # the fixes, not every sample
    others = [ln for ln in ax.lines if ln.get_label().endswith(" error") and "held" not in ln.get_label()]
    assert all(line.get_drawstyle() == "default" for line in others)


def test_status_strip_has_the_status_and_the_reasons_seen(run):
    ax = run["figs"]["status"].axes[0]
    labels = [t.get_text() for t in ax.get_yticklabels()]
    assert labels[0] == "status"
    reasons = run["result"].new_reasons()
    assert reasons is not None and np.any(reasons)
    assert "gnss_step" in labels and "standstill" in labels
    assert len(ax.collections) >= len(labels)  # a broken bar per row at least
    status = run["result"].new_estimates()["status"]
    assert np.any(status == 2)  # DEGRADED during the multipath step: drawn orange
    colours = {tuple(np.round(c.get_facecolor()[0][:3], 3)) for c in ax.collections}
    assert (1.0, 0.498, 0.055) in colours  # tab:orange


def test_innovations_show_gating(run):
    ax = run["figs"]["innovations"].axes[0]
    gated = [line for line in ax.lines if "gated" in line.get_label()]
    assert gated and gated[0].get_xdata().size == int(re.search(r"\((\d+)\)", gated[0].get_label()).group(1))


def test_report_html_is_self_contained_with_verdict_and_no_link_in_a_replay(run, tmp_path):
    path = write_report(run["data"], tmp_path)
    page = path.read_text()
    assert page.count('src="data:image/png;base64,') == len(FIGURES)
    assert "<h2>Consistency (NEES): " in page and "<h2>OBCU link</h2>" not in page
    assert '"state": "down"' not in page and "there is no OBCU in a replay" in page
    assert run["result"].metrics["link"]["state"] == "down"  # what the pipeline says, with no acks
    verdict, comment = nees_verdict(run["metrics"])
    assert verdict in page
    for name in FIGURES:
        assert (tmp_path / f"{name}.png").stat().st_size > 5000
    assert "warning:" not in page
    run["data"].link = {"state": "up", "acks": 12}
    run["data"].warnings = ["c.pcap: capture truncated mid-record: skipped the last 20 bytes (1 record)"]
    page = write_report(run["data"], tmp_path / "demo").read_text()
    run["data"].link, run["data"].warnings = None, []
    assert "<h2>OBCU link</h2>" in page and "<td>acks</td><td>12</td>" in page
    assert "warning: c.pcap: capture truncated mid-record: skipped the last 20 bytes" in page


def test_nees_verdicts():
    band = {"nees_band_95": [0.7, 1.3], "nees_samples": 100}
    assert nees_verdict({"nees_mean": 0.25, **band})[0] == "below the band (pessimistic)"
    assert "2 times" in nees_verdict({"nees_mean": 0.25, **band})[1]
    assert nees_verdict({"nees_mean": 1.0, **band})[0] == "inside the band (consistent)"
    assert nees_verdict({"nees_mean": 4.0, **band})[0] == "above the band (optimistic)"
    assert nees_verdict({})[0] == "not computed"


def test_fault_windows_from_simulator_events():
    events = [
        (100.0, "depart", "A"),
        (110.0, "multipath_step", "E +25.0 m N -5.0 m"),
        (125.0, "multipath_end", ""),
        (130.0, "odo_slip", "configured +20.0% until 35.0 s"),  # scenario time: start 100
        (140.0, "odo_slide", "spontaneous -5.0% for 2.5 s"),
        (150.0, "stuck", "odometer"),
        (153.0, "stuck_end", "odometer"),
        (160.0, "restart", "gps"),
        (170.0, "odo_dropout", ""),
        (180.0, "gnss_lost", "silent"),
    ]
    got = fault_windows(events, end_s=200.0, start_epoch_s=100.0)
    assert [(a, b) for a, b, _ in got] == [(110.0, 125.0), (130.0, 135.0), (140.0, 142.5), (150.0, 153.0),
                                           (160.0, 160.0), (180.0, 200.0)]  # fmt: skip
    assert got[0][2] == "multipath_step E +25.0 m N -5.0 m"
