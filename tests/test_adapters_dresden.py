"""Dresden adapter: deterministic conversion, decodable capture, IMU axes and levelling, GNSS dating
(receiver time tags, separate speed and position latencies), track from its own GPS checked against the
gyro, bad input, and the pipeline's self-consistency on the real log (with a GNSS outage)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from listener.codec import GpsFix, ImuSample, OdometerSample, decode_input
from tools.adapters.common import MODULE_PORTS, read_pcap_udp
from tools.adapters.dresden import (
    COLUMNS,
    KMH,
    DresdenConfig,
    convert_dresden,
    default_source_file,
    estimate_latency_s,
    frd_imu,
    gps_epochs,
    gps_time_tags_s,
    heading_rate_radps,
    lagged_fit,
    levelling,
    position_speed_mps,
    read_dresden,
)
from tools.adapters.evaluate import (
    UPDATE_FIELDS,
    read_truth,
    run_pipeline,
    self_consistency,
    write_updates_csv,
)
from tools.errors import ToolError

SRC = default_source_file()
G = 9.80665


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    return convert_dresden(None, tmp_path_factory.mktemp("dresden"))


@pytest.fixture(scope="module")
def messages(converted):
    return [(ts, port, decode_input(p)) for ts, port, p in read_pcap_udp(converted.capture)]


def test_conversion_is_byte_identical(converted, tmp_path):
    again = convert_dresden(None, tmp_path / "again")
    assert again.capture.read_bytes() == converted.capture.read_bytes()


def test_every_datagram_decodes_with_the_source_counts(messages):
    by_port: dict[int, list] = {}
    for _, port, m in messages:
        by_port.setdefault(port, []).append(m)
    imu, odo, gps = (by_port[MODULE_PORTS[k]] for k in ("imu", "odometer", "gps"))
    assert len(imu) == 10800 and all(isinstance(m, ImuSample) for m in imu)
    assert len(odo) == len(gps) == 2158
    assert all(isinstance(m, OdometerSample) for m in odo) and all(isinstance(m, GpsFix) for m in gps)
    d = read_dresden(SRC)
    g = gps_epochs(d)
    np.testing.assert_allclose([m.speed for m in odo], d["speed"][g] * KMH, rtol=1e-15)
    np.testing.assert_array_equal([m.lat for m in gps], d["latitude"][g])
    np.testing.assert_array_equal([m.sigma_h for m in gps], d["epe"][g])
    np.testing.assert_array_equal([m.epoch for m in imu], d["millis"] / 1000.0)
    ts = np.array([t for t, _, _ in messages])
    assert np.all(np.diff(ts) >= 0.0)


def test_gnss_epochs_are_time_tags_minus_the_estimated_latencies(messages, converted):
    """Speed and positions are dated by the receiver's time tag on the logger clock minus their own
    latency (speed 0.95 s, positions 0.45 s earlier than the speed: measured), sent at their real arrival;
    the recommended merge hold covers the longest wait."""
    meta = json.loads(converted.metadata.read_text())
    tim = meta["real"]["gnss_timing"]
    assert 0.8 <= tim["speed_latency_s"] <= 1.2 and tim["speed_latency_correlation"] > 0.8
    assert 0.8 < tim["speed_latency_slope_f_forward_on_dv_dt"] < 1.2
    assert 0.3 <= tim["position_lead_s"] <= 0.6 and tim["position_lead_correlation"] > 0.95
    pos_lat = tim["position_latency_s"]
    assert pos_lat == pytest.approx(tim["speed_latency_s"] - tim["position_lead_s"], abs=1e-12)
    # the independent check (gyro yaw rate against the GPS heading rate) agrees within 0.15 s
    assert tim["check_gyro_vs_gps_heading_rate"]["lag_s"] == pytest.approx(pos_lat, abs=0.15)
    assert tim["check_gyro_vs_gps_heading_rate"]["correlation"] > 0.6
    d = read_dresden(SRC)
    g = gps_epochs(d)
    tagged = gps_time_tags_s(d["time"][g]) + tim["tag_to_logger_offset_s"]
    odo = [(t, m) for t, port, m in messages if port == MODULE_PORTS["odometer"]]
    gps = [(t, m) for t, port, m in messages if port == MODULE_PORTS["gps"]]
    np.testing.assert_allclose([m.epoch for _, m in odo], tagged - tim["speed_latency_s"], atol=1e-6)
    np.testing.assert_allclose([m.epoch for _, m in gps], tagged - pos_lat, atol=1e-6)
    np.testing.assert_allclose([t for t, _ in gps], d["millis"][g] / 1000.0 + 0.002, atol=1e-6)
    wait = max(max(t - m.epoch for t, m in odo), max(t - m.epoch for t, m in gps))
    assert wait + 0.2 <= meta["recommended_listener"]["merge.hold_s"] + 0.005


def test_the_logger_reads_the_receiver_late_by_a_varying_delay():
    """Why fixes are dated by their time tag and not by when the logger read them: the read delay is
    steady (a 0.24 s sawtooth: the logger's polling phase) except when the logger stalled 96-99 s into
    the drive (20 IMU rows/s instead of 50), after which it read the receiver up to 1.7 s late until it
    caught up."""
    d = read_dresden(SRC)
    g = gps_epochs(d)
    t = d["millis"] / 1000.0
    delay = t[g] - gps_time_tags_s(d["time"][g])
    delay -= np.median(delay)
    rel = t[g] - t[0]
    stall = (rel > 96.0) & (rel < 110.0)
    assert np.ptp(delay[~stall]) < 0.25
    assert delay[stall].max() > 1.5
    rows_97_99 = np.sum((t - t[0] >= 97.0) & (t - t[0] < 99.0))
    assert rows_97_99 < 50  # the stall: ~20 rows/s instead of 50


def test_time_tags_decode_and_wrap_at_midnight():
    tags = gps_time_tags_s(np.array([123825300.0, 235959900.0, 100.0]))
    np.testing.assert_allclose(tags, [12 * 3600 + 38 * 60 + 25.3, 86399.9, 86400.1])


def test_frd_mapping_of_the_logger_axes():
    d = {c: np.array([0.0]) for c in COLUMNS}
    d.update(ax=np.array([1.0]), ay=np.array([2.0]), az=np.array([3.0]),
             rollrate=np.array([10.0]), pitchrate=np.array([20.0]), yawrate=np.array([30.0]))
    f, w = frd_imu(d)
    np.testing.assert_array_equal(f[0], [-1.0, 2.0, 3.0])
    np.testing.assert_allclose(w[0], np.radians([10.0, -20.0, -30.0]))


def test_frd_mapping_agrees_with_the_log_itself():
    """The evidence the mapping rests on: gravity on -z, -ax follows d(speed)/dt, and the integral of
    the FRD yaw rate turns the same way as the GPS track (clockwise positive)."""
    d = read_dresden(SRC)
    f, w = frd_imu(d)
    assert f[:, 2].mean() == pytest.approx(-9.6, abs=0.2)
    t = d["millis"] / 1000.0
    g = gps_epochs(d)
    lag, corr, slope = estimate_latency_s(t, f[:, 0], t[g], d["speed"][g] * KMH)
    assert corr > 0.8 and 0.8 < slope < 1.2
    yaw_turn_deg = math.degrees(np.sum(0.5 * (w[1:, 2] + w[:-1, 2]) * np.diff(t)))
    assert yaw_turn_deg == pytest.approx(177.0, abs=5.0)  # GPS heading turns +181 deg over the drive


def test_levelled_axes_agree_with_the_motion():
    """After levelling: f_x follows d(speed)/dt with slope 1 (m/s^2, not g), f_y follows +v * gz (the
    centripetal force points right in a right turn: FRD), and gz follows the clockwise heading rate of
    the GPS positions (deg/s converted to rad/s: a rad/s column would be 57 times too large)."""
    d = read_dresden(SRC)
    f, w = frd_imu(d)
    _, _, rot = levelling(f.mean(axis=0))
    f, w = f @ rot.T, w @ rot.T
    t = d["millis"] / 1000.0
    g = gps_epochs(d)
    tg = gps_time_tags_s(d["time"][g])
    tg = tg - tg[0] + t[g][0]
    v = d["speed"][g] * KMH
    lag, corr, slope = estimate_latency_s(t, f[:, 0], tg, v)
    assert corr > 0.8 and 0.9 < slope < 1.1
    vt = np.interp(t, tg - lag, v)
    moving = vt > 3.0
    k = np.polyfit(vt[moving] * w[moving, 2], f[moving, 1], 1)[0]
    assert 0.7 < k < 1.1
    from track_db.geodesy import LocalFrame, centred_proj_string

    frame = LocalFrame.from_proj(centred_proj_string(d["latitude"][g], d["longitude"][g]))
    e, n = (np.asarray(a) for a in frame.to_local(d["latitude"][g], d["longitude"][g]))
    lag_h, corr_h, slope_h = lagged_fit(t, w[:, 2], tg, heading_rate_radps(tg, e, n, v))
    assert corr_h > 0.6 and 0.5 < slope_h < 1.2 and 0.0 <= lag_h < 1.5


@given(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(9.0, 10.5))
def test_levelling_recovers_roll_and_pitch(roll, pitch, g):
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    f = np.array([g * sp, -g * sr * cp, -g * cr * cp])  # specific force at rest, tilted sensor
    r, p, rot = levelling(f)
    assert r == pytest.approx(roll, abs=1e-9) and p == pytest.approx(pitch, abs=1e-9)
    np.testing.assert_allclose(rot @ f, [0.0, 0.0, -g], atol=1e-9)
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)


def test_levelled_imu_has_level_mean_specific_force(messages):
    f = np.array([[m.ax, m.ay, m.az] for _, port, m in messages if port == MODULE_PORTS["imu"]])
    mean = f.mean(axis=0)
    assert abs(mean[0]) < 1e-9 and abs(mean[1]) < 1e-9 and mean[2] == pytest.approx(-9.78, abs=0.05)


def test_latency_estimate_recovers_a_known_delay():
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 200.0, 0.02)
    accel = np.convolve(rng.normal(0.0, 10.0, t.size), np.ones(100) / 100, mode="same")  # ~1 m/s^2
    speed_true = np.cumsum(accel) * 0.02 + 5.0
    ts = np.arange(0.0, 200.0, 0.1)
    speed_logged = np.interp(ts - 0.8, t, speed_true)  # the logger records a 0.8 s old speed
    lag, corr, slope = estimate_latency_s(t, accel + rng.normal(0.0, 0.3, t.size), ts, speed_logged)
    assert lag == pytest.approx(0.8, abs=0.051)
    assert corr > 0.9 and slope == pytest.approx(1.0, abs=0.1)


def test_position_lead_estimate_recovers_a_known_delay():
    """Speed logged 0.45 s after the positions it belongs to: lagged_fit on the positions' own speed
    finds the lag."""
    rng = np.random.default_rng(11)
    t = np.arange(0.0, 120.0, 0.1)
    v = 8.0 + 4.0 * np.sin(t / 7.0) + np.convolve(rng.normal(0.0, 1.0, t.size), np.ones(20) / 20, "same")
    s = np.cumsum(v) * 0.1
    e, n = s * 0.6 + rng.normal(0.0, 0.3, t.size), s * 0.8 + rng.normal(0.0, 0.3, t.size)
    speed_logged = np.interp(t - 0.45, t, v)
    lag, corr, slope = lagged_fit(t, position_speed_mps(t, e, n), t, speed_logged)
    assert lag == pytest.approx(0.45, abs=0.051)
    assert corr > 0.95 and slope == pytest.approx(1.0, abs=0.05)


def test_track_curvature_agrees_with_the_gyro(messages, converted):
    """The digitised track's curvature k(s) at the fixes' arc lengths, times the speed, against the FRD
    yaw rate of every IMU sample while moving (> 2 m/s): same sign and scale. Measured: correlation 0.80,
    slope 0.88, residual rms 5.4 deg/s (street corners are sharper than a GPS track can show); with the
    20 m railway smoothing of track_db the correlation was 0.56 and the rms 7.3 deg/s."""
    from sfa.track_arrays import TrackArrays
    from track_db import TrackDatabase

    with TrackDatabase.open(converted.track) as db:
        ta = TrackArrays.from_line(db.line())
    ref = read_truth(converted.out_dir / "gnss_on_track.csv")
    imu = np.array([(m.epoch, m.gz) for _, port, m in messages if port == MODULE_PORTS["imu"]])
    odo = np.array([(m.epoch, m.speed) for _, port, m in messages if port == MODULE_PORTS["odometer"]])
    s = np.interp(imu[:, 0], ref["epoch"], ref["arc_length"])
    v = np.interp(imu[:, 0], odo[:, 0], odo[:, 1])
    vk = v * np.interp(s, ta.s_m, ta.curvature_inv_m)
    moving = v > 2.0
    assert np.corrcoef(vk[moving], imu[moving, 1])[0, 1] > 0.75
    assert 0.8 < np.polyfit(vk[moving], imu[moving, 1], 1)[0] < 1.1
    assert math.degrees(math.sqrt(np.mean((imu[moving, 1] - vk[moving]) ** 2))) < 6.0


def test_track_follows_its_gps(converted):
    from track_db import TrackDatabase

    ref = read_truth(converted.out_dir / "gnss_on_track.csv")
    assert np.percentile(np.abs(ref["cross_track"]), 95) < 1.5
    with TrackDatabase.open(converted.track) as db:
        assert db.junctions() == []
        line = db.line()
        assert np.all(line.grade_at(line.s_m) == 0.0)  # level: no altitude from GPS
        assert ref["arc_length"][-1] == pytest.approx(line.length_m, abs=5.0)


def test_bad_input_is_a_clear_error(tmp_path):
    with pytest.raises(ToolError, match="source file not found"):
        convert_dresden(tmp_path / "none.csv", tmp_path / "o")
    lines = SRC.read_text().splitlines()
    bad = tmp_path / "missing.csv"
    bad.write_text(lines[0].replace(",yawrate", "") + "\n")
    with pytest.raises(ToolError, match="missing column\\(s\\) yawrate"):
        read_dresden(bad)
    cells = lines[5].split(",")
    cells[3] = "x"
    bad.write_text("\n".join([*lines[:5], ",".join(cells), *lines[6:20]]) + "\n")
    with pytest.raises(ToolError, match=r"missing.csv:6: column 'ax' is not a number"):
        read_dresden(bad)
    bad.write_text("\n".join([lines[0], lines[3], lines[2]]) + "\n")
    with pytest.raises(ToolError, match=r"missing.csv:3: millis does not increase"):
        read_dresden(bad)
    with pytest.raises(ToolError, match="speed_sigma_mps"):
        DresdenConfig(speed_sigma_mps=0.0)
    with pytest.raises(ToolError, match="position_lead_s"):
        DresdenConfig(position_lead_s=-0.1)
    with pytest.raises(ToolError, match="track_smoothing_sigma_m"):
        DresdenConfig(track_smoothing_sigma_m=0.0)


@pytest.fixture(scope="module")
def short_log(tmp_path_factory):
    """The first 60 s of the drive (3000 rows), with one GNSS epoch whose time tag goes backwards."""
    lines = SRC.read_text().splitlines()
    head, rows = lines[0], lines[1:3001]
    cols = head.split(",")
    ti = cols.index("time")
    d = read_dresden(SRC)
    g = gps_epochs(d)
    k = int(g[100])  # data row of the 101st epoch: its tag is set 1 s back (rows of the same epoch too)
    tag = rows[k].split(",")[ti]
    back = str(int(tag) - 1000)
    for j in range(k, int(g[101])):
        cells = rows[j].split(",")
        cells[ti] = back
        rows[j] = ",".join(cells)
    path = tmp_path_factory.mktemp("short") / "short.csv"
    path.write_text("\n".join([head, *rows]) + "\n")
    return path


def test_out_of_order_time_tags_are_dropped_and_counted(short_log, tmp_path):
    conv = convert_dresden(short_log, tmp_path / "o")
    meta = json.loads(conv.metadata.read_text())
    assert meta["real"]["gnss_timing"]["epochs_dropped_out_of_order"] == 1
    d = read_dresden(short_log)
    assert conv.by_module["gps"] == conv.by_module["odometer"] == gps_epochs(d).size - 1


def test_gnss_outage_is_withheld_and_measured(short_log, tmp_path):
    """--eval-gps-gap with --eval-gap-odometer: the fixes and speeds dated inside the window never reach
    the filter (counted), and the residual against the withheld fixes is reported apart; updates.csv
    has one row per processed measurement."""
    from dataclasses import replace

    from listener.config import ListenerConfig

    conv = convert_dresden(short_log, tmp_path / "o")
    meta = json.loads(conv.metadata.read_text())
    ref = read_truth(conv.out_dir / "gnss_on_track.csv")
    gap = (float(ref["epoch"][0]) + 20.0, float(ref["epoch"][0]) + 30.0)
    cfg = ListenerConfig()
    cfg = replace(cfg, merge=replace(cfg.merge, hold_s=meta["recommended_listener"]["merge.hold_s"]))
    ports = frozenset({MODULE_PORTS["gps"], MODULE_PORTS["odometer"]})
    result = run_pipeline(conv.capture, conv.track, cfg, gps_gap=gap, gap_ports=ports)
    in_gap = int(np.sum((ref["epoch"] >= gap[0]) & (ref["epoch"] < gap[1])))
    odo_epochs = np.array([decode_input(p).epoch for _, port, p in read_pcap_udp(conv.capture)
                           if port == MODULE_PORTS["odometer"]])
    odo_in_gap = int(np.sum((odo_epochs >= gap[0]) & (odo_epochs < gap[1])))
    assert in_gap > 90 and odo_in_gap > 90
    assert result["gps_withheld"] == in_gap + odo_in_gap
    out = result["metrics"]["filter"]["outcomes"]
    gps_seen = sum(v for k, v in out.items() if k.startswith("gps_"))
    odo_seen = sum(v for k, v in out.items() if k.startswith("odo_"))
    assert gps_seen == conv.by_module["gps"] - in_gap
    assert odo_seen == conv.by_module["odometer"] - odo_in_gap
    fig = self_consistency(result["estimates"], ref, gap)
    assert fig["gap_fixes"] == in_gap
    assert 0.0 <= fig["gap_residual_p50_m"] <= fig["gap_residual_p95_m"] <= fig["gap_residual_max_m"]
    n = write_updates_csv(tmp_path / "updates.csv", result["updates"])
    lines = (tmp_path / "updates.csv").read_text().splitlines()
    assert lines[0].split(",") == list(UPDATE_FIELDS) and len(lines) == n + 1
    kinds = {ln.split(",")[1] for ln in lines[1:]}
    assert kinds == {"init", "imu", "odo", "gps"}


def test_pipeline_takes_every_datagram_of_the_real_log(converted):
    """The listener pipeline over the whole log: nothing rejected by the codec, every measurement dated
    by its epoch and processed (the merge waits out the GNSS latency, so no GNSS fix is late), every IMU
    sample accepted, one estimate at least per GNSS epoch over the whole drive, all finite, and the
    self-consistency figures computable. The figures themselves are reported in docs/real-data.md, not
    bounded here: they depend on the filter's car-unrelated (train) tuning, which is being developed."""
    from dataclasses import replace

    from listener.config import ListenerConfig

    meta = json.loads(converted.metadata.read_text())
    cfg = ListenerConfig()
    cfg = replace(cfg, merge=replace(cfg.merge, hold_s=meta["recommended_listener"]["merge.hold_s"]))
    result = run_pipeline(converted.capture, converted.track, cfg)
    inp = result["metrics"]["input"]
    assert inp["rejected_by_reason"] == {} and inp.get("rejected", 0) == 0
    assert inp["dated_by_epoch"] == inp["processed"] == 10800 + 2158 + 2158 + 1
    out = result["metrics"]["filter"]["outcomes"]
    assert out["imu_accepted"] == 10800
    assert not any(k.endswith("_late") for k in out)
    est = result["estimates"]
    assert est["epoch"].size > 2158
    assert all(np.all(np.isfinite(v)) for v in est.values())
    ref = read_truth(converted.out_dir / "gnss_on_track.csv")
    assert est["epoch"][0] <= ref["epoch"][0] + 0.2 and est["epoch"][-1] >= ref["epoch"][-1] - 0.2
    fig = self_consistency(est, ref)
    assert fig["fixes"] >= ref["epoch"].size - 1  # the last fix may lie just past the last estimate
    assert np.isfinite(fig["along_track_residual_p95_m"])


def test_the_listener_does_not_publish_the_estimates_that_leave_the_line(converted):
    """With its plausibility stage (the listener's default) the estimates that the model-matched train
    tuning puts off the car's line (docs/real-data.md, run A: p95 3 km) are not sent: every published
    arc length lies within the line plus arc_margin_m, and every withheld one is counted as a warning
    (off the line, or an implausible step: a relocalisation's jump back towards the fixes is withheld
    until the speed bound admits it). The default datasheet presets keep the estimate on the line:
    nothing is withheld."""
    from dataclasses import replace

    from listener.config import ListenerConfig, PlausibilityConfig
    from track_db import TrackDatabase

    meta = json.loads(converted.metadata.read_text())
    length = TrackDatabase.open(converted.track).lines()[0].length_m
    margin = PlausibilityConfig().arc_margin_m
    withheld, jumps = {}, {}
    for presets in ("model-matched", "datasheet"):
        cfg = ListenerConfig()
        cfg = replace(cfg, merge=replace(cfg.merge, hold_s=meta["recommended_listener"]["merge.hold_s"]),
                      filter=replace(cfg.filter, presets=presets))
        vetted = run_pipeline(converted.capture, converted.track, cfg, vet_outputs=True)
        arc = vetted["estimates"]["arc_length"]
        assert arc.size > 0 and np.all((arc >= -margin) & (arc <= length + margin)), presets
        res = vetted["metrics"]["resilience"]
        withheld[presets] = res["outputs_not_sent"]["arc_off_line"]
        jumps[presets] = res["outputs_not_sent"]["arc_implausible_step"]
        assert res["warnings"].get("output_implausible", 0) == withheld[presets] + jumps[presets], presets
    assert withheld["model-matched"] > 1000
    assert withheld["datasheet"] == jumps["datasheet"] == 0


def test_a_weak_latency_estimate_is_refused_unless_given(short_log, tmp_path):
    """The latency estimates are trusted only above min_latency_correlation (0.7 by default; the first
    60 s of the drive reach 0.79 for the speed, 0.997 for the position lead): below it the conversion
    stops with an error naming the option, and given values are used as they are."""
    with pytest.raises(ToolError, match="speed latency cannot be estimated .* --latency"):
        convert_dresden(short_log, tmp_path / "a", DresdenConfig(min_latency_correlation=0.99))
    conv = convert_dresden(short_log, tmp_path / "b", DresdenConfig(
        min_latency_correlation=0.99, gnss_latency_s=0.95, position_lead_s=0.45))
    tim = json.loads(conv.metadata.read_text())["real"]["gnss_timing"]
    assert tim["speed_latency_s"] == 0.95 and not tim["speed_latency_estimated"]
    assert tim["position_latency_s"] == pytest.approx(0.50) and not tim["position_lead_estimated"]


def test_the_datasheet_filter_does_not_diverge_on_the_real_drive(converted):
    """The issue's real-data target for Dresden: no divergence, p95 of the estimate against the GNSS
    fixes on the track <= 10 m, with the datasheet presets (sfa.presets.datasheet_config_for: nothing
    fitted to this log) and use_gyro off as they set it. It was 116.8 m (session 8: a false GNSS ramp
    hold-off and a declared odometer slip at once left the accelerometer bridging alone, and after the
    slip's widening every fix past a bend was gated); 4.3 m after the iterated GNSS update, one aid out at
    a time and the non-latching slip arbitration (docs/filter.md)."""
    from dataclasses import replace

    from listener.config import ListenerConfig
    from sfa.presets import datasheet_config_for

    meta = json.loads(converted.metadata.read_text())
    cfg = ListenerConfig()
    cfg = replace(cfg, merge=replace(cfg.merge, hold_s=meta["recommended_listener"]["merge.hold_s"]))
    result = run_pipeline(converted.capture, converted.track, cfg, filter_config=datasheet_config_for())
    fig = self_consistency(result["estimates"], read_truth(converted.out_dir / "gnss_on_track.csv"))
    assert fig["along_track_residual_p95_m"] <= 10.0, fig
