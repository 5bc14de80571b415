"""balzer82 Dresden car log (Paul Balzer, CC BY-SA 2.0): real IMU, GPS and speed, no ground truth.

What goes into the capture (docs/real-data.md has the evidence and the measured results):

* IMU: every row (about 50 Hz), dated by the logger's ``millis``. Axes: the data show that the logger's
  accelerometer columns are the *negated* specific force in a forward-left-up triad (``az`` is -9.6 at
  rest; ``-ax`` follows d(speed)/dt; ``ay`` follows +v * heading rate, i.e. rightward in turns) and the
  gyro columns are rates about forward-left-up [deg/s] (the integral of ``yawrate`` is -177 deg where
  the GPS heading turns +181 deg clockwise). So, in FRD: f = (-ax, ay, az), w = (rollrate, -pitchrate,
  -yawrate) in rad/s. The sensor is mounted tilted (mean forward specific force -1.8 m/s^2, ~10 deg):
  both vectors are rotated by the roll and pitch of the mean specific force over the drive (coarse
  levelling, the usual mounting alignment; angles in metadata.json). No other change. REAL.
* ODOMETER: the ``speed`` column [km/h -> m/s] at each new GPS epoch, with a constant documented sigma.
  It updates exactly with the GPS epochs, so it is the receiver's speed over ground (not a wheel
  sensor): it is not independent of the GPS positions. REAL.
* GPS: each new GPS epoch (the ``time`` column changes, 10 Hz): lat, lon, altitude, ``epe`` as sigma_h,
  fix 2/3 -> NMEA quality 1 (else 0), ``satellites_used``. REAL.
* Timing: every GNSS epoch is dated by the receiver's own time tag (``time``, hhmmssSS0 UTC) mapped to
  the logger clock with one constant offset (the median of read time minus tag), then moved back by
  its latency: the speed by the lag that best aligns d(speed)/dt with the IMU's forward specific force
  (0.95 s on 2014-03-26), the positions by that minus the lag of the speed behind the positions' own
  speed (0.45 s; the gyro against the GPS heading rate confirms 0.6 s). Not by the row that first holds
  it: the logger reads the receiver late by a varying amount (up to 1.7 s after it stalled). Each
  datagram is *sent* at that row's logger time, its real arrival. An epoch whose tag does not increase
  is dropped and counted.
* Track: digitised from the GPS fixes taken at >= ``track_min_speed_mps`` (there is no other
  geometry): thinned to at least ``min_spacing_m`` between vertices, a ``smooth_vertices``-point moving
  average on the interior vertices, and a ``track_smoothing_sigma_m`` heading/curvature profile (5 m:
  street corners; the gyro agrees best with it, docs/real-data.md). No altitude: the GPS altitude is
  far too noisy for a grade (it would feed the filter metres-per-second-squared of false gravity along
  the track), so the track is taken as level. Because the track comes from the same GPS the filter
  uses, results can only be checked for self-consistency (gnss_on_track.csv: each fix projected on the
  track; see tools.adapters.evaluate).
* Control: GROUND TRUTH before the first row, dated at the first fix's sampling time (its arc length
  projected on the track, the speed interpolated there), STROBE every second, STOP 0.5 s after the last
  row.
"""

from __future__ import annotations

import csv
import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tools.adapters.common import (
    MODULE_PORTS,
    Conversion,
    ScheduleConfig,
    Timeline,
    add_control,
    count_by_module,
    prepare_out_dir,
    project_along,
    thin_by_spacing,
    write_json,
    write_pcap,
    write_truth_csv,
)
from tools.errors import ToolError

DEFAULT_FILE = "2014-03-26-000-Data.csv"
COLUMNS = ("millis", "ax", "ay", "az", "rollrate", "pitchrate", "yawrate", "speed", "time", "latitude",
           "longitude", "altitude", "epe", "fix", "satellites_used")
ATTRIBUTION = "Dresden car IMU/GPS log, (c) Paul Balzer (github.com/balzer82/Kalman), CC BY-SA 2.0"
OUTPUT_NAMES = ("capture.pcap", "track.db", "gnss_on_track.csv", "metadata.json")
KMH = 1.0 / 3.6  #: one km/h [m/s]


def default_source_file() -> Path:
    """The bundled copy: tools/data/dresden/2014-03-26-000-Data.csv."""
    return Path(__file__).resolve().parent.parent / "data" / "dresden" / DEFAULT_FILE


@dataclass(frozen=True)
class DresdenConfig:
    """Parameters of the Dresden conversion."""

    speed_sigma_mps: float = 0.3  #: 1-sigma written into each ODOMETER datagram [m/s]
    min_spacing_m: float = 2.0  #: smallest distance between track vertices [m]
    smooth_vertices: int = 5  #: moving-average window over the thinned vertices [vertices, odd]
    level_imu: bool = True  #: rotate the IMU by the roll/pitch of its mean specific force
    junction_tolerance_m: float = 0.01  #: vertex distance that makes a junction (see smartloc) [m]
    #: age of the receiver's speed (and course) at its time tag, on the logger clock [s]; None: estimated
    #: from the data (the lag that best aligns d(speed)/dt with the IMU's forward specific force)
    gnss_latency_s: float | None = None
    #: how much earlier than the speed the positions are valid [s]; None: estimated from the data (the
    #: lag that best aligns the speed column with the speed derived from the positions)
    position_lead_s: float | None = None
    max_latency_s: float = 3.0  #: largest latency searched by the estimates [s]
    #: an estimated latency whose correlation is below this is refused (pass the value instead) [-]
    min_latency_correlation: float = 0.7
    #: fixes slower than this (by the speed column) are not used for the track: at a standstill the
    #: positions wander by metres and would add false length and false curvature [m/s]
    track_min_speed_mps: float = 1.0
    #: Gaussian smoothing of the track's heading/curvature profile (track_db BuildConfig) [m]; streets
    #: turn in 10-20 m radius corners, which the 20 m default for railway lines smears out
    track_smoothing_sigma_m: float = 5.0
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.speed_sigma_mps) and 0.0 < self.speed_sigma_mps <= 50.0):
            raise ToolError(f"speed_sigma_mps must be in (0, 50], got {self.speed_sigma_mps!r}")
        if not (math.isfinite(self.min_spacing_m) and self.min_spacing_m > 0):
            raise ToolError(f"min_spacing_m must be > 0, got {self.min_spacing_m!r}")
        if self.gnss_latency_s is not None and not (
            math.isfinite(self.gnss_latency_s) and 0.0 <= self.gnss_latency_s <= self.max_latency_s
        ):
            raise ToolError(
                f"gnss_latency_s must be in [0, {self.max_latency_s}], got {self.gnss_latency_s!r}"
            )
        if self.position_lead_s is not None and not (
            math.isfinite(self.position_lead_s) and 0.0 <= self.position_lead_s <= self.max_latency_s
        ):
            raise ToolError(
                f"position_lead_s must be in [0, {self.max_latency_s}], got {self.position_lead_s!r}"
            )
        if not (math.isfinite(self.track_min_speed_mps) and self.track_min_speed_mps >= 0.0):
            raise ToolError(f"track_min_speed_mps must be >= 0, got {self.track_min_speed_mps!r}")
        if not (math.isfinite(self.track_smoothing_sigma_m) and self.track_smoothing_sigma_m > 0.0):
            raise ToolError(f"track_smoothing_sigma_m must be > 0, got {self.track_smoothing_sigma_m!r}")
        if self.smooth_vertices < 1 or self.smooth_vertices % 2 == 0:
            raise ToolError(f"smooth_vertices must be a positive odd number, got {self.smooth_vertices!r}")


def read_dresden(path: str | Path) -> dict[str, np.ndarray]:
    """The columns the adapter uses, as float arrays; every failure names the file and line."""
    src = Path(path)
    if not src.is_file():
        raise ToolError(f"Dresden source file not found: {src}")
    cols: dict[str, list[float]] = {c: [] for c in COLUMNS}
    try:
        with open(src, newline="", encoding="ascii") as fh:
            reader = csv.DictReader(fh)
            missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
            if missing:
                raise ToolError(f"{src}: not a Dresden log: missing column(s) {', '.join(missing)}")
            for row in reader:
                no = reader.line_num
                for c in COLUMNS:
                    try:
                        v = float(row[c])
                    except (TypeError, ValueError):
                        raise ToolError(f"{src}:{no}: column {c!r} is not a number ({row[c]!r})") from None
                    if not math.isfinite(v):
                        raise ToolError(f"{src}:{no}: column {c!r} is not finite")
                    cols[c].append(v)
    except UnicodeDecodeError as exc:
        raise ToolError(f"{src}: not a Dresden CSV log ({exc.reason})") from None
    except csv.Error as exc:
        raise ToolError(f"{src}: malformed CSV ({exc})") from None
    except OSError as exc:
        raise ToolError(f"cannot read {src}: {exc}") from None
    out = {c: np.asarray(v, dtype=np.float64) for c, v in cols.items()}
    n = out["millis"].size
    if n < 2:
        raise ToolError(f"{src}: at least two data rows are needed, got {n}")
    bad = np.flatnonzero(np.diff(out["millis"]) <= 0.0)
    if bad.size:
        raise ToolError(f"{src}:{int(bad[0]) + 3}: millis does not increase")
    for c, lo, hi in (("latitude", -90.0, 90.0), ("longitude", -180.0, 180.0), ("speed", 0.0, 540.0)):
        bad = np.flatnonzero((out[c] < lo) | (out[c] > hi))
        if bad.size:
            raise ToolError(f"{src}:{int(bad[0]) + 2}: {c} {out[c][bad[0]]} outside [{lo}, {hi}]")
    return out


def frd_imu(d: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) specific force [m/s^2] and (n, 3) rates [rad/s] in FRD, from the logger's columns."""
    f = np.column_stack([-d["ax"], d["ay"], d["az"]])
    w = np.radians(np.column_stack([d["rollrate"], -d["pitchrate"], -d["yawrate"]]))
    return f, w


def levelling(f_mean: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(roll_rad, pitch_rad, R) of the coarse alignment: R rotates sensor FRD vectors into a level FRD
    frame, so that the mean specific force ``f_mean`` becomes (0, 0, -|f_mean|)."""
    fx, fy, fz = (float(v) for v in f_mean)
    # at rest f = (g sin(pitch), -g sin(roll) cos(pitch), -g cos(roll) cos(pitch))
    roll = math.atan2(-fy, -fz)
    pitch = math.atan2(fx, math.hypot(fy, fz))
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    # body -> level: R = Ry(pitch) Rx(roll) (C_b^n with zero heading)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    return roll, pitch, ry @ rx


def lagged_fit(
    t_a_s: np.ndarray, a: np.ndarray, t_b_s: np.ndarray, b: np.ndarray,
    max_lag_s: float = 3.0, step_s: float = 0.05, min_lag_s: float = 0.0,
) -> tuple[float, float, float]:
    """(lag_s, correlation, slope): the lag in [min_lag_s, max_lag_s] for which ``b(t)`` best follows
    ``a(t - lag)`` (``b`` is ``lag`` later than ``a``).

    Both signals on a 0.1 s grid, Gaussian-smoothed (sigma 0.5 s), Pearson correlation at each candidate
    lag; the best one wins. The slope of ``a`` on ``b`` at that lag is a scale check (1: same units)."""
    from scipy.ndimage import gaussian_filter1d

    pad = max(max_lag_s, -min_lag_s, 0.0)
    lo, hi = max(t_a_s[0], t_b_s[0]) + pad, min(t_a_s[-1], t_b_s[-1]) - pad
    if hi - lo < 10.0:
        raise ToolError("too short a log to estimate a latency (needs > 10 s beyond the lag range)")
    grid = np.arange(lo, hi, 0.1)
    bb = gaussian_filter1d(np.interp(grid, t_b_s, b), 5.0)
    best = (-2.0, 0.0, 0.0)
    for lag in np.arange(min_lag_s, max_lag_s + 1e-9, step_s):
        aa = gaussian_filter1d(np.interp(grid - lag, t_a_s, a), 5.0)
        c = float(np.corrcoef(bb, aa)[0, 1])
        if c > best[0]:
            best = (c, float(lag), float(np.polyfit(bb, aa, 1)[0]))
    return best[1], best[0], best[2]


def estimate_latency_s(
    t_s: np.ndarray, f_forward_mps2: np.ndarray, t_speed_s: np.ndarray, speed_mps: np.ndarray,
    max_lag_s: float = 3.0, step_s: float = 0.05,
) -> tuple[float, float, float]:
    """(lag_s, correlation, slope): how much later than the IMU the speed reflects the same acceleration
    (d(speed)/dt against the forward specific force, :func:`lagged_fit`; slope 1 for a consistent pair)."""
    from scipy.ndimage import gaussian_filter1d

    if t_speed_s.size < 3:
        raise ToolError("too short a log to estimate the GNSS latency")
    dv = np.gradient(gaussian_filter1d(speed_mps, 2.0), t_speed_s)
    return lagged_fit(t_s, f_forward_mps2, t_speed_s, dv, max_lag_s, step_s)


def position_speed_mps(t_s: np.ndarray, east_m: np.ndarray, north_m: np.ndarray, half_window: int = 5
                       ) -> np.ndarray:
    """Speed from the positions: chord over +-``half_window`` epochs divided by its time (ends: shorter)."""
    n = t_s.size
    i = np.arange(n)
    a, b = np.clip(i - half_window, 0, n - 1), np.clip(i + half_window, 0, n - 1)
    dt = t_s[b] - t_s[a]
    chord = np.hypot(east_m[b] - east_m[a], north_m[b] - north_m[a])
    return np.where(dt > 0, chord / np.where(dt > 0, dt, 1.0), 0.0)


def heading_rate_radps(t_s: np.ndarray, east_m: np.ndarray, north_m: np.ndarray, speed_mps: np.ndarray,
                       min_speed_mps: float = 3.0, half_window: int = 3) -> np.ndarray:
    """Clockwise heading rate of the position track [rad/s] (FRD yaw-rate sign); 0 below ``min_speed_mps``
    (the heading of a slow track is noise)."""
    from scipy.ndimage import gaussian_filter1d

    es, ns = gaussian_filter1d(east_m, 2.0), gaussian_filter1d(north_m, 2.0)
    n = t_s.size
    i = np.arange(n)
    a, b = np.clip(i - half_window, 0, n - 1), np.clip(i + half_window, 0, n - 1)
    hd = np.unwrap(np.arctan2(es[b] - es[a], ns[b] - ns[a]))
    rate = np.gradient(hd, t_s)
    return np.where(speed_mps >= min_speed_mps, rate, 0.0)


def gps_time_tags_s(time_col: np.ndarray) -> np.ndarray:
    """The receiver's time tag of each row [s of the UTC day, unwrapped past midnight] from the
    ``time`` column (hhmmssSS0: 123825300 = 12:38:25.30)."""
    tm = np.asarray(time_col, dtype=np.float64)
    hh, mm = np.floor(tm / 1e7), np.floor(tm / 1e5) % 100.0
    ss = (tm % 1e5) / 1000.0
    sod = hh * 3600.0 + mm * 60.0 + ss
    wraps = np.concatenate(([0.0], np.cumsum(np.diff(sod) < -43200.0)))
    return sod + 86400.0 * wraps


def gps_epochs(d: dict[str, np.ndarray]) -> np.ndarray:
    """Row indices where a new GPS epoch (the ``time`` column) first appears."""
    tm = d["time"]
    return np.flatnonzero(np.r_[True, np.diff(tm) != 0.0])


def moving_average_interior(x: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average; the first and last ``window // 2`` vertices keep their values."""
    if window <= 1 or x.size <= window:
        return x.copy()
    k = window // 2
    c = np.convolve(x, np.ones(window) / window, mode="valid")
    out = x.copy()
    out[k:-k] = c
    return out


def convert_dresden(
    src: str | Path | None, out_dir: str | Path, config: DresdenConfig | None = None, overwrite: bool = False
) -> Conversion:
    """Write capture.pcap, track.db, gnss_on_track.csv and metadata.json for a Dresden log."""
    from listener.codec import GpsFix, GroundTruth, ImuSample, OdometerSample
    from track_db import TrackDatabase
    from track_db.build import BuildConfig, LineGeometry, create_database
    from track_db.errors import TrackDbError
    from track_db.geodesy import LocalFrame, centred_proj_string

    cfg = config or DresdenConfig()
    path = default_source_file() if src is None else Path(src)
    d = read_dresden(path)
    out = prepare_out_dir(out_dir, OUTPUT_NAMES, overwrite)
    t = d["millis"] / 1000.0  # logger clock, unix seconds = sensor-set time

    # --- IMU in FRD, levelled
    f, w = frd_imu(d)
    roll = pitch = 0.0
    if cfg.level_imu:
        roll, pitch, rot = levelling(f.mean(axis=0))
        f, w = f @ rot.T, w @ rot.T
    lim = 16.0 * 9.80665
    bad = np.flatnonzero((np.abs(f) > lim).any(axis=1) | (np.abs(w) > 35.0).any(axis=1))
    if bad.size:
        raise ToolError(f"{path}:{int(bad[0]) + 2}: IMU sample outside the wire range")

    # --- GPS epochs, dated by the receiver's own time tag (``time``), not by when the logger read them:
    # the logger reads the receiver late by a varying amount (0.2 s normally, up to 1.7 s after it
    # stalled 96-99 s into the 2014-03-26 drive). An epoch whose tag does not increase is dropped.
    g_all = gps_epochs(d)
    tag_all = gps_time_tags_s(d["time"][g_all])
    in_order = tag_all > np.maximum.accumulate(np.r_[-np.inf, tag_all[:-1]])
    g, tag = g_all[in_order], tag_all[in_order]
    dropped_out_of_order = int((~in_order).sum())
    if g.size < 2:
        raise ToolError(f"{path}: fewer than two GPS epochs with increasing time tags")
    # time tag -> logger clock: the median of (logger time when read - tag); the spread is reading delay
    read_delay = t[g] - tag
    clock_offset = float(np.median(read_delay))
    t_tag = tag + clock_offset  # logger time at which the receiver tagged each epoch
    drift = float(np.polyfit(t_tag - t_tag[0], read_delay, 1)[0]) if g.size > 2 else 0.0
    glat, glon, galt = d["latitude"][g], d["longitude"][g], d["altitude"][g]
    fixq = np.where(d["fix"][g] >= 2.0, 1, 0).astype(int)
    valid = fixq > 0
    if valid.sum() < 2:
        raise ToolError(f"{path}: fewer than two GPS epochs with a fix")
    speed = d["speed"][g] * KMH

    frame = LocalFrame.from_proj(centred_proj_string(glat[valid], glon[valid]))
    e, n = (np.asarray(a) for a in frame.to_local(glat[valid], glon[valid]))

    # --- GNSS latencies on the logger clock. Speed (and course) come from the receiver's velocity
    # solution and lag the IMU more than its positions do, so each gets its own latency:
    #   speed: the lag that best aligns d(speed)/dt with the IMU's forward specific force;
    #   positions: the speed latency minus the lag of the speed column behind the positions' own speed.
    lag_corr = lag_slope = lead_corr = lead_slope = math.nan
    if cfg.gnss_latency_s is None:
        latency, lag_corr, lag_slope = estimate_latency_s(t, f[:, 0], t_tag, speed, cfg.max_latency_s)
    else:
        latency = float(cfg.gnss_latency_s)
    if cfg.position_lead_s is None:
        lead, lead_corr, lead_slope = lagged_fit(t_tag[valid], position_speed_mps(t_tag[valid], e, n),
                                                 t_tag, speed, cfg.max_latency_s)
    else:
        lead = float(cfg.position_lead_s)
    for name, corr, flag, known in (("speed latency", lag_corr, "--latency", 0.95),
                                    ("position lead", lead_corr, "--position-lead", 0.45)):
        if math.isfinite(corr) and corr < cfg.min_latency_correlation:
            raise ToolError(
                f"{path}: the {name} cannot be estimated from this log (best correlation {corr:.2f} < "
                f"{cfg.min_latency_correlation}); give it with {flag} S (2014-03-26 drive: {known} s)")
    pos_latency = max(latency - lead, 0.0)
    t_speed = t_tag - latency  # sampling time of each speed
    t_pos = t_tag - pos_latency  # sampling time of each position
    # independent check of the position latency: the GPS heading rate against the gyro's yaw rate
    try:
        yaw_lag, yaw_corr, yaw_slope = lagged_fit(
            t, w[:, 2], t_tag[valid],
            heading_rate_radps(t_pos[valid], e, n, np.interp(t_pos[valid], t_speed, speed)),
            cfg.max_latency_s)
    except ToolError:
        yaw_lag = yaw_corr = yaw_slope = math.nan

    # --- track from the valid fixes taken while moving (speed at the fix's own time)
    moving = np.interp(t_pos[valid], t_speed, speed) >= cfg.track_min_speed_mps
    if moving.sum() < 2:
        raise ToolError(f"{path}: fewer than two fixes at >= {cfg.track_min_speed_mps} m/s")
    em, nm = e[moving], n[moving]
    keep = thin_by_spacing(em, nm, cfg.min_spacing_m)
    if keep.size < 2:
        raise ToolError(f"{path}: the GPS track does not move {cfg.min_spacing_m} m")
    te = moving_average_interior(em[keep], cfg.smooth_vertices)
    tn = moving_average_interior(nm[keep], cfg.smooth_vertices)
    tlat, tlon = (np.asarray(a) for a in frame.to_geodetic(te, tn))
    geom = LineGeometry(
        "Dresden car drive 2014-03-26 (digitised from its own GPS)", tlat, tlon, None,
        source=f"{path.name}: GPS fixes at >= {cfg.track_min_speed_mps} m/s thinned to >= "
               f"{cfg.min_spacing_m} m, {cfg.smooth_vertices}-vertex moving average",
        attribution=ATTRIBUTION,
    )
    track_path = out / "track.db"
    try:
        create_database(track_path, [geom], overwrite=True,
                        config=BuildConfig(junction_tolerance_m=cfg.junction_tolerance_m,
                                           smoothing_sigma_m=cfg.track_smoothing_sigma_m))
        db = TrackDatabase.open(track_path)
    except TrackDbError as exc:
        raise ToolError(f"cannot build the track from {path}: {exc}") from exc
    line = db.line()
    if line.s_m.size != keep.size:
        raise ToolError(f"track build changed the vertex count ({keep.size} -> {line.s_m.size})")
    fe, fn = (np.asarray(a) for a in db.to_local(glat[valid], glon[valid]))
    # each fix's expected segment: the one of the last track vertex taken at or before it
    src_index = np.flatnonzero(moving)[keep]
    hint = np.clip(np.searchsorted(src_index, np.arange(fe.size), side="right") - 1, 0, keep.size - 2)
    fix_s, fix_dist = project_along(line.s_m, line.east_m, line.north_m, fe, fn, hint)
    line_id = int(line.line_id)
    length_m = float(line.length_m)
    db.close()

    # --- datagrams
    tl = Timeline(cfg.schedule)
    t0, t1 = float(t[0]), float(t[-1])
    s0 = float(fix_s[0])
    tg0 = float(t_pos[valid][0])  # GROUND TRUTH carries the state at the first fix's sampling time
    v0 = float(np.interp(tg0, t_speed, speed))
    add_control(tl, t0, t1, lambda seq: GroundTruth(seq, v0, 0.0, 0.0, s0, line_id, tg0))
    for ti, fi, wi in zip(t.tolist(), f.tolist(), w.tolist(), strict=True):
        tl.add("imu", ti, lambda seq, ti=ti, fi=fi, wi=wi: ImuSample(seq, *fi, *wi, ti))
    # sent when the logger read them (t[g]), dated by their sampling time (t_speed, t_pos)
    for ts, ti, v in zip(t[g].tolist(), t_speed.tolist(), speed.tolist(), strict=True):
        tl.add("odometer", ts, lambda seq, ti=ti, v=v: OdometerSample(seq, v, cfg.speed_sigma_mps, ti))
    epe = d["epe"][g]
    for i, (ts, ti) in enumerate(zip(t[g].tolist(), t_pos.tolist(), strict=True)):
        sig = float(epe[i]) if epe[i] > 0 else None
        tl.add("gps", ts, lambda seq, i=i, ti=ti, sig=sig: GpsFix(
            seq, float(glat[i]), float(glon[i]), float(galt[i]), int(fixq[i]),
            int(min(max(d["satellites_used"][g][i], 0), 255)),
            sig if sig is not None else 1e5, ti))
    packets = tl.packets()
    # the merge must hold every measurement until it is processed in epoch order
    wait = float(np.max(t[g] - np.minimum(t_speed, t_pos))) + cfg.schedule.transport_delay_s
    hold = math.ceil((wait + 0.2) * 100.0) / 100.0
    capture = out / "capture.pcap"
    write_pcap(packets, capture, cfg.schedule.listener_port)
    ref = out / "gnss_on_track.csv"
    write_truth_csv(
        ref, {"epoch": t_pos[valid], "arc_length": fix_s, "cross_track": fix_dist, "epe": epe[valid]},
        {"epoch": ".3f", "arc_length": ".4f", "cross_track": ".4f", "epe": ".2f"},
    )
    by_module = count_by_module(packets)
    meta = {
        "source": "balzer82/Kalman 2014-03-26-000-Data.csv (real car drive in Dresden)",
        "licence": "CC BY-SA 2.0",
        "attribution": ATTRIBUTION,
        "source_file": {path.name: hashlib.sha256(path.read_bytes()).hexdigest()},
        "real": {
            "imu": "every row; FRD f = (-ax, ay, az), w = (rollrate, -pitchrate, -yawrate) deg/s -> rad/s",
            "imu_levelling": {"applied": cfg.level_imu, "roll_deg": math.degrees(roll),
                              "pitch_deg": math.degrees(pitch),
                              "how": "roll/pitch of the mean specific force over the drive"},
            "odometer": f"speed column km/h -> m/s at each GPS epoch, sigma {cfg.speed_sigma_mps} m/s "
                        "(constant, chosen: the log has none; likely GNSS speed over ground)",
            "gps": "lat, lon, altitude, epe as sigma_h, fix>=2 -> quality 1, satellites_used",
            "gnss_timing": {
                "dating": "each epoch by the receiver's time tag (the `time` column) mapped to the logger "
                          "clock with a constant offset; sent at the logger time of the row that first "
                          "holds it (its real arrival)",
                "tag_to_logger_offset_s": clock_offset,
                "read_delay_minus_offset_s": {"min": float(np.min(read_delay) - clock_offset),
                                              "max": float(np.max(read_delay) - clock_offset)},
                "logger_minus_tag_drift": drift,
                "epochs_dropped_out_of_order": dropped_out_of_order,
                "speed_latency_s": latency,
                "speed_latency_estimated": cfg.gnss_latency_s is None,
                "speed_latency_correlation": lag_corr,
                "speed_latency_slope_f_forward_on_dv_dt": lag_slope,
                "position_lead_s": lead,
                "position_lead_estimated": cfg.position_lead_s is None,
                "position_lead_correlation": lead_corr,
                "position_lead_slope_position_speed_on_speed": lead_slope,
                "position_latency_s": pos_latency,
                "check_gyro_vs_gps_heading_rate": {"lag_s": yaw_lag, "correlation": yaw_corr,
                                                   "slope_gz_on_heading_rate": yaw_slope},
                "how": "speed latency: the lag maximising the correlation of d(speed)/dt with the IMU's "
                       "forward specific force; position lead: the lag of the speed column behind the "
                       "speed derived from the positions; position latency = speed latency - lead",
            },
        },
        "synthesised": {},
        "no_truth": "track digitised from the same GPS: only self-consistency can be checked "
                    "(gnss_on_track.csv: epoch, arc_length of each fix projected on the track)",
        "capture": {
            "listener_port": cfg.schedule.listener_port,
            "source_ports": {m: p for m, p in sorted(MODULE_PORTS.items()) if m in by_module},
            "timestamps": f"logger time (unix s) + {cfg.schedule.transport_delay_s} s transport delay",
            "epochs": "every measurement datagram carries its epoch: IMU logger millis / 1000; GPS and speed "
                      "their sampling time (see real.gnss_timing)",
            "control": f"GROUND TRUTH {cfg.schedule.ground_truth_lead_s} s before the first row (dated at "
                       "the first fix's sampling time: its arc length on the track, the speed there), "
                       f"STROBE every {cfg.schedule.strobe_interval_s} s, STOP 0.5 s after the last row",
            "datagrams": by_module,
        },
        "recommended_listener": {
            "merge.hold_s": hold,
            "why": "GPS and speed arrive up to this long (less 0.2 s) after their epoch; the merge must "
                   "wait that long so the filter gets them in time order (it drops GNSS older than 0.5 s)",
        },
        "track": {"vertices": int(keep.size), "length_m": length_m, "min_spacing_m": cfg.min_spacing_m,
                  "smooth_vertices": cfg.smooth_vertices, "min_speed_mps": cfg.track_min_speed_mps,
                  "fixes_used": int(moving.sum()), "profile_smoothing_sigma_m": cfg.track_smoothing_sigma_m},
    }
    metadata = out / "metadata.json"
    write_json(metadata, meta)
    return Conversion(out, capture, track_path, None, metadata, len(packets), by_module)
