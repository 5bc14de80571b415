"""smartLoc (TU Chemnitz, CC BY-SA 4.0), Berlin Potsdamer Platz: a real car's odometry with ground truth.

What goes into the capture (docs/real-data.md has the reasons and the measured results):

* ODOMETER: every ``odom3`` record unchanged -- the car's CAN forward speed ``vx`` [m/s] with the
  dataset's own variance as sigma (sqrt(0.0025) = 0.05 m/s), dated by the record's time stamp. REAL.
* No IMU datagrams. The dataset has a yaw rate but no accelerometer, and an IMU datagram needs a full
  specific-force vector; inventing accelerations (e.g. from differentiated odometer speed) would pass
  synthetic data off as an IMU. The filter runs odometer-driven: without an IMU it predicts with a
  constant-velocity model (``FilterConfig.no_imu_accel_psd_m2ps3``), and reports ``imu_timeout``.
* GPS: SYNTHESISED from the ground truth at ``rate_hz`` (1 Hz): the truth position (ECEF, linearly
  interpolated at the fix time) plus a seeded first-order Gauss-Markov + white horizontal error and a
  white vertical error (defaults: the simulator's ``standalone`` preset). Or, with
  ``gnss_source="spp"``, REAL: a robust single-point solution from the dataset's urban-canyon
  pseudoranges at the same rate (:mod:`tools.adapters.spp`; epochs without a solution are sent as
  "no fix").
* Track: one line digitised from the ground-truth trajectory (ECEF -> WGS84 with pyproj), thinned so
  that vertices are at least ``min_spacing_m`` apart (this also drops the standstill samples); no
  smoothing (the reference trajectory is centimetre-grade already).
* Truth: each ground-truth sample projected on that line, searching only the segments around its own
  place in the trajectory (the car drives one street twice, so the line passes the same place twice).
* Control: GROUND TRUTH (truth arc length and speed) at the first time stamp, STROBE every second,
  STOP 0.5 s after the last sample. Every measurement datagram carries its epoch.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tools.adapters.common import (
    MODULE_PORTS,
    Conversion,
    GnssNoise,
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
from tools.adapters.spp import SppConfig
from tools.errors import ToolError

GT_FILE = "Berlin_Potsdamer_Platz_GT.txt"
INPUT_FILE = "Berlin_Potsdamer_Platz_Input.txt"
#: EGM2008 geoid undulation near Potsdamer Platz, Berlin (about 39 m; only fills the wire's "above MSL"
#: altitude field, which the along-track filter does not use) [m]
GEOID_UNDULATION_M = 39.0
ATTRIBUTION = (
    "smartLoc dataset, Berlin Potsdamer Platz, (c) 2016-2022 Reisdorf, Pfeifer, Bressler, Bauer, Weissig, "
    "Lange (TU Chemnitz), CC BY-SA 4.0; derived data under the same licence"
)
OUTPUT_NAMES = ("capture.pcap", "track.db", "truth.csv", "metadata.json")


def default_source_dir() -> Path:
    """The bundled copy (tools/data/smartloc/: the ground truth and the odometry records)."""
    return Path(__file__).resolve().parent.parent / "data" / "smartloc"


@dataclass(frozen=True)
class SmartLocConfig:
    """Parameters of the smartLoc conversion."""

    seed: int = 1  #: seed of the synthesised GNSS errors
    gnss: GnssNoise = field(default_factory=GnssNoise)  #: synthesised GNSS error model
    min_spacing_m: float = 1.0  #: smallest distance between track vertices [m]
    gnss_source: str = "synthetic"  #: "synthetic" (truth + noise) or "spp" (robust single-point solution)
    spp: SppConfig = field(default_factory=SppConfig)  #: settings of the single-point solution
    #: vertex distance that makes a junction [m]: 1 cm, because where the drive passes a place twice
    #: (the two lanes of one street, opposite directions) the line is not a switch the car could take
    junction_tolerance_m: float = 0.01
    #: the capture clock runs 1 s ahead of the dataset's time stamps (which start at 0), so that
    #: GROUND TRUTH, sent 0.1 s before the first sample, has a non-negative capture timestamp
    schedule: ScheduleConfig = field(default_factory=lambda: ScheduleConfig(host_clock_offset_s=1.0))

    def __post_init__(self) -> None:
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise ToolError(f"seed must be a non-negative integer, got {self.seed!r}")
        if not (math.isfinite(self.min_spacing_m) and self.min_spacing_m > 0):
            raise ToolError(f"min_spacing_m must be > 0, got {self.min_spacing_m!r}")
        if self.gnss_source not in ("synthetic", "spp"):
            raise ToolError(f"gnss_source must be 'synthetic' or 'spp', got {self.gnss_source!r}")


@dataclass(frozen=True)
class SmartLocData:
    """The records the adapter uses, as read from the source files."""

    gt_t_s: np.ndarray  #: ground-truth time stamps [s]
    gt_ecef_m: np.ndarray  #: (n, 3) ground-truth ECEF X, Y, Z [m]
    odo_t_s: np.ndarray  #: odometry time stamps [s]
    odo_speed_mps: np.ndarray  #: forward speed vx [m/s]
    odo_sigma_mps: np.ndarray  #: sqrt of the speed variance [m/s]
    odo_yaw_rate_radps: np.ndarray  #: wz [rad/s] (read, checked, not sent: see module doc)


def _rows(path: Path, tag: str, ncols: int) -> tuple[np.ndarray, list[int]]:
    """Numeric columns 1..ncols of the lines starting with ``tag``, and their line numbers."""
    if not path.is_file():
        raise ToolError(f"smartLoc source file missing: {path}")
    rows: list[list[float]] = []
    lines: list[int] = []
    try:
        with open(path, encoding="ascii") as fh:
            for no, line in enumerate(fh, start=1):
                parts = line.split()
                if not parts or parts[0] != tag:
                    continue
                if len(parts) < ncols + 1:
                    raise ToolError(
                        f"{path}:{no}: {tag} record has {len(parts) - 1} fields, expected {ncols}"
                    )
                try:
                    vals = [float(x) for x in parts[1 : ncols + 1]]
                except ValueError:
                    raise ToolError(f"{path}:{no}: {tag} record has a non-numeric field") from None
                if not all(math.isfinite(v) for v in vals):
                    raise ToolError(f"{path}:{no}: {tag} record has a non-finite field")
                rows.append(vals)
                lines.append(no)
    except UnicodeDecodeError as exc:
        raise ToolError(f"{path}: not a smartLoc text file ({exc.reason})") from None
    except OSError as exc:
        raise ToolError(f"cannot read {path}: {exc}") from None
    if not rows:
        raise ToolError(f"{path}: no {tag} records")
    return np.asarray(rows, dtype=np.float64), lines


def _check_increasing(t: np.ndarray, path: Path, lines: list[int], what: str) -> None:
    bad = np.flatnonzero(np.diff(t) <= 0.0)
    if bad.size:
        k = int(bad[0]) + 1
        raise ToolError(
            f"{path}:{lines[k]}: {what} time stamp {t[k]} does not increase (previous {t[k - 1]})"
        )


def read_smartloc(src_dir: str | Path) -> SmartLocData:
    """Read and check the ground truth (``point3``) and the odometry (``odom3``) of ``src_dir``."""
    src = Path(src_dir)
    if not src.is_dir():
        raise ToolError(f"smartLoc source directory not found: {src}")
    gt_path, in_path = src / GT_FILE, src / INPUT_FILE
    gt, gt_lines = _rows(gt_path, "point3", 4)
    odo, odo_lines = _rows(in_path, "odom3", 13)
    _check_increasing(gt[:, 0], gt_path, gt_lines, "ground-truth")
    _check_increasing(odo[:, 0], in_path, odo_lines, "odometry")
    r = np.linalg.norm(gt[:, 1:4], axis=1)
    bad = np.flatnonzero((r < 6.30e6) | (r > 6.42e6))
    if bad.size:
        k = int(bad[0])
        raise ToolError(
            f"{gt_path}:{gt_lines[k]}: ECEF position {r[k]:.0f} m from the geocentre is not on the Earth"
        )
    var = odo[:, 7]
    bad = np.flatnonzero(var <= 0.0)
    if bad.size:
        k = int(bad[0])
        raise ToolError(f"{in_path}:{odo_lines[k]}: odometry speed variance {var[k]} is not positive")
    bad = np.flatnonzero((odo[:, 1] < -150.0) | (odo[:, 1] > 150.0))
    if bad.size:
        k = int(bad[0])
        raise ToolError(f"{in_path}:{odo_lines[k]}: odometry speed {odo[k, 1]} m/s out of range")
    if gt.shape[0] < 2:
        raise ToolError(f"{gt_path}: at least two ground-truth records are needed")
    return SmartLocData(
        gt_t_s=gt[:, 0].copy(), gt_ecef_m=gt[:, 1:4].copy(),
        odo_t_s=odo[:, 0].copy(), odo_speed_mps=odo[:, 1].copy(), odo_sigma_mps=np.sqrt(var),
        odo_yaw_rate_radps=odo[:, 6].copy(),
    )


def ecef_to_geodetic(ecef_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lat_deg, lon_deg, ellipsoidal height_m) of WGS84 ECEF positions (pyproj EPSG:4978 -> 4979)."""
    from pyproj import Transformer

    tr = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    lon, lat, h = tr.transform(ecef_m[:, 0], ecef_m[:, 1], ecef_m[:, 2])
    return np.asarray(lat), np.asarray(lon), np.asarray(h)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def convert_smartloc(
    src_dir: str | Path | None, out_dir: str | Path, config: SmartLocConfig | None = None,
    overwrite: bool = False,
) -> Conversion:
    """Write capture.pcap, track.db, truth.csv and metadata.json for the smartLoc drive into ``out_dir``."""
    from listener.codec import GpsFix, GroundTruth, OdometerSample
    from tools.adapters.smartloc_gnss import fix_errors, gnss_metadata, spp_fixes, synthetic_fixes
    from track_db import TrackDatabase
    from track_db.build import BuildConfig, LineGeometry, create_database
    from track_db.errors import TrackDbError
    from track_db.geodesy import LocalFrame, centred_proj_string

    cfg = config or SmartLocConfig()
    src = default_source_dir() if src_dir is None else Path(src_dir)
    data = read_smartloc(src)
    out = prepare_out_dir(out_dir, OUTPUT_NAMES, overwrite)

    # --- track: the ground-truth trajectory, thinned
    lat, lon, h = ecef_to_geodetic(data.gt_ecef_m)
    frame = LocalFrame.from_proj(centred_proj_string(lat, lon))
    east, north = (np.asarray(a) for a in frame.to_local(lat, lon))
    keep = thin_by_spacing(east, north, cfg.min_spacing_m)
    if keep.size < 2:
        raise ToolError(f"{src / GT_FILE}: the ground truth does not move {cfg.min_spacing_m} m")
    geom = LineGeometry(
        "smartLoc Berlin Potsdamer Platz (digitised from the ground truth)",
        lat[keep], lon[keep], h[keep] - GEOID_UNDULATION_M,
        source=f"{GT_FILE}: point3 records thinned to >= {cfg.min_spacing_m} m vertex spacing",
        attribution=ATTRIBUTION,
    )
    track_path = out / "track.db"
    try:
        create_database(track_path, [geom], overwrite=True,
                        config=BuildConfig(junction_tolerance_m=cfg.junction_tolerance_m))
        db = TrackDatabase.open(track_path)
    except TrackDbError as exc:
        raise ToolError(f"cannot build the track from {src / GT_FILE}: {exc}") from exc
    line = db.line()
    if line.s_m.size != keep.size:
        raise ToolError(f"track build changed the vertex count ({keep.size} -> {line.s_m.size})")

    # --- truth: local projection of every ground-truth sample on its own stretch of the line
    ge, gn = (np.asarray(a) for a in db.to_local(lat, lon))
    hint = np.clip(np.searchsorted(keep, np.arange(lat.size), side="right") - 1, 0, keep.size - 2)
    truth_s, truth_off = project_along(line.s_m, line.east_m, line.north_m, ge, gn, hint)
    truth_v = np.gradient(truth_s, data.gt_t_s)
    db.close()

    # --- GNSS at rate_hz inside the truth's time span: synthesised, or solved from the pseudoranges
    noise = cfg.gnss
    t0, t1 = float(data.gt_t_s[0]), float(data.gt_t_s[-1])
    if cfg.gnss_source == "synthetic":
        gnss = synthetic_fixes(data, noise, cfg.seed)
    else:
        gnss = spp_fixes(src / INPUT_FILE, data, noise.rate_hz, cfg.spp)
    gnss_stats = fix_errors(gnss, data)

    # --- datagrams
    tl = Timeline(cfg.schedule)
    add_control(tl, t0, max(t1, float(data.odo_t_s[-1])), lambda seq: GroundTruth(
        seq, float(truth_v[0]), 0.0, 0.0, float(truth_s[0]), int(line.line_id), t0))
    for t, v, sg in zip(data.odo_t_s.tolist(), data.odo_speed_mps.tolist(), data.odo_sigma_mps.tolist(),
                        strict=True):
        tl.add("odometer", t, lambda seq, t=t, v=v, sg=sg: OdometerSample(seq, v, sg, t))
    for fix in gnss:
        tl.add("gps", fix.t_s, lambda seq, f=fix: GpsFix(
            seq, f.lat_deg, f.lon_deg, f.alt_m, f.fix_quality, f.num_sv, f.sigma_h_m, f.t_s))
    packets = tl.packets()
    capture = out / "capture.pcap"
    write_pcap(packets, capture, cfg.schedule.listener_port)

    truth = out / "truth.csv"
    write_truth_csv(
        truth,
        {"epoch": data.gt_t_s, "arc_length": truth_s, "speed": truth_v, "lat": lat, "lon": lon,
         "offset": truth_off},
        {"epoch": ".3f", "arc_length": ".4f", "speed": ".4f", "lat": ".9f", "lon": ".9f", "offset": ".4f"},
    )
    by_module = count_by_module(packets)
    meta = {
        "source": "smartLoc, Berlin Potsdamer Platz (github.com/TUC-ProAut/libRSF datasets/smartLoc)",
        "licence": "CC BY-SA 4.0",
        "attribution": ATTRIBUTION,
        "source_files": {GT_FILE: _sha256(src / GT_FILE), INPUT_FILE: _sha256(src / INPUT_FILE)},
        "real": {
            "odometer": "odom3 forward speed vx [m/s], sigma = sqrt(variance of vx) from the record",
            "track": "digitised from the ground truth (point3, ECEF -> WGS84 by pyproj EPSG:4978->4979)",
            "truth": "ground truth projected on the track, locally (truth.csv: epoch, arc_length, speed)",
        },
        "gnss": gnss_metadata(cfg.gnss_source, cfg.seed, cfg.gnss, cfg.spp, gnss_stats),
        "not_used": {
            "yaw_rate": "odom3 wz is real but not sent: an IMU datagram needs a specific-force vector "
                        "the car did not record (no accelerometer); no accelerations are invented",
            "pseudoranges": "used only with gnss_source 'spp'" if cfg.gnss_source == "synthetic"
                            else "used: robust single-point solution (see gnss)",
        },
        "capture": {
            "listener_port": cfg.schedule.listener_port,
            "source_ports": {m: p for m, p in sorted(MODULE_PORTS.items()) if m in by_module},
            "timestamps": f"sensor time + {cfg.schedule.host_clock_offset_s} s host clock offset + "
                          f"{cfg.schedule.transport_delay_s} s transport delay",
            "epochs": "every measurement datagram carries its epoch (dataset time stamp [s])",
            "control": f"GROUND TRUTH {cfg.schedule.ground_truth_lead_s} s before the first epoch (truth arc "
                       "length and speed at the first epoch), STROBE every "
                       f"{cfg.schedule.strobe_interval_s} s, STOP 0.5 s after the last sample",
            "datagrams": by_module,
        },
        "track": {
            "vertices": int(keep.size),
            "length_m": float(line.length_m),
            "min_spacing_m": cfg.min_spacing_m,
            "truth_offset_max_m": float(np.max(truth_off)),
        },
        "recommended_filter": {"imu": "mems-train", "odometer": "wheel-odometer", "gps": "standalone",
                               "note": "no IMU datagrams: the filter runs odometer-driven"},
    }
    metadata = out / "metadata.json"
    write_json(metadata, meta)
    return Conversion(out, capture, track_path, truth, metadata, len(packets), by_module)

