"""Simulator physics: forces, LSPB planning, the driver, and the noise-free IMU integrated back to truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from interface_modules import dynamics
from interface_modules.journey import build_legs
from interface_modules.motion import drive
from interface_modules.offline import generate, simulate_truth
from interface_modules.planner import accel_distance_table, lspb_profile_mps, plan_leg, travel_times_s
from interface_modules.presets import G_MPS2
from interface_modules.scenario import scenario_from_dict
from interface_modules.sensors.imu import true_imu
from interface_modules.synthetic import Segment, SyntheticTrack
from interface_modules.trains import KMH, TRAIN_PRESETS

TRAM = TRAIN_PRESETS["tram"]


def hilly_scenario(**sensors) -> dict:
    """A 2.4 km synthetic line with curves both ways, climbs and descents, four stops."""
    return {
        "scenario": {"name": "hilly", "seed": 11, "tail_s": 3.0},
        "track": {
            "database": "synthetic",
            "line_speed_kmh": 60.0,
            "segments": [
                {"length_m": 300.0},
                {"length_m": 250.0, "curvature_per_m": 1 / 180.0, "grade": 0.03},
                {"length_m": 400.0, "grade": 0.01},
                {"length_m": 300.0, "curvature_per_m": -1 / 250.0, "grade": -0.04},
                {"length_m": 1150.0, "grade": -0.005},
            ],
        },
        "train": {"preset": "tram"},
        "journey": {
            "points": [
                {"name": "A", "s_m": 20.0, "departure_s": 5.0},
                {"name": "B", "s_m": 700.0, "arrival_s": 90.0, "departure_s": 115.0, "dwell_s": 20.0},
                {"name": "P", "kind": "pass", "s_m": 1300.0, "arrival_s": 170.0},
                {"name": "C", "s_m": 1600.0, "arrival_s": 205.0, "departure_s": 230.0, "dwell_s": 20.0},
                {"name": "D", "s_m": 2350.0, "arrival_s": 320.0},
            ]
        },
        "sensors": sensors,
    }


@pytest.fixture(scope="module")
def hilly():
    sc = scenario_from_dict(
        hilly_scenario(imu={"preset": "ideal"}, odometer={"preset": "ideal"}, gps={"preset": "ideal"})
    )
    return sc, generate(sc)


def test_davis_grade_curve_forces_follow_the_formulas():
    v = np.array([0.0, 10.0, 20.0])
    expected = TRAM.davis_a_n + TRAM.davis_b_n_per_mps * v + TRAM.davis_c_n_per_mps2 * v * v
    np.testing.assert_allclose(dynamics.davis_resistance_n(TRAM, v), expected)
    assert dynamics.grade_force_n(TRAM, 0.04) == pytest.approx(
        TRAM.mass_kg * G_MPS2 * 0.04 / math.sqrt(1.0016)
    )
    assert dynamics.grade_force_n(TRAM, -0.02) < 0  # descending helps
    # Roeckl, metre gauge: M g 0.4 / (R - 20)
    assert dynamics.curve_resistance_n(TRAM, 1 / 120.0) == pytest.approx(TRAM.mass_kg * G_MPS2 * 0.4 / 100.0)
    emu = TRAIN_PRESETS["regional-emu"]  # standard gauge, R >= 300: 0.65 / (R - 55); R < 300: 0.5 / (R - 30)
    assert dynamics.curve_resistance_n(emu, -1 / 555.0) == pytest.approx(emu.mass_kg * G_MPS2 * 0.65 / 500.0)
    assert dynamics.curve_resistance_n(emu, 1 / 230.0) == pytest.approx(emu.mass_kg * G_MPS2 * 0.5 / 200.0)
    assert dynamics.curve_resistance_n(emu, 0.0) == 0.0


def test_traction_envelope_is_effort_adhesion_and_power_limited():
    adhesion = TRAM.adhesion_coefficient * TRAM.adhesive_mass_fraction * TRAM.mass_kg * G_MPS2
    assert dynamics.traction_limit_n(TRAM, 0.0) == pytest.approx(min(TRAM.max_tractive_effort_n, adhesion))
    assert dynamics.traction_limit_n(TRAM, 19.0) == pytest.approx(TRAM.max_power_w / 19.0)


def test_standstill_without_enough_force_does_not_roll_back():
    fg = float(dynamics.grade_force_n(TRAM, 0.05))
    assert dynamics.acceleration_mps2(TRAM, 0.0, 0.0, fg, 0.0) == 0.0
    a = dynamics.acceleration_mps2(TRAM, fg + TRAM.davis_a_n + 1000.0, 0.0, fg, 0.0)
    assert a == pytest.approx(1000.0 / TRAM.effective_mass_kg)


def test_lspb_profile_respects_cap_and_acceleration_limits():
    x = np.linspace(0.0, 1500.0, 3001)
    cap = np.full(x.size, 15.0)
    cap[1000:1400] = 6.0  # a restriction in the middle
    table = accel_distance_table(TRAM, 15.0)
    v = lspb_profile_mps(x, cap, 0.9, table)
    assert v[0] == 0.0 and v[-1] == 0.0
    assert np.all(v <= cap + 1e-9)
    dv2 = np.diff(v * v) / np.diff(x)
    assert dv2.min() >= -2 * 0.9 - 1e-6  # braking never harder than planned
    # Phi is tabulated (2000 speeds): the forward pass matches the acceleration law to 0.1 %
    assert dv2.max() <= 2 * TRAM.plan_accel_mps2 * 1.001
    assert v.max() == pytest.approx(15.0)
    assert np.all(v[1000:1400] <= 6.0 + 1e-9)


def test_plan_fits_the_scheduled_running_time():
    def flat(s):
        return np.zeros(np.shape(s))

    def limit(s):
        return np.full(np.shape(s), 50 * KMH)

    fastest = plan_leg(
        TRAM,
        s_start_m=0.0,
        s_end_m=800.0,
        dx_m=0.5,
        limit_at=limit,
        grade_at=flat,
        curvature_at=flat,
        scheduled_run_s=None,
    )
    slow = plan_leg(
        TRAM,
        s_start_m=0.0,
        s_end_m=800.0,
        dx_m=0.5,
        limit_at=limit,
        grade_at=flat,
        curvature_at=flat,
        scheduled_run_s=fastest.run_time_s + 20.0,
    )
    assert slow.run_time_s == pytest.approx(fastest.run_time_s + 20.0, abs=0.05)
    assert slow.v_mps.max() < fastest.v_mps.max()
    infeasible = plan_leg(
        TRAM,
        s_start_m=0.0,
        s_end_m=800.0,
        dx_m=0.5,
        limit_at=limit,
        grade_at=flat,
        curvature_at=flat,
        scheduled_run_s=fastest.run_time_s / 2,
    )
    assert infeasible.run_time_s == pytest.approx(fastest.run_time_s)
    backwards = plan_leg(
        TRAM,
        s_start_m=800.0,
        s_end_m=0.0,
        dx_m=0.5,
        limit_at=limit,
        grade_at=flat,
        curvature_at=flat,
        scheduled_run_s=None,
    )
    assert backwards.direction == -1 and backwards.run_time_s == pytest.approx(fastest.run_time_s)
    assert travel_times_s(fastest.x_m, fastest.v_mps)[-1] == pytest.approx(fastest.run_time_s)


def test_driver_keeps_stops_dwells_timetable_and_limits(hilly):
    sc, run = hilly
    ev = [(t - sc.start_epoch_s, kind, detail) for t, kind, detail in run.events]
    arrivals = [e for e in ev if e[1] == "arrive"]
    departures = [e for e in ev if e[1] == "depart"]
    assert [d.split(" ")[0] for _, _, d in arrivals] == ["B", "C", "D"]
    assert [d.split(" ")[0] for _, _, d in departures] == ["A", "B", "C"]
    sched_arr = {"B": 90.0, "C": 205.0, "D": 320.0}
    sched_dep = {"A": 5.0, "B": 115.0, "C": 230.0}
    for t, _, detail in departures:
        name = detail.split(" ")[0]
        assert t >= sched_dep[name] - 1e-9  # never leaves early
    for (t_arr, _, detail), (t_dep, _, _) in zip(arrivals[:-1], departures[1:], strict=True):
        assert t_dep - t_arr >= 20.0 - 1e-9  # minimum dwell
        name = detail.split(" ")[0]
        assert abs(t_arr - sched_arr[name]) < 4.0  # on time within a few seconds
    truth = run.truth
    t_rel = truth["epoch"] - sc.start_epoch_s
    for t_arr, _, detail in arrivals:
        name = detail.split(" ")[0]
        s_stop = {"B": 700.0, "C": 1600.0, "D": 2350.0}[name]
        i = int(np.searchsorted(t_rel, t_arr - 1e-9))
        assert abs(truth["arc_length"][i] - s_stop) < 1.0  # stops at the platform
        assert truth["speed"][i] == 0.0
    passes = [e for e in ev if e[1] == "pass"]
    assert len(passes) == 1 and abs(passes[0][0] - 170.0) < 6.0
    assert truth["speed"].max() <= 60 * KMH + 0.3  # line speed (small tracking overshoot)
    assert truth["speed"].min() >= 0.0
    assert truth["accel"].max() <= TRAM.max_tractive_effort_n / TRAM.effective_mass_kg + 0.5
    assert truth["accel"].min() >= -TRAM.service_brake_mps2 - 0.5
    # truth follows the documented constant-acceleration step scheme
    dt = 1.0 / sc.truth_rate_hz
    v, a, s, d = truth["speed"], truth["accel"], truth["arc_length"], truth["direction"]
    np.testing.assert_allclose(v[1:], np.maximum(v[:-1] + a[:-1] * dt, 0.0), atol=1e-12)
    np.testing.assert_allclose(s[1:], s[:-1] + d[:-1] * (v[:-1] * dt + 0.5 * a[:-1] * dt * dt), atol=1e-9)


def test_curve_speed_limit_is_respected():
    sc = scenario_from_dict(hilly_scenario())
    track = SyntheticTrack([Segment(400.0), Segment(300.0, 1 / 60.0), Segment(600.0)])
    traj = simulate_truth(
        sc.with_overrides(journey=sc.journey[:1] + (sc.journey[-1].__class__(s_m=1250.0, name="E"),)), track
    )
    in_curve = (traj.s_m > 400.0) & (traj.s_m < 700.0)
    assert traj.v_mps[in_curve].max() <= math.sqrt(TRAM.max_lateral_accel_mps2 * 60.0) + 0.3


def test_noise_free_imu_datagrams_integrate_back_to_truth_within_millimetres(hilly):
    """Integrate ax - g sin(theta) from the GROUND TRUTH state with the documented scheme."""
    sc, run = hilly
    track = SyntheticTrack([Segment(**seg.__dict__) for seg in sc.track.segments])
    msgs = run.messages()
    gt = next(m for m in msgs if type(m).__name__ == "GroundTruth")
    imu = [m for m in msgs if type(m).__name__ == "ImuSample"]
    assert len(imu) == run.truth["epoch"].size  # 100 Hz, one per truth step
    dt = 1.0 / 100.0
    s, v = gt.arc_length, gt.vx
    s_int = np.empty(len(imu))
    v_int = np.empty(len(imu))
    heading = float(track.heading_at(s))
    for k, m in enumerate(imu):
        assert m.epoch == pytest.approx(sc.start_epoch_s + k * dt, abs=1e-6)
        s_int[k], v_int[k] = s, v
        grade = float(track.grade_at(s))  # direction of travel is +s on this journey
        a = m.ax - G_MPS2 * math.sin(math.atan(grade))
        if v + a * dt < 0:
            a = -v / dt
        s += v * dt + 0.5 * a * dt * dt
        v += a * dt
        heading += m.gz * dt
    err = np.abs(s_int - run.truth["arc_length"])
    assert err.max() < 1e-3, err.max()
    assert np.abs(v_int - run.truth["speed"]).max() < 1e-6
    # yaw rate v k integrates to the track's heading change (curvature known exactly here)
    assert heading == pytest.approx(float(track.heading_at(s)), abs=2e-3)


def test_imu_specific_force_at_rest_and_in_curves():
    track = SyntheticTrack([Segment(100.0, 0.0, 0.05), Segment(100.0, 1 / 100.0, 0.0)])
    from interface_modules.motion import Trajectory

    traj = Trajectory(
        dt_s=0.01,
        t_s=np.array([0.0, 0.01]),
        s_m=np.array([50.0, 150.0]),
        v_mps=np.array([0.0, 10.0]),
        a_mps2=np.array([0.0, 0.0]),
        direction=np.array([1, 1], dtype=np.int8),
        events=[],
    )
    _, f, w = true_imu(traj, track, 1)
    theta = math.atan(0.05)
    np.testing.assert_allclose(f[0], [G_MPS2 * math.sin(theta), 0.0, -G_MPS2 * math.cos(theta)], atol=1e-12)
    np.testing.assert_allclose(f[1], [0.0, 100.0 / 100.0, -G_MPS2], atol=1e-12)  # ay = v^2 k (right turn)
    np.testing.assert_allclose(w[1], [0.0, 0.0, 10.0 / 100.0], atol=1e-12)  # gz = v k
    # the same curve travelled backwards is a left turn: negative yaw rate and lateral force
    back = Trajectory(
        dt_s=0.01,
        t_s=np.array([0.0]),
        s_m=np.array([150.0]),
        v_mps=np.array([10.0]),
        a_mps2=np.array([0.0]),
        direction=np.array([-1], dtype=np.int8),
        events=[],
    )
    _, fb, wb = true_imu(back, track, 1)
    assert fb[0, 1] == pytest.approx(-1.0) and wb[0, 2] == pytest.approx(-0.1)


def test_reversed_journey_runs_backwards_along_the_line():
    data = hilly_scenario()
    data["journey"]["points"] = [
        {"name": "D", "s_m": 2350.0, "departure_s": 1.0},
        {"name": "C", "s_m": 1600.0, "dwell_s": 20.0},
        {"name": "A", "s_m": 20.0},
    ]
    sc = scenario_from_dict(data)
    track = SyntheticTrack([Segment(**seg.__dict__) for seg in sc.track.segments])
    legs = build_legs(sc, track)
    traj = drive(sc.train, legs, dt_s=0.01)
    assert np.all(np.diff(traj.s_m) <= 1e-12)
    assert abs(traj.s_m[-1] - 20.0) < 1.0 and set(traj.direction.tolist()) == {-1}


def test_cant_rolls_the_body_into_the_curve():
    from interface_modules.motion import Trajectory
    from interface_modules.sensors.imu import CantModel

    track = SyntheticTrack([Segment(200.0), Segment(400.0, 1 / 300.0), Segment(200.0)])
    cant = CantModel(design_speed_mps=15.0, max_cant_m=0.15, rail_spacing_m=1.5)
    n = 100 * 60
    t = np.arange(n) * 0.01
    traj = Trajectory(
        dt_s=0.01,
        t_s=t,
        s_m=100.0 + 12.0 * t,
        v_mps=np.full(n, 12.0),
        a_mps2=np.zeros(n),
        direction=np.ones(n, dtype=np.int8),
        events=[],
    )
    _, f, w = true_imu(traj, track, 1, cant)
    _, f0, w0 = true_imu(traj, track, 1)
    np.testing.assert_array_equal(f[:, 0], f0[:, 0])  # ax (and so the along-track integration) is unchanged
    mid = (traj.s_m > 350.0) & (traj.s_m < 550.0)
    phi = math.asin(1.5 * 15.0**2 / 300.0 / G_MPS2 / 1.5)  # cant 115 mm < 150 mm
    ay_level = 12.0**2 / 300.0
    np.testing.assert_allclose(f[mid, 1], ay_level * math.cos(phi) - G_MPS2 * math.sin(phi), atol=1e-9)
    np.testing.assert_allclose(f[mid, 2], -ay_level * math.sin(phi) - G_MPS2 * math.cos(phi), atol=1e-9)
    assert np.all(np.abs(f[mid, 1]) < np.abs(f0[mid, 1]))  # below the balancing speed: less lateral force
    np.testing.assert_allclose(np.linalg.norm(f[mid], axis=1), np.linalg.norm(f0[mid], axis=1), atol=1e-9)
    # the roll rate integrates to the roll angle in the curve and back to zero after it
    roll = np.concatenate(([0.0], np.cumsum(w[:, 0]) * 0.01))[:-1]
    np.testing.assert_allclose(roll[mid], phi, atol=1e-12)
    assert abs(roll[-1]) < 1e-12
