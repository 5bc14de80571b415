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
  It updates exactly with the GPS epochs, so it is most likely the receiver's speed over ground (not a
  wheel sensor): it is not independent of the GPS positions. REAL.
* GPS: each new GPS epoch (the ``time`` column changes, 10 Hz): lat, lon, altitude, ``epe`` as sigma_h,
  fix 2/3 -> NMEA quality 1 (else 0), ``satellites_used``, dated by the ``millis`` of the row where it
  first appears (the logger's clock). REAL.
* Track: digitised from those GPS fixes themselves (there is no other geometry): thinned to at least
  ``min_spacing_m`` between vertices, then a ``smooth_vertices``-point moving average on the interior
  vertices. No altitude: the GPS altitude is far too noisy for a grade (it would feed the filter
  metres-per-second-squared of false gravity along the track), so the track is taken as level.
  Because the track comes from the same GPS the filter uses, results can only be checked for
  self-consistency (gnss_on_track.csv: each fix projected on the track; see tools.adapters.evaluate).
* Control: GROUND TRUTH at the first row (arc length of the first fix projected on the track, speed of
  the first row), STROBE every second, STOP 0.5 s after the last row.
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
    #: age of the GPS fix and speed when the logger records them [s]; None: estimated from the data
    #: (the lag that best aligns d(speed)/dt with the IMU's forward specific force)
    gnss_latency_s: float | None = None
    max_latency_s: float = 3.0  #: largest latency searched by the estimate [s]
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


def estimate_latency_s(
    t_s: np.ndarray, f_forward_mps2: np.ndarray, t_speed_s: np.ndarray, speed_mps: np.ndarray,
    max_lag_s: float = 3.0, step_s: float = 0.05,
) -> tuple[float, float, float]:
    """(lag_s, correlation, slope): how much later than the IMU the speed reflects the same acceleration.

    Both signals on a 0.1 s grid, Gaussian-smoothed (sigma 0.5 s); d(speed)/dt is correlated with the
    forward specific force shifted by each candidate lag in [0, max_lag_s]; the best lag wins. The slope
    of f_forward on d(speed)/dt at that lag is a scale check (1 for a consistent pair)."""
    from scipy.ndimage import gaussian_filter1d

    lo, hi = max(t_s[0], t_speed_s[0]) + max_lag_s, min(t_s[-1], t_speed_s[-1])
    if hi - lo < 10.0:
        raise ToolError("too short a log to estimate the GNSS latency (needs > 10 s beyond the lag range)")
    grid = np.arange(lo, hi, 0.1)
    v = gaussian_filter1d(np.interp(grid, t_speed_s, speed_mps), 5.0)
    dv = np.gradient(v, grid)
    best = (-2.0, 0.0, 0.0)
    for lag in np.arange(0.0, max_lag_s + 1e-9, step_s):
        fx = gaussian_filter1d(np.interp(grid - lag, t_s, f_forward_mps2), 5.0)
        c = float(np.corrcoef(dv, fx)[0, 1])
        if c > best[0]:
            best = (c, float(lag), float(np.polyfit(dv, fx, 1)[0]))
    return best[1], best[0], best[2]


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

    # --- GPS epochs
    g = gps_epochs(d)
    glat, glon, galt = d["latitude"][g], d["longitude"][g], d["altitude"][g]
    fixq = np.where(d["fix"][g] >= 2.0, 1, 0).astype(int)
    valid = fixq > 0
    if valid.sum() < 2:
        raise ToolError(f"{path}: fewer than two GPS epochs with a fix")

    # --- GNSS latency: the logger records fix and speed late; their epochs are moved back by it
    lag_corr = lag_slope = math.nan
    if cfg.gnss_latency_s is None:
        latency, lag_corr, lag_slope = estimate_latency_s(t, f[:, 0], t[g], d["speed"][g] * KMH,
                                                          cfg.max_latency_s)
    else:
        latency = float(cfg.gnss_latency_s)
    gt = t[g] - latency  # sampling time of each GPS epoch (fix and speed)

    # --- track from the valid fixes
    frame = LocalFrame.from_proj(centred_proj_string(glat[valid], glon[valid]))
    e, n = (np.asarray(a) for a in frame.to_local(glat[valid], glon[valid]))
    keep = thin_by_spacing(e, n, cfg.min_spacing_m)
    if keep.size < 2:
        raise ToolError(f"{path}: the GPS track does not move {cfg.min_spacing_m} m")
    te = moving_average_interior(e[keep], cfg.smooth_vertices)
    tn = moving_average_interior(n[keep], cfg.smooth_vertices)
    tlat, tlon = (np.asarray(a) for a in frame.to_geodetic(te, tn))
    geom = LineGeometry(
        "Dresden car drive 2014-03-26 (digitised from its own GPS)", tlat, tlon, None,
        source=f"{path.name}: GPS epochs thinned to >= {cfg.min_spacing_m} m, "
               f"{cfg.smooth_vertices}-vertex moving average",
        attribution=ATTRIBUTION,
    )
    track_path = out / "track.db"
    try:
        create_database(track_path, [geom], overwrite=True,
                        config=BuildConfig(junction_tolerance_m=cfg.junction_tolerance_m))
        db = TrackDatabase.open(track_path)
    except TrackDbError as exc:
        raise ToolError(f"cannot build the track from {path}: {exc}") from exc
    line = db.line()
    if line.s_m.size != keep.size:
        raise ToolError(f"track build changed the vertex count ({keep.size} -> {line.s_m.size})")
    fe, fn = (np.asarray(a) for a in db.to_local(glat[valid], glon[valid]))
    hint = np.clip(np.searchsorted(keep, np.arange(fe.size), side="right") - 1, 0, keep.size - 2)
    fix_s, fix_dist = project_along(line.s_m, line.east_m, line.north_m, fe, fn, hint)
    line_id = int(line.line_id)
    length_m = float(line.length_m)
    db.close()

    # --- datagrams
    tl = Timeline(cfg.schedule)
    t0, t1 = float(t[0]), float(t[-1])
    v0 = float(d["speed"][g][valid][0]) * KMH
    s0 = float(fix_s[0])
    tg0 = float(gt[valid][0])  # GROUND TRUTH carries the state at the first fix's sampling time
    add_control(tl, t0, t1, lambda seq: GroundTruth(seq, v0, 0.0, 0.0, s0, line_id, tg0))
    for ti, fi, wi in zip(t.tolist(), f.tolist(), w.tolist(), strict=True):
        tl.add("imu", ti, lambda seq, ti=ti, fi=fi, wi=wi: ImuSample(seq, *fi, *wi, ti))
    # sent when the logger recorded them (t[g]), dated by their sampling time (gt)
    for ts, ti, v in zip(t[g].tolist(), gt.tolist(), (d["speed"][g] * KMH).tolist(), strict=True):
        tl.add("odometer", ts, lambda seq, ti=ti, v=v: OdometerSample(seq, v, cfg.speed_sigma_mps, ti))
    epe = d["epe"][g]
    for i, (ts, ti) in enumerate(zip(t[g].tolist(), gt.tolist(), strict=True)):
        sig = float(epe[i]) if epe[i] > 0 else None
        tl.add("gps", ts, lambda seq, i=i, ti=ti, sig=sig: GpsFix(
            seq, float(glat[i]), float(glon[i]), float(galt[i]), int(fixq[i]),
            int(min(max(d["satellites_used"][g][i], 0), 255)),
            sig if sig is not None else 1e5, ti))
    packets = tl.packets()
    capture = out / "capture.pcap"
    write_pcap(packets, capture, cfg.schedule.listener_port)
    ref = out / "gnss_on_track.csv"
    write_truth_csv(
        ref, {"epoch": gt[valid], "arc_length": fix_s, "cross_track": fix_dist, "epe": epe[valid]},
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
            "gnss_latency": {
                "latency_s": latency,
                "estimated": cfg.gnss_latency_s is None,
                "correlation": lag_corr,
                "slope_f_forward_on_dv_dt": lag_slope,
                "how": "GPS and speed datagrams are sent at the row's logger time, with epoch = logger "
                       "time - latency (the lag maximising the correlation of d(speed)/dt with the "
                       "IMU's forward specific force)",
            },
        },
        "synthesised": {},
        "no_truth": "track digitised from the same GPS: only self-consistency can be checked "
                    "(gnss_on_track.csv: epoch, arc_length of each fix projected on the track)",
        "capture": {
            "listener_port": cfg.schedule.listener_port,
            "source_ports": {m: p for m, p in sorted(MODULE_PORTS.items()) if m in by_module},
            "timestamps": f"logger time (unix s) + {cfg.schedule.transport_delay_s} s transport delay",
            "epochs": "every measurement datagram carries its epoch (logger millis / 1000)",
            "control": f"GROUND TRUTH {cfg.schedule.ground_truth_lead_s} s before the first row (first "
                       "fix projected on the track, first speed), STROBE every "
                       f"{cfg.schedule.strobe_interval_s} s, STOP 0.5 s after the last row",
            "datagrams": by_module,
        },
        "recommended_listener": {
            "merge.hold_s": round(latency + 0.2, 2),
            "why": "GPS and speed arrive `latency` after their epoch; the merge must wait that long so "
                   "the filter gets them in time order (the filter drops GNSS older than 0.5 s)",
        },
        "track": {"vertices": int(keep.size), "length_m": length_m, "min_spacing_m": cfg.min_spacing_m,
                  "smooth_vertices": cfg.smooth_vertices},
    }
    metadata = out / "metadata.json"
    write_json(metadata, meta)
    return Conversion(out, capture, track_path, None, metadata, len(packets), by_module)
