"""The ATO seed's driver (interface_modules.ato_driver) and the seed's field ring scenario."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from interface_modules.ato_driver import AtoPidConfig
from interface_modules.capture import write_pcap
from interface_modules.errors import ScenarioError
from interface_modules.journey import build_legs
from interface_modules.motion import DriverConfig, drive
from interface_modules.offline import generate
from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from interface_modules.scenario import load_scenario, scenario_from_dict
from interface_modules.tracks import database_path, open_line
from interface_modules.trains import KMH

DT = 0.01


@pytest.fixture(autouse=True)
def cache_dir(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("SFA_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "sfa-track-cache"))


@pytest.fixture(scope="module")
def ring(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("SFA_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "sfa-track-cache"))
    sc = load_scenario("field-ring")
    line = open_line(sc)
    legs = build_legs(sc, line)
    yield sc, line, legs
    mp.undo()


def tracking(traj, legs):
    """Per leg: speed errors against the LSPB reference at the train's position, and the stop error."""
    out = []
    t_dep = [e[0] for e in traj.events if e[1] == "depart"]
    t_arr = [e[0] for e in traj.events if e[1] == "arrive"]
    assert len(t_dep) == len(t_arr) == len(legs)
    for leg, t0, t1 in zip(legs, t_dep, t_arr, strict=True):
        p = leg.plan
        m = (traj.t_s >= t0 - 1e-9) & (traj.t_s < t1 - 1e-9)
        x = p.direction * (traj.s_m[m] - p.s_start_m)
        err = np.interp(x, p.x_m, p.v_mps) - traj.v_mps[m]
        i_end = int(np.searchsorted(traj.t_s, t1 - 1e-9))
        stop_err = p.direction * (traj.s_m[i_end] - p.s_start_m) - p.length_m
        out.append((err, stop_err))
    return out


def moving_jerk(traj):
    v, a = traj.v_mps, traj.a_mps2
    moving = (v[1:] > 0.05) & (v[:-1] > 0.05)
    return np.abs(np.diff(a) / traj.dt_s)[moving]


def test_pidgs_tracks_the_lspb_reference_within_the_train_limits(ring):
    sc, _line, legs = ring
    assert isinstance(sc.driver, AtoPidConfig)
    spec = sc.train
    traj = drive(spec, legs, dt_s=DT, driver=sc.driver)
    for err, stop_err in tracking(traj, legs):
        assert np.max(np.abs(err)) < 0.5  # m/s, worst moment: the start's traction lag
        assert np.percentile(np.abs(err), 95) < 0.1
        assert abs(stop_err) < 0.1  # m from the stopping point
    # acceleration within the actuators' envelope, jerk within the train's limit while moving (the
    # applied force is slew-limited to M_eff j; the resistances add a little)
    assert traj.a_mps2.max() <= spec.plan_accel_mps2 + 0.05
    assert traj.a_mps2.min() >= -spec.service_brake_mps2 - 0.05
    assert moving_jerk(traj).max() <= spec.jerk_limit_mps3 * 1.02
    assert traj.v_mps.max() <= 40.0 * KMH
    # and it looks like a train: it accelerates and brakes near its planning rates
    assert traj.a_mps2.max() > 0.6 and traj.a_mps2.min() < -0.6


def test_actuator_lag_and_traction_saturation_shape_the_response(ring):
    sc, _line, legs = ring
    spec = sc.train
    quick = drive(spec, legs[:1], dt_s=DT, driver=dataclasses.replace(sc.driver, traction_lag_s=0.01,
                                                                      brake_lag_s=0.01))
    slow = drive(spec, legs[:1], dt_s=DT, driver=sc.driver)
    # the lag delays the start (the train gets the force later)
    t_move = [t.t_s[np.flatnonzero(t.v_mps > 0.5)[0]] for t in (quick, slow)]
    assert t_move[1] > t_move[0] + 0.2
    capped = drive(spec, legs[:1], dt_s=DT, driver=dataclasses.replace(sc.driver, traction_saturation=0.3))
    from interface_modules import dynamics

    a_cap = 0.3 * dynamics.traction_limit_n(spec, 0.0) / spec.effective_mass_kg
    assert capped.a_mps2.max() <= a_cap + 1e-9
    err, stop_err = tracking(capped, legs[:1])[0]
    assert np.max(np.abs(err)) > 1.0  # the seed's field test: a delay while accelerating, saturated
    assert abs(stop_err) < 0.1  # and still stops at the platform
    assert moving_jerk(capped).max() <= spec.jerk_limit_mps3 * 1.02


def test_gains_are_scheduled_on_the_reference_speed(ring):
    sc, _line, legs = ring
    flat = dataclasses.replace(sc.driver, kp_high_per_s=sc.driver.kp_low_per_s,
                               ki_high_per_s2=sc.driver.ki_low_per_s2, kd_high=sc.driver.kd_low)
    a = drive(sc.train, legs[:1], dt_s=DT, driver=sc.driver)
    b = drive(sc.train, legs[:1], dt_s=DT, driver=flat)
    assert a.t_s.size != b.t_s.size or not np.array_equal(a.v_mps, b.v_mps)


def test_the_driver_is_deterministic_the_default_and_the_pi_driver_an_option(ring):
    sc, _line, legs = ring
    a = drive(sc.train, legs, dt_s=DT, driver=sc.driver)
    b = drive(sc.train, legs, dt_s=DT)
    assert np.array_equal(a.s_m, b.s_m) and np.array_equal(a.a_mps2, b.a_mps2) and a.events == b.events
    assert isinstance(load_scenario("tram-urban").driver, AtoPidConfig)
    pi = drive(sc.train, legs, dt_s=DT, driver=DriverConfig())
    n = min(pi.a_mps2.size, a.a_mps2.size)
    assert not np.array_equal(pi.a_mps2[:n], a.a_mps2[:n])


@pytest.mark.parametrize("name", ["tram-urban", "standstill-creep", "regional-tunnel"])
def test_the_seed_driver_drives_every_shipped_train_within_its_limits(name):
    sc = load_scenario(name)
    legs = build_legs(sc, open_line(sc))
    traj = drive(sc.train, legs, dt_s=DT, driver=sc.driver)
    for err, stop_err in tracking(traj, legs):
        assert np.max(np.abs(err)) < 0.7 and np.percentile(np.abs(err), 95) < 0.5
        assert abs(stop_err) < 0.5
    assert moving_jerk(traj).max() <= sc.train.jerk_limit_mps3 * 1.02
    assert traj.a_mps2.min() >= -sc.train.service_brake_mps2 - 0.05


def test_same_seed_gives_byte_identical_field_ring_captures(tmp_path):
    sc = load_scenario("field-ring").with_overrides(max_duration_s=120.0)
    write_pcap(generate(sc, 3), tmp_path / "a.pcap")
    write_pcap(generate(sc, 3), tmp_path / "b.pcap")
    write_pcap(generate(sc, 4), tmp_path / "c.pcap")
    assert (tmp_path / "a.pcap").read_bytes() == (tmp_path / "b.pcap").read_bytes()
    assert (tmp_path / "c.pcap").read_bytes() != (tmp_path / "a.pcap").read_bytes()


def test_field_ring_is_a_closed_5_7_km_ring_with_three_stops_at_40_kmh(ring):
    sc, line, _legs = ring
    assert sc.track.database.startswith("geojson:") and database_path(sc).is_file()
    assert 5600.0 < line.length_m < 5800.0
    lat0, lon0 = line.latlon_at(0.0)
    lat1, lon1 = line.latlon_at(line.length_m)
    gap = np.hypot((lat1 - lat0) * 111_195.0, (lon1 - lon0) * 111_195.0 * np.cos(np.radians(lat0)))
    assert gap < 0.5
    stops = [p for p in sc.journey if p.kind == "stop"]
    assert len({p.name for p in stops}) == 3 and stops[0].name == stops[-1].name
    assert stops[-1].s_m - stops[0].s_m > line.length_m - 50.0  # a complete turn
    assert sc.track.line_speed_kmh <= 40.0
    # mismatch on: as-built truth and actual errors that differ from the presets
    assert sc.track.as_built.enabled
    presets = {"imu": IMU_PRESETS, "odometer": ODOMETER_PRESETS, "gps": GPS_PRESETS}
    for name, table in presets.items():
        module = getattr(sc, name)
        assert module.actual, name
        spec = table[module.preset]
        assert all(getattr(spec, k) != v for k, v in module.actual)


def test_field_ring_run_stops_at_the_platforms_at_most_40_kmh():
    run = generate(load_scenario("field-ring"), 1)
    v = run.truth["speed"]
    assert v.max() <= 40.0 * KMH
    arrivals = [e for e in run.events if e[1] == "arrive"]
    assert [d.split(" stop")[0] for _, _, d in arrivals] == ["Ring B", "Ring C", "Ring A"]
    for _, _, detail in arrivals:
        stop_err = float(detail.split("stop error ")[1].split(" m")[0])
        assert abs(stop_err) < 0.1, detail


def test_driver_table_is_validated():
    base = {
        "track": {"database": "synthetic", "segments": [{"length_m": 1000.0}]},
        "train": {"preset": "tram"},
        "journey": {"points": [{"name": "A", "s_m": 10.0, "departure_s": 1.0}, {"name": "B", "s_m": 900.0}]},
    }
    sc = scenario_from_dict({**base, "driver": {"kind": "ato-pid", "brake_lag_s": 1.2}})
    assert sc.driver == AtoPidConfig(brake_lag_s=1.2)
    assert scenario_from_dict(base).driver == AtoPidConfig()
    pi = scenario_from_dict({**base, "driver": {"kind": "pi", "kp_per_s": 0.8}})
    assert pi.driver == DriverConfig(kp_per_s=0.8)
    with pytest.raises(ScenarioError, match="driver.kind 'mpc' unknown"):
        scenario_from_dict({**base, "driver": {"kind": "mpc"}})
    with pytest.raises(ScenarioError, match="driver.brake_lag_s must be > 0"):
        scenario_from_dict({**base, "driver": {"kind": "ato-pid", "brake_lag_s": 0.0}})
    with pytest.raises(ScenarioError, match="traction_saturation"):
        scenario_from_dict({**base, "driver": {"kind": "ato-pid", "traction_saturation": 1.5}})
    with pytest.raises(ScenarioError, match="kp_per_s"):
        scenario_from_dict({**base, "driver": {"kp_per_s": 1.0}})  # a PI key on the default driver
    # a synthetic run with the seed's driver arrives at its stop
    run = generate(scenario_from_dict({**base, "driver": {"kind": "ato-pid"}}), 1)
    assert any(e[1] == "arrive" for e in run.events)


def test_a_missing_geojson_track_is_a_scenario_error(tmp_path):
    data = {
        "track": {"database": "geojson:no-such.geojson"},
        "journey": {"points": [{"name": "A", "s_m": 10.0, "departure_s": 1.0}, {"name": "B", "s_m": 900.0}]},
    }
    sc = scenario_from_dict(data, base_dir=str(tmp_path))
    with pytest.raises(ScenarioError, match="GeoJSON source .*no-such.geojson.* not found"):
        database_path(sc)
