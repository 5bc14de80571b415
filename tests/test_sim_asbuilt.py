"""As-built truth paths and actual sensor errors: the simulator's world differs from the filter's."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from interface_modules.asbuilt import AsBuiltConfig, ReferenceMap, as_built_line, lateral_offset
from interface_modules.errors import ScenarioError
from interface_modules.offline import generate
from interface_modules.presets import GPS_PRESETS
from interface_modules.scenario import actual_spec, load_scenario, scenario_from_dict
from listener.codec import GroundTruth
from track_db import TrackDatabase, default_database_path


@pytest.fixture(scope="module")
def reference():
    db = TrackDatabase.open(default_database_path())
    yield db.line(2)
    db.close()


def test_lateral_offset_has_the_configured_size_and_is_seeded():
    s = np.arange(0.0, 50_000.0, 1.0)
    cfg = AsBuiltConfig(lateral_sigma_m=0.5)
    a = lateral_offset(s, cfg, np.random.default_rng(3))
    b = lateral_offset(s, cfg, np.random.default_rng(3))
    c = lateral_offset(s, cfg, np.random.default_rng(4))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    # a sum of 24 sinusoids of amplitude sigma sqrt(2/24): its RMS over many wavelengths is sigma
    assert 0.4 < float(np.sqrt(np.mean(a * a))) < 0.6
    # smooth: no wavelength below min_wavelength_m, so the slope is at most the sum of the components'
    # amplitudes times 2 pi / min_wavelength_m (a rigorous bound; a shorter wavelength would break it)
    amp = cfg.lateral_sigma_m * np.sqrt(2.0 / cfg.components)
    assert float(np.max(np.abs(np.diff(a)))) <= cfg.components * amp * 2.0 * np.pi / cfg.min_wavelength_m
    short = AsBuiltConfig(lateral_sigma_m=0.5, min_wavelength_m=2.0, max_wavelength_m=2.0)
    assert float(np.max(np.abs(np.diff(lateral_offset(s, short, np.random.default_rng(3)))))) > 0.3


def test_as_built_path_differs_from_the_database_and_maps_back_onto_it(reference):
    built = as_built_line(reference, AsBuiltConfig(), np.random.default_rng(1))
    assert built.line_id == reference.line_id
    s = np.linspace(0.0, built.length_m, 2000)
    e, n = built.point_at(s)
    s_ref, off = reference.project(np.asarray(e), np.asarray(n))
    off = np.asarray(off)
    # metre-class lateral differences, not a copy and not a different line
    assert 0.2 < float(np.sqrt(np.mean(off * off))) < 2.0
    assert float(np.max(np.abs(off))) < 6.0
    # its curvature is not the database's: the gyro sees a different world than the map tells
    k_built = np.asarray(built.curvature_at(s))
    k_ref = np.asarray(reference.curvature_at(np.clip(np.asarray(s_ref), 0.0, reference.length_m)))
    assert float(np.sqrt(np.mean((k_built - k_ref) ** 2))) > 1e-3
    ref_map = ReferenceMap(built, reference)
    mapped = ref_map(s)
    assert np.all(np.diff(mapped) >= 0.0)
    assert abs(float(mapped[-1]) - reference.length_m) < 5.0
    np.testing.assert_allclose(ref_map(ref_map.inverse(mapped[::50])), mapped[::50], atol=1e-6)


def test_as_built_config_rejects_bad_values():
    with pytest.raises(ValueError, match="lateral_sigma_m"):
        AsBuiltConfig(lateral_sigma_m=-1.0)
    with pytest.raises(ValueError, match="max_wavelength_m"):
        AsBuiltConfig(min_wavelength_m=100.0, max_wavelength_m=50.0)


def _scenario_dict(**track_extra):
    sc = load_scenario("tram-urban")
    return {
        "scenario": {"name": "t", "seed": 2},
        "track": {"database": "default", "line_id": 2, **track_extra},
        "journey": {"points": [
            {"name": "a", "s_m": 153.0, "departure_s": 5.0},
            {"name": "b", "s_m": 535.4, "arrival_s": 60.0},
        ]},
        "sensors": {"gps": {"preset": sc.gps.preset,
                            "actual": {"gm_sigma_m": 2.5, "reported_sigma_h_m": 0.8}}},
    }


def test_actual_errors_replace_the_preset_for_the_simulator_only():
    sc = scenario_from_dict(_scenario_dict())
    spec = actual_spec(sc.gps)
    assert spec.gm_sigma_m == 2.5 and spec.reported_sigma_h_m == 0.8
    assert GPS_PRESETS[sc.gps.preset].gm_sigma_m != 2.5  # the preset itself is untouched
    assert actual_spec(sc.imu) is not None
    bad = _scenario_dict()
    bad["sensors"]["gps"]["actual"] = {"no_such_error": 1.0}
    with pytest.raises(ScenarioError, match="no_such_error"):
        scenario_from_dict(bad)
    bad["sensors"]["gps"]["actual"] = {"gm_sigma_m": "big"}
    with pytest.raises(ScenarioError, match="gm_sigma_m"):
        scenario_from_dict(bad)


def test_generated_truth_is_in_the_database_frame_on_the_as_built_path():
    sc = scenario_from_dict(_scenario_dict(as_built={"enabled": True}))
    assert sc.track.as_built.enabled
    run = generate(sc)
    perfect = generate(dataclasses.replace(
        sc, track=dataclasses.replace(sc.track, as_built=AsBuiltConfig(enabled=False))))
    # same driver, different path: the truth differs, the GROUND TRUTH is the truth's first sample
    assert not np.array_equal(run.truth["lat"], perfect.truth["lat"])
    gt = [m for m in run.messages() if isinstance(m, GroundTruth)]
    assert gt and gt[0].arc_length == pytest.approx(float(run.truth["arc_length"][0]), abs=1e-6)
    s = run.truth["arc_length"]
    assert np.all(np.diff(s) >= 0.0) and 100.0 < s[0] < 200.0
    # the same seed gives the same as-built world
    again = generate(sc)
    np.testing.assert_array_equal(again.truth["lat"], run.truth["lat"])
    # the default since session 10: perfect knowledge is the opt-in
    assert scenario_from_dict(_scenario_dict()).track.as_built.enabled
