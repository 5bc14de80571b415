"""Scenario files: the shipped ones load and run on real tracks; bad input gives a clear ScenarioError."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from interface_modules.errors import ScenarioError, SimError
from interface_modules.journey import build_legs
from interface_modules.offline import generate
from interface_modules.scenario import load_scenario, scenario_from_dict, scenario_names
from interface_modules.tracks import database_path, open_line

SHIPPED = [
    "field-ring",
    "regional-long",
    "regional-tunnel",
    "standstill-creep",
    "tram-faults",
    "tram-urban",
    "tram-urban-rtk",
]


@pytest.fixture(autouse=True)
def cache_dir(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("SFA_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "sfa-track-cache"))


def base() -> dict:
    return {
        "scenario": {"name": "t", "seed": 1},
        "track": {"database": "synthetic", "segments": [{"length_m": 1000.0}]},
        "train": {"preset": "tram"},
        "journey": {"points": [{"name": "A", "s_m": 10.0, "departure_s": 1.0}, {"name": "B", "s_m": 900.0}]},
    }


def test_shipped_scenarios_load():
    assert scenario_names() == SHIPPED
    for name in SHIPPED:
        sc = load_scenario(name)
        assert sc.name == name and sc.description
        assert len({m.port for m in sc.modules}) == 4


def test_tram_scenarios_are_realistic_on_the_bundled_network():
    sc = load_scenario("tram-urban")
    stops = [p for p in sc.journey if p.kind == "stop"]
    spacing = np.diff([p.s_m for p in stops])
    assert 300.0 < spacing.mean() < 700.0  # stations every ~500 m
    assert all(20.0 <= p.dwell_s <= 30.0 for p in stops[1:])
    run = generate(sc, max_duration_s=200.0)
    assert run.truth["speed"].max() <= 70 / 3.6
    assert sc.gps.preset == "standalone" and load_scenario("tram-urban-rtk").gps.preset == "rtk"


def test_regional_line_is_built_from_the_shipped_gtfs_extract():
    sc = load_scenario("regional-tunnel")
    path = database_path(sc)
    assert path.is_file() and database_path(sc) == path  # built once, then reused from the cache
    line = open_line(sc)
    assert 100_000.0 < line.length_m < 120_000.0  # E1 Donostia-Bilbao
    tunnel = sc.track.tunnels[0]
    assert tunnel.to_m - tunnel.from_m == pytest.approx(1000.0)
    stops = [p for p in sc.journey if p.kind == "stop"]
    assert stops[0].s_m < tunnel.from_m < tunnel.to_m < stops[-1].s_m


def test_regional_tunnel_run_loses_gnss_in_the_tunnel():
    sc = load_scenario("regional-tunnel")
    run = generate(sc, max_duration_s=560.0)
    kinds = [e[1] for e in run.events]
    assert "tunnel_in" in kinds and "tunnel_out" in kinds
    legs = build_legs(sc, open_line(sc))
    # the E1 is a curvy metre-gauge line: the curve limit keeps this section between 60 and 100 km/h
    v_max = max(leg.plan.v_mps.max() for leg in legs)
    assert 60 / 3.6 < v_max <= 100 / 3.6
    gps = [m for m in run.messages() if type(m).__name__ == "GpsFix"]
    s_of = np.interp([m.epoch for m in gps], run.truth["epoch"], run.truth["arc_length"])
    inside = (s_of >= 35_000.0) & (s_of <= 36_000.0)
    assert inside.any() and all(m.fix_quality == 0 for m, i in zip(gps, inside, strict=True) if i)


def test_long_scenario_lasts_at_least_an_hour():
    sc = load_scenario("regional-long")
    assert sc.journey[-1].arrival_s >= 3600.0


@pytest.mark.parametrize(
    ("patch", "message"),
    [
        (lambda d: d.update(bogus=1), "unknown key bogus"),
        (lambda d: d["scenario"].update(seed="x"), "scenario.seed must be int"),
        (lambda d: d["train"].update(preset="maglev"), "train.preset 'maglev' unknown"),
        (
            lambda d: d.setdefault("sensors", {}).update(imu={"preset": "nope"}),
            "sensors.imu.preset 'nope' unknown",
        ),
        (lambda d: d.setdefault("sensors", {}).update(gps={"port": 47001}), "own source port"),
        (
            lambda d: d.setdefault("sensors", {}).update(imu={"seq_start": 70000}),
            "seq_start must be in 0..65535",
        ),
        (lambda d: d["journey"].update(points=d["journey"]["points"][:1]), "at least two stops"),
        (lambda d: d["journey"]["points"][1].update(kind="teleport"), "kind must be 'stop' or 'pass'"),
        (lambda d: d["journey"]["points"][1].update(s_m=5000.0), "outside the line"),
        (lambda d: d.update(faults=[{"kind": "meteor"}]), "unknown fault kind 'meteor'"),
        (lambda d: d.update(faults=[{"kind": "odo_slip", "start_s": 5.0}]), "needs end_s"),
        (lambda d: d.update(faults=[{"kind": "imu_bias_step", "start_s": 1.0, "axis": "q"}]), "axis must be"),
        (lambda d: d.update(faults=[{"kind": "gnss_outage", "from_m": 9.0, "to_m": 1.0}]), "from_m < to_m"),
        (lambda d: d["track"].update(database="missing.db"), "not found"),
        (lambda d: d["track"].update(tunnels=[{"from_m": 5.0, "to_m": 1.0}]), "from_m < to_m"),
        (
            lambda d: d["train"].update(overrides={"mass_kg": "heavy"}),
            "train.overrides.mass_kg must be float",
        ),
    ],
)
def test_bad_scenarios_are_rejected_with_the_key_named(patch, message):
    data = copy.deepcopy(base())
    patch(data)
    with pytest.raises(SimError, match=message):
        sc = scenario_from_dict(data, base_dir="/nonexistent")
        generate(sc, max_duration_s=1.0)


def test_bad_files(tmp_path):
    with pytest.raises(ScenarioError, match="unknown scenario"):
        load_scenario("no-such-scenario")
    bad = tmp_path / "bad.toml"
    bad.write_text("[scenario\nname=", encoding="utf-8")
    with pytest.raises(ScenarioError, match="not valid TOML"):
        load_scenario(bad)
    with pytest.raises(ScenarioError, match="not found"):
        load_scenario(tmp_path / "missing.toml")


def test_duration_and_seed_overrides():
    sc = scenario_from_dict(base())
    run = generate(sc, seed=5, max_duration_s=12.0)
    assert run.seed == 5 and run.duration_s == pytest.approx(11.99)
    with pytest.raises(SimError, match="seed must be >= 0"):
        generate(sc, seed=-1)
