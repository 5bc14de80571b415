"""Golden hashes of today's exact-replay outputs (issue 17: pinned before the engine moves).

Four captures from shipped scenarios (the simulator is seeded, so each capture is the same bytes on
every machine): the Jena tram with epochs; the same with its measurements STROBE-dated (no epoch, the
thesis's form) and 1 % loss, 1 % duplicates and 1 % adjacent swaps; the E1 regional line; the tram
with its scripted sensor faults. Each is replayed by the exact path with the listener's defaults and
the scenario's presets. A test fails with the capture's hash when the simulator changed (not the
replay), with the outputs' hash when the replay did: a change of either must be explained in the
commit that updates the pinned value.

Each capture is pinned with both preset families: "datasheet" (the listener's default since session
10) and "model-matched" (the simulator's own sensor settings, the default before it).

Re-pinned (outputs only, captures unchanged) since:
- the model-matched presets' curvature registration (sfa.presets.filter_config_for, PROFILE_STEP_M /
  sqrt(12));
- the GNSS update's iterated linearisation in the arc length (sfa.kernels.step_gps, GPS_IEKF_ITERATIONS;
  with it set to 0 all four outputs hash to their previous values: the session's other GNSS/slip changes
  do not touch these captures).
- session 10, captures and outputs: the shipped scenarios run on their as-built path by default
  (interface_modules.asbuilt, ``enabled = True``; the driver plans on the reference line's curvature,
  offline._PlanningView). The outputs' hashes of the perfect-knowledge captures, for the record (the
  model-matched ones unchanged since the IEKF; datasheet added with the preset switch): tram-urban
  ee7612c8.. / 14b8725b.., tram-urban-strobe-lossy 48479e00.. / b16ca5bf.., regional-tunnel
  b8276fce.. / c7718a61.., tram-faults a4833396.. / d48ee68e...
- session 11, regional-tunnel capture and outputs: on a fresh machine the capture differed from the
  pinned 02f10b76.. (outputs 8478c7d4.. / 65bd3aed..) on unchanged code, the tram captures did not, and
  older shapely, scipy, numpy and numba releases gave the same new capture. Its E1 database is built
  from the GTFS feed into a cache that was keyed on the feed alone, so the likely cause is a database
  built before a track_db change and reused where the value was pinned. The cache key now includes
  the builder's sources (interface_modules.tracks.builder_digest); the values are re-pinned from a
  fresh build (the same before and after that change; the three tram captures did not change).
- Session 12: the four ``datasheet`` hashes re-pinned after the adaptive GNSS model gained a 100 s
  lag (``sfa.layout.AD_LAGS_S``; docs/filter.md, "Adaptive GNSS error model"): a correlation time
  up to the 120 s the mismatch families draw is now identifiable. The model-matched hashes (a fixed
  GNSS model) did not change, and solution separation (off by default) changes none.
- Session 18: the four ``datasheet`` hashes re-pinned after the map's lateral error became correlated
  along the track in a fix's R (``track_lateral_corr_length_m`` = 40 m in ``datasheet_config_for``;
  ``sfa.kernels.lateral_variance``). The model-matched hashes (length 0) did not change; the previous
  datasheet outputs: tram-urban a7ff3926.., tram-urban-strobe-lossy 9f97eee4.., regional-tunnel
  db96e126.., tram-faults 75b76e8a...
"""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest

from interface_modules.capture import datagrams_of, lossy, strobe_dated
from interface_modules.offline import generate
from interface_modules.scenario import load_scenario
from interface_modules.tracks import database_path
from listener.config import FilterSelection, ListenerConfig
from tools.replay import ReplayOptions, replay_datagrams
from track_db import TrackDatabase

#: capture name -> (sha256 of the capture's datagrams, {preset family: sha256 of the replay's new estimates})
GOLDEN = {
    "tram-urban": ("d00971dbd998bcc4f60608d307515912d7c6b8fc0bf74cdd4079ad5eb9e1461e", {
        "model-matched": "8752159fd1370dc8c29bd0778cf13d9a0aac5814661c750d8e2d0b7b93b02397",
        "datasheet": "3ebde27519122450e4ba2629ff1e6d94708c3e8c8b23ccb38b332b83de75a7e3"}),
    "tram-urban-strobe-lossy": ("4cc40b9aa5efad4d4a7a3ff50f41dd6e26df0daeadc884b0979c8063b84654b0", {
        "model-matched": "b752846dccdc3a9d930ffc2d04f65120b919d18fa407cc1eb0ee2964b5128aeb",
        "datasheet": "a3bde384dd48c489b4c6002e96c1a07ce6b22840b06b398f2b4d3968e579e020"}),
    "regional-tunnel": ("acd48cd640dc2305c2c6a535e31b552968e7c2ef8bf61512fbb7c15fa8530ba2", {
        "model-matched": "5b801593ca66d7f513f84095f7030af64eb391237dd5947282d02eaae7f789dd",
        "datasheet": "2c17958fdd2f801eadd1225d13184bd42263136cb6a88f3e7f242b8963dc43fd"}),
    "tram-faults": ("810b91fee2760d48c96207b3d5aae070b52a30c064257c65886a22513faec068", {
        "model-matched": "77a7a357c41a49f860ab2ea518ae01616f38206de9c3e2fc78f1b889b700163c",
        "datasheet": "1b0d16494951edfc36c1791e566a3e4346a4a6b8ab9b2ff1cf0b095736bc4832"}),
}
#: (capture, preset family) pairs, each family's hash checked on every capture
CASES = [(name, presets) for name in sorted(GOLDEN) for presets in ("datasheet", "model-matched")]


def _capture(name: str) -> tuple[object, list[tuple[float, tuple[str, int], bytes]]]:
    scenario = "tram-urban" if name.startswith("tram-urban") else name
    sc = dataclasses.replace(load_scenario(scenario), max_duration_s=60.0)
    if name == "tram-urban-strobe-lossy":
        sc = strobe_dated(sc)
    dgrams = datagrams_of(generate(sc))
    if name == "tram-urban-strobe-lossy":
        dgrams = lossy(dgrams, seed=17)
    return sc, dgrams


def _hash_capture(dgrams) -> str:
    h = hashlib.sha256()
    for t, src, p in dgrams:
        h.update(np.float64(t).tobytes() + src[1].to_bytes(2, "little") + len(p).to_bytes(2, "little") + p)
    return h.hexdigest()


def _hash_estimates(result) -> str:
    est = result.new_estimates()
    h = hashlib.sha256()
    for k in sorted(est):
        h.update(k.encode() + np.ascontiguousarray(est[k]).tobytes())
    return h.hexdigest()


@pytest.mark.parametrize("name, presets", CASES)
def test_exact_replay_outputs_match_their_golden_hash(name, presets):
    sc, dgrams = _capture(name)
    sel = FilterSelection(presets=presets, imu=sc.imu.preset, odometer=sc.odometer.preset, gps=sc.gps.preset)
    with TrackDatabase.open(database_path(sc)) as track:
        result = replay_datagrams(iter(dgrams), track, ReplayOptions(config=ListenerConfig(filter=sel)))
    got = (_hash_capture(dgrams), _hash_estimates(result))
    assert result.new_estimates()["epoch"].size > 1000
    want = GOLDEN[name]
    assert got[0] == want[0], f"{name}: the capture changed (the simulator): {got[0]}"
    assert got[1] == want[1][presets], f"{name}, {presets}: the replay's outputs changed: {got[1]}"


@pytest.mark.parametrize("name, presets", CASES)
def test_compiled_replay_gives_the_golden_hash(name, presets, tmp_path):
    """``sfa replay``'s default path on the same captures (written as pcap) runs compiled on every one,
    the STROBE-dated lossy capture (sequence repair) and the scripted sensor faults included, and gives
    the same golden hash as the exact replay."""
    from helpers_capture import write_capture

    from tools.fast_replay import try_fast_replay

    sc, dgrams = _capture(name)
    cap = tmp_path / "capture.pcap"
    write_capture(cap, dgrams)
    sel = FilterSelection(presets=presets, imu=sc.imu.preset, odometer=sc.odometer.preset, gps=sc.gps.preset)
    with TrackDatabase.open(database_path(sc)) as track:
        result, info = try_fast_replay(cap, track, ReplayOptions(config=ListenerConfig(filter=sel)))
    assert info.used, info.reason
    assert _hash_estimates(result) == GOLDEN[name][1][presets], (name, presets)
