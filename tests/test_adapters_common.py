"""Shared adapter blocks: GNSS error process, thinning, local projection, datagram timeline, pcap."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from listener.codec import OdometerSample, Stop, Strobe, decode_input
from tools.adapters.common import (
    GnssNoise,
    ScheduleConfig,
    Timeline,
    add_control,
    gnss_errors_m,
    prepare_out_dir,
    project_along,
    read_pcap_udp,
    thin_by_spacing,
    write_pcap,
)
from tools.errors import ToolError


def test_gnss_error_process_has_the_documented_statistics():
    """Long series: per-axis variance white^2 + gm^2, and the variance of 1 s differences
    2 white^2 + 2 gm^2 (1 - exp(-1/tau)) of a first-order Gauss-Markov plus white process."""
    noise = GnssNoise(white_sigma_m=0.5, gm_sigma_m=1.0, gm_tau_s=30.0, vertical_sigma_m=3.0)
    t = np.arange(0.0, 400_000.0, 1.0)
    err = gnss_errors_m(noise, t, np.random.default_rng(3))
    var = 0.5**2 + 1.0**2
    np.testing.assert_allclose(err[:, :2].var(axis=0), var, rtol=0.05)
    dvar = 2 * 0.5**2 + 2 * 1.0**2 * (1 - math.exp(-1.0 / 30.0))
    np.testing.assert_allclose(np.diff(err[:, :2], axis=0).var(axis=0), dvar, rtol=0.03)
    assert err[:, 2].std() == pytest.approx(3.0, rel=0.02)
    again = gnss_errors_m(noise, t[:100], np.random.default_rng(3))
    np.testing.assert_array_equal(again, err[:100])  # seeded: same seed, same errors


@given(st.lists(st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3)), min_size=2, max_size=60),
       st.floats(0.1, 20.0))
def test_thinning_keeps_ends_and_spacing(points, spacing):
    p = np.array(points)
    keep = thin_by_spacing(p[:, 0], p[:, 1], spacing)
    assert keep[0] == 0 and keep[-1] == p.shape[0] - 1
    assert np.all(np.diff(keep) > 0)
    d = np.hypot(np.diff(p[keep, 0]), np.diff(p[keep, 1]))
    assert np.all(d[:-1] >= spacing)  # the last vertex is kept whatever its distance
    if keep.size > 2:
        assert d[-1] >= 0.5 * spacing


def test_local_projection_picks_the_pass_it_is_told():
    """A line that drives a street out and back 1 m apart: a point on the return pass projects onto
    the return pass when hinted there, although the outbound pass is as near."""
    e = np.array([0.0, 100.0, 100.0, 0.0])
    n = np.array([0.0, 0.0, 1.0, 1.0])
    s = np.array([0.0, 100.0, 101.0, 201.0])
    pe, pn = np.array([30.0, 30.0]), np.array([0.5, 0.5])
    s_out, d = project_along(s, e, n, pe, pn, np.array([0, 2]), window=0)
    np.testing.assert_allclose(s_out, [30.0, 171.0])
    np.testing.assert_allclose(d, [0.5, 0.5])
    # exact on the line: project(point_at(s)) == s
    s_on, d_on = project_along(s, e, n, np.array([55.0, 100.0]), np.array([0.0, 0.25]), np.array([1, 1]))
    np.testing.assert_allclose(s_on, [55.0, 100.25])
    np.testing.assert_allclose(d_on, 0.0, atol=1e-12)


def test_timeline_orders_packets_and_numbers_each_module(tmp_path):
    tl = Timeline(ScheduleConfig(transport_delay_s=0.01, host_clock_offset_s=2.0))
    add_control(tl, 0.0, 2.5, lambda seq: OdometerSample(seq, 1.0, 0.1, 0.0))  # any message as "truth"
    for k in range(70000):  # wraps the 16-bit sequence number
        tl.add("odometer", k * 1e-4, lambda seq, k=k: OdometerSample(seq, 1.0, 0.1, k * 1e-4))
    packets = tl.packets()
    assert [p.arrival_s for p in packets] == sorted(p.arrival_s for p in packets)
    assert packets[0].arrival_s == pytest.approx(-0.1 + 2.01)  # GROUND TRUTH leads by 0.1 s
    odo = [decode_input(p.payload).seq for p in packets if p.module == "odometer"]
    assert odo[:3] == [0, 1, 2] and odo[65535] == 65535 and odo[65536] == 0
    ctrl = [decode_input(p.payload) for p in packets if p.module == "control"]
    assert [m.timestamp for m in ctrl if isinstance(m, Strobe)] == [0.0, 1.0, 2.0]
    assert isinstance(ctrl[-1], Stop)
    path = tmp_path / "c.pcap"
    assert write_pcap(packets[:50], path, 48000) == 50
    back = read_pcap_udp(path)
    assert [b[2] for b in back] == [p.payload for p in packets[:50]]
    assert [b[1] for b in back] == [p.src_port for p in packets[:50]]
    np.testing.assert_allclose([b[0] for b in back], [p.arrival_s for p in packets[:50]], atol=1e-6)


def test_negative_capture_time_and_bad_configs_are_refused():
    tl = Timeline(ScheduleConfig())
    add_control(tl, 0.0, 1.0, lambda seq: OdometerSample(seq, 1.0, 0.1, 0.0))
    with pytest.raises(ToolError, match="negative"):
        tl.packets()
    with pytest.raises(ToolError, match="strobe_interval_s"):
        ScheduleConfig(strobe_interval_s=0.0)
    with pytest.raises(ToolError, match="gm_tau_s"):
        GnssNoise(gm_tau_s=-1.0)
    with pytest.raises(ToolError, match="unknown GPS preset"):
        GnssNoise.from_preset("nope")


def test_unreadable_capture_and_occupied_output(tmp_path):
    from tools.errors import CaptureError

    bad = tmp_path / "x.pcap"
    bad.write_bytes(b"not a pcap at all")
    with pytest.raises(CaptureError, match="cannot read capture"):
        read_pcap_udp(bad)
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "capture.pcap").write_bytes(b"")
    with pytest.raises(ToolError, match="already holds capture.pcap"):
        prepare_out_dir(tmp_path / "out", ["capture.pcap", "track.db"], overwrite=False)
    prepare_out_dir(tmp_path / "out", ["capture.pcap"], overwrite=True)
    assert not (tmp_path / "out" / "capture.pcap").exists()
