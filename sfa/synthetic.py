"""Small deterministic synthetic sensor data on a track line, for the filter's tests and examples.

Not the project's simulator (``interface_modules``): a compact, seeded generator whose error model is
exactly the filter's (constant accelerometer bias, odometer scale, Gauss-Markov + white GNSS error), with
optional injected faults (GNSS jump, ramp and outage, odometer slip). Sensor specifications are passed in
(objects shaped like ``interface_modules.presets`` specs) so that ``sfa`` does not import the simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sfa.measurements import GpsMeas, ImuMeas, InitMeas, OdoMeas

G_MPS2 = 9.80665


@dataclass(frozen=True)
class Faults:
    """Injected faults; every time in seconds from the start of the run."""

    gps_outages: tuple[tuple[float, float], ...] = ()  #: (start, end) without any fix
    gps_jumps: tuple[tuple[float, float, float, float], ...] = ()  #: (start, end, d_east_m, d_north_m)
    gps_ramps: tuple[tuple[float, float, float, float], ...] = ()  #: (start, end, east_mps, north_mps)
    odo_slips: tuple[tuple[float, float, float], ...] = ()  #: (start, end, factor): odometer reads v * factor


@dataclass(frozen=True)
class Profile:
    """Speed profile: segments of (duration [s], acceleration [m/s^2]) repeated in order."""

    segments: tuple[tuple[float, float], ...] = ((15.0, 0.8), (60.0, 0.0), (15.0, -0.8), (10.0, 0.0))
    v0_mps: float = 0.0  #: initial speed [m/s]
    s0_m: float = 20.0  #: initial arc length [m]


@dataclass
class SyntheticRun:
    """Truth at the IMU rate and the time-ordered measurements."""

    t_s: np.ndarray
    s_m: np.ndarray
    v_mps: np.ndarray
    measurements: list = field(default_factory=list)
    bias_mps2: float = 0.0
    odo_scale: float = 0.0


def generate(
    track,
    line_id: int,
    duration_s: float,
    imu,
    odo,
    gps,
    seed: int,
    profile: Profile | None = None,
    faults: Faults | None = None,
    t0_s: float = 1000.0,
) -> SyntheticRun:
    """Seeded synthetic run on ``track.line(line_id)`` (a track_db database or anything shaped like it)."""
    rng = np.random.default_rng(seed)
    profile = profile or Profile()
    faults = faults or Faults()
    line = track.line(line_id)
    dt = 1.0 / imu.rate_hz
    n = int(round(duration_s / dt)) + 1
    t_rel = np.arange(n) * dt
    # speed profile (clamped at >= 0 and at the end of the line)
    acc = np.zeros(n)
    seg_t = 0.0
    k = 0
    for i in range(n):
        while t_rel[i] >= seg_t + profile.segments[k % len(profile.segments)][0]:
            seg_t += profile.segments[k % len(profile.segments)][0]
            k += 1
        acc[i] = profile.segments[k % len(profile.segments)][1]
    v = np.empty(n)
    s = np.empty(n)
    v[0], s[0] = profile.v0_mps, profile.s0_m
    for i in range(1, n):
        a = acc[i - 1]
        vn = v[i - 1] + a * dt
        if vn < 0.0:
            vn = 0.0
            a = -v[i - 1] / dt
        s[i] = s[i - 1] + v[i - 1] * dt + 0.5 * a * dt * dt
        v[i] = vn
        acc[i - 1] = a
    acc[-1] = 0.0 if n < 2 else acc[-2]
    if s[-1] > line.length_m - 1.0:
        raise ValueError("synthetic run leaves the line: shorten it or lower the speeds")
    grade = np.asarray(line.grade_at(s), dtype=float)
    curv = np.asarray(line.curvature_at(s), dtype=float)
    sin_th = grade / np.sqrt(1.0 + grade * grade)
    cos_th = 1.0 / np.sqrt(1.0 + grade * grade)
    t = t0_s + t_rel
    meas: list[tuple[float, int, object]] = [(t[0], 0, InitMeas(t[0], float(s[0]), float(v[0]), line_id))]

    bias = float(rng.normal(0.0, imu.accel_bias_sigma))
    gbias = float(rng.normal(0.0, imu.gyro_bias_sigma))
    an = imu.accel_noise_density * math.sqrt(imu.rate_hz)
    gn = imu.gyro_noise_density * math.sqrt(imu.rate_hz)
    fx = acc + G_MPS2 * sin_th + bias + rng.normal(0.0, an, n)
    fy = v * v * curv + rng.normal(0.0, an, n)
    fz = -G_MPS2 * cos_th + rng.normal(0.0, an, n)
    wz = v * curv + gbias + rng.normal(0.0, gn, n)
    wx = rng.normal(0.0, gn, n)
    wy = rng.normal(0.0, gn, n)
    for i in range(1, n):
        meas.append((t[i], 1, ImuMeas(float(t[i]), (float(fx[i]), float(fy[i]), float(fz[i])),
                                      (float(wx[i]), float(wy[i]), float(wz[i])))))

    scale = float(rng.normal(0.0, odo.scale_sigma))
    step = max(1, int(round(imu.rate_hz / odo.rate_hz)))
    for i in range(step, n, step):
        sig = odo.sigma_floor_mps + odo.sigma_fraction * abs(v[i])
        factor = 1.0
        for a0, a1, f in faults.odo_slips:
            if a0 <= t_rel[i] < a1:
                factor = f
        z = v[i] * (1.0 + scale) * factor + rng.normal(0.0, sig)
        if odo.lsb_mps > 0:
            z = round(z / odo.lsb_mps) * odo.lsb_mps
        if v[i] == 0.0:
            z = 0.0  # a stopped wheel reads exactly zero
        meas.append((t[i], 2, OdoMeas(float(t[i]), float(z), float(sig))))

    gstep = max(1, int(round(imu.rate_hz / gps.rate_hz)))
    phi = math.exp(-gstep * dt / gps.gm_tau_s)
    q = gps.gm_sigma_m * math.sqrt(1.0 - phi * phi)
    ge, gnn = rng.normal(0.0, gps.gm_sigma_m, 2)
    for i in range(gstep, n, gstep):
        ge = phi * ge + rng.normal(0.0, q)
        gnn = phi * gnn + rng.normal(0.0, q)
        we, wn = rng.normal(0.0, gps.white_sigma_m, 2)
        if any(a0 <= t_rel[i] < a1 for a0, a1 in faults.gps_outages):
            continue
        e, nn = line.point_at(s[i])
        de = dn = 0.0
        for a0, a1, je, jn in faults.gps_jumps:
            if a0 <= t_rel[i] < a1:
                de, dn = de + je, dn + jn
        for a0, a1, re, rn in faults.gps_ramps:
            if a0 <= t_rel[i] < a1:
                de, dn = de + re * (t_rel[i] - a0), dn + rn * (t_rel[i] - a0)
        lat, lon = track.to_geodetic(float(e) + ge + we + de, float(nn) + gnn + wn + dn)
        meas.append((t[i], 3, GpsMeas(float(t[i]), float(lat), float(lon), 0.0, gps.reported_sigma_h_m,
                                      gps.fix_quality, gps.num_sv_mean)))
    meas.sort(key=lambda m: (m[0], m[1]))
    return SyntheticRun(t, s, v, [m for _, _, m in meas], bias, scale)


def _arc(x0: float, y0: float, heading: float, radius: float, angle: float, step: float):
    """Points (east, north) of a circular arc from (x0, y0) at ``heading`` (rad, clockwise from north);
    angle > 0 turns right. Returns the points (without the start) and the final heading."""
    n = max(2, int(math.ceil(abs(angle) * radius / step)))
    sign = 1.0 if angle > 0 else -1.0

    def right(h: float) -> tuple[float, float]:
        return math.cos(h), -math.sin(h)  # unit vector to the right of heading h

    rx, ry = right(heading)
    cx, cy = x0 + sign * radius * rx, y0 + sign * radius * ry  # centre on the inside of the turn
    pts = []
    for k in range(1, n + 1):
        qx, qy = right(heading + angle * k / n)
        pts.append((cx - sign * radius * qx, cy - sign * radius * qy))
    return pts, heading + angle


def _straight(x0: float, y0: float, heading: float, length: float, step: float):
    n = max(1, int(math.ceil(length / step)))
    dx, dy = math.sin(heading), math.cos(heading)
    return [(x0 + length * k / n * dx, y0 + length * k / n * dy) for k in range(1, n + 1)]


def build_track_db(path, lat0_deg: float = 50.93, lon0_deg: float = 11.58, step_m: float = 10.0):
    """Write a small two-line test network with ``track_db.build.create_database`` and return its path.

    Line 1 (default): 2 km north, a 90 deg right curve of radius 300 m, 10 km east, with a gentle
    +-1 % grade. Line 2 shares line 1's first 1 km and branches left (radius 200 m, 45 deg) for 2 km.
    """
    from track_db.build import LineGeometry, create_database

    r_earth = 6378137.0

    def to_latlon(pts):
        p = np.asarray(pts)
        lat = lat0_deg + np.degrees(p[:, 1] / r_earth)
        lon = lon0_deg + np.degrees(p[:, 0] / (r_earth * math.cos(math.radians(lat0_deg))))
        return lat, lon

    def alt_of(pts):
        p = np.asarray(pts)
        s = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1])))))
        return 150.0 + 5.0 * np.sin(s / 500.0)

    p1 = [(0.0, 0.0)] + _straight(0.0, 0.0, 0.0, 2000.0, step_m)
    arc, hd = _arc(*p1[-1], 0.0, 300.0, math.pi / 2, step_m)
    p1 += arc
    p1 += _straight(*p1[-1], hd, 10000.0, step_m)
    n_shared = int(round(1000.0 / step_m)) + 1
    p2 = p1[:n_shared]
    arc2, hd2 = _arc(*p2[-1], 0.0, 200.0, -math.pi / 4, step_m)
    p2 = p2 + arc2
    p2 += _straight(*p2[-1], hd2, 2000.0, step_m)
    lines = []
    for name, pts in (("synthetic main", p1), ("synthetic branch", p2)):
        lat, lon = to_latlon(pts)
        lines.append(LineGeometry(name=name, lat_deg=lat, lon_deg=lon, alt_m=alt_of(pts),
                                  source="sfa.synthetic", attribution="synthetic test geometry"))
    return create_database(path, lines, overwrite=True)
