"""Building blocks shared by the real-data adapters: datagram schedule, pcap writer, track digitising,
local projection of a trajectory onto its line, synthesised GNSS noise and the output files.

Every function is pure (arrays and messages in, arrays and messages out) except the ``write_*``
writers, which raise :class:`tools.errors.ToolError` naming the file when they cannot write.
"""

from __future__ import annotations

import csv
import json
import math
import socket
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from tools.errors import ToolError

#: UDP source port of each sending module in the captures (the simulator's defaults, docs/architecture.md)
MODULE_PORTS: dict[str, int] = {"control": 47000, "imu": 47001, "odometer": 47002, "gps": 47003}
SRC_IP = "127.0.0.1"  #: source address of the modules in the captures
DST_IP = "127.0.0.1"  #: listener host address in the captures
SRC_MAC = b"\x02\x00\x00\x00\x00\x01"  #: locally administered MAC of the sensor set
DST_MAC = b"\x02\x00\x00\x00\x00\x02"  #: locally administered MAC of the listener's host
STOP_LAG_S = 0.5  #: STOP is sent this long after the last sample [s]


@dataclass(frozen=True)
class ScheduleConfig:
    """How sensor samples become datagrams on the listener's host."""

    transport_delay_s: float = 0.002  #: sampling time -> capture (arrival) time, every module [s]
    host_clock_offset_s: float = 0.0  #: capture clock minus sensor-set time [s]
    ground_truth_lead_s: float = 0.1  #: GROUND TRUTH is sent this long before the first sample [s]
    strobe_interval_s: float = 1.0  #: STROBE period [s]
    listener_port: int = 48000  #: UDP destination port (listener.defaults.DEFAULT_LISTENER_PORT)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.transport_delay_s) and self.transport_delay_s >= 0.0):
            raise ToolError(f"transport_delay_s must be >= 0, got {self.transport_delay_s!r}")
        if not (math.isfinite(self.ground_truth_lead_s) and self.ground_truth_lead_s >= 0.0):
            raise ToolError(f"ground_truth_lead_s must be >= 0, got {self.ground_truth_lead_s!r}")
        if not math.isfinite(self.host_clock_offset_s):
            raise ToolError(f"host_clock_offset_s must be finite, got {self.host_clock_offset_s!r}")
        if not (math.isfinite(self.strobe_interval_s) and self.strobe_interval_s > 0.0):
            raise ToolError(f"strobe_interval_s must be > 0, got {self.strobe_interval_s!r}")
        if not 1 <= int(self.listener_port) <= 65535:
            raise ToolError(f"listener_port must be in 1..65535, got {self.listener_port!r}")


@dataclass(frozen=True, slots=True)
class Packet:
    """One datagram as captured on the listener's host."""

    arrival_s: float  #: capture timestamp [s] (sensor-set time + host clock offset + transport delay)
    src_port: int  #: UDP source port of the module
    payload: bytes  #: INPUT_PROTOCOL datagram
    module: str  #: control, imu, odometer or gps


@dataclass
class Timeline:
    """Datagrams of all modules; each module numbers its own datagrams from 0 (uint16, wrapping)."""

    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)
    _items: list[tuple[float, int, int, str, object]] = field(default_factory=list)
    _seq: dict[str, int] = field(default_factory=dict)

    def next_seq(self, module: str) -> int:
        seq = self._seq.get(module, 0)
        self._seq[module] = (seq + 1) & 0xFFFF
        return seq

    def add(self, module: str, send_s: float, make) -> None:
        """Queue ``make(seq)`` (an InputMessage) sent by ``module`` at sensor-set time ``send_s``.

        Sequence numbers follow the order of ``add`` calls per module, so call in sending order."""
        msg = make(self.next_seq(module))
        self._items.append((float(send_s), len(self._items), MODULE_PORTS[module], module, msg))

    def packets(self) -> list[Packet]:
        """Encoded packets in capture order (arrival time, then insertion order)."""
        from listener.codec import encode_input

        delay = self.schedule.transport_delay_s + self.schedule.host_clock_offset_s
        ordered = sorted(self._items, key=lambda it: (it[0], it[1]))
        out = [Packet(t + delay, port, encode_input(msg), module) for t, _, port, module, msg in ordered]
        if out and out[0].arrival_s < 0.0:
            raise ToolError(f"capture timestamp {out[0].arrival_s} s is negative: raise host_clock_offset_s")
        return out


def add_control(timeline: Timeline, t_start_s: float, t_end_s: float, ground_truth) -> None:
    """GROUND TRUTH ``ground_truth_lead_s`` before the start (it carries the state at the start, like the
    simulator's), a STROBE every ``strobe_interval_s`` from the start, STOP 0.5 s after the end.

    ``ground_truth(seq)`` builds the GROUND TRUTH message; STROBE carries its own sending time."""
    from listener.codec import Stop, Strobe

    timeline.add("control", t_start_s - timeline.schedule.ground_truth_lead_s, ground_truth)
    step = timeline.schedule.strobe_interval_s
    n = int(math.floor((t_end_s - t_start_s) / step + 1e-9)) + 1
    for k in range(n):
        t = t_start_s + k * step
        timeline.add("control", t, lambda seq, t=t: Strobe(seq, t))
    timeline.add("control", t_end_s + STOP_LAG_S, lambda seq: Stop(seq))


def write_pcap(packets: Sequence[Packet], path: str | Path, listener_port: int) -> int:
    """Classic pcap (Ethernet II / IPv4 / UDP built with dpkt, like the simulator's captures); frames."""
    import dpkt

    src_ip = socket.inet_aton(SRC_IP)
    dst_ip = socket.inet_aton(DST_IP)
    ip_ids: dict[int, int] = {}
    try:
        with open(path, "wb") as fh:
            writer = dpkt.pcap.Writer(fh, linktype=dpkt.pcap.DLT_EN10MB)
            for p in packets:
                udp = dpkt.udp.UDP(sport=p.src_port, dport=listener_port, data=p.payload)
                udp.ulen = len(udp)
                ident = ip_ids.get(p.src_port, 0)
                ip_ids[p.src_port] = (ident + 1) & 0xFFFF
                ip = dpkt.ip.IP(src=src_ip, dst=dst_ip, p=dpkt.ip.IP_PROTO_UDP, ttl=64, id=ident, data=udp)
                ip.len = len(ip)
                frame = dpkt.ethernet.Ethernet(
                    src=SRC_MAC, dst=DST_MAC, type=dpkt.ethernet.ETH_TYPE_IP, data=ip
                )
                writer.writepkt(bytes(frame), ts=p.arrival_s)
    except OSError as exc:
        raise ToolError(f"cannot write capture {str(path)!r}: {exc}") from exc
    return len(packets)


def read_pcap_udp(path: str | Path) -> list[tuple[float, int, bytes]]:
    """(timestamp, source port, UDP payload) of every frame of a capture written by :func:`write_pcap`."""
    import dpkt

    from tools.errors import CaptureError

    out: list[tuple[float, int, bytes]] = []
    try:
        with open(path, "rb") as fh:
            for k, (ts, buf) in enumerate(dpkt.pcap.Reader(fh)):
                try:
                    ip = dpkt.ethernet.Ethernet(buf).data
                    udp = ip.data
                    out.append((float(ts), int(udp.sport), bytes(udp.data)))
                except (dpkt.dpkt.UnpackError, AttributeError) as exc:
                    raise CaptureError(f"{path}: frame {k} is not Ethernet/IPv4/UDP ({exc})") from None
    except (OSError, ValueError, dpkt.dpkt.UnpackError) as exc:
        raise CaptureError(f"cannot read capture {str(path)!r}: {exc}") from None
    return out


# ------------------------------------------------------------------------------------------ track
def thin_by_spacing(east_m: np.ndarray, north_m: np.ndarray, min_spacing_m: float) -> np.ndarray:
    """Indices of the vertices kept so that each is at least ``min_spacing_m`` from the previous kept
    one (the first and the last sample are always kept; the last replaces a too-close predecessor)."""
    keep = [0]
    le, ln = east_m[0], north_m[0]
    for i in range(1, east_m.size):
        if math.hypot(east_m[i] - le, north_m[i] - ln) >= min_spacing_m:
            keep.append(i)
            le, ln = east_m[i], north_m[i]
    last = east_m.size - 1
    if keep[-1] != last:
        if len(keep) > 1 and math.hypot(east_m[last] - east_m[keep[-1]], north_m[last] - north_m[keep[-1]]) \
                < 0.5 * min_spacing_m:
            keep[-1] = last
        else:
            keep.append(last)
    return np.asarray(keep, dtype=np.int64)


def project_along(
    line_s_m: np.ndarray, line_e_m: np.ndarray, line_n_m: np.ndarray,
    east_m: np.ndarray, north_m: np.ndarray, segment_hint: np.ndarray, window: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """(s_m, distance_m) of each point projected onto the polyline, searching only the segments within
    ``window`` of ``segment_hint`` (the segment the point is expected on). A local search is needed
    because a trajectory that drives a road twice gives a line that passes the same place twice,
    where the globally nearest point may belong to the other pass."""
    nseg = line_s_m.size - 1
    best_s = np.full(east_m.size, np.nan)
    best_d = np.full(east_m.size, np.inf)
    for off in range(-window, window + 1):
        k = np.clip(segment_hint + off, 0, nseg - 1)
        e0, n0 = line_e_m[k], line_n_m[k]
        de, dn = line_e_m[k + 1] - e0, line_n_m[k + 1] - n0
        ll = de * de + dn * dn
        u = np.clip(((east_m - e0) * de + (north_m - n0) * dn) / np.where(ll > 0, ll, 1.0), 0.0, 1.0)
        d = np.hypot(e0 + u * de - east_m, n0 + u * dn - north_m)
        s = line_s_m[k] + u * (line_s_m[k + 1] - line_s_m[k])
        better = d < best_d
        best_d = np.where(better, d, best_d)
        best_s = np.where(better, s, best_s)
    return best_s, best_d


# ------------------------------------------------------------------------------------------ GNSS noise
@dataclass(frozen=True)
class GnssNoise:
    """Synthesised horizontal GNSS error per axis: first-order Gauss-Markov plus white (defaults: the
    simulator's ``standalone`` preset, interface_modules/presets.py)."""

    rate_hz: float = 1.0  #: fix rate [Hz]
    white_sigma_m: float = 0.5  #: white noise per horizontal axis, 1-sigma [m]
    gm_sigma_m: float = 1.0  #: Gauss-Markov error per horizontal axis, steady 1-sigma [m]
    gm_tau_s: float = 30.0  #: Gauss-Markov correlation time [s]
    vertical_sigma_m: float = 3.0  #: white vertical error, 1-sigma [m]
    reported_sigma_h_m: float = 1.5  #: sigma_h written into each GPS datagram [m]
    fix_quality: int = 1  #: NMEA GGA quality of every fix
    num_sv: int = 12  #: satellites used, written into every fix

    def __post_init__(self) -> None:
        for name in ("rate_hz", "gm_tau_s", "reported_sigma_h_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ToolError(f"GnssNoise.{name} must be > 0, got {v!r}")
        for name in ("white_sigma_m", "gm_sigma_m", "vertical_sigma_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ToolError(f"GnssNoise.{name} must be >= 0, got {v!r}")

    @classmethod
    def from_preset(cls, name: str = "standalone") -> GnssNoise:
        from interface_modules.presets import GPS_PRESETS

        try:
            p = GPS_PRESETS[name]
        except KeyError:
            raise ToolError(f"unknown GPS preset {name!r}; known: {sorted(GPS_PRESETS)}") from None
        return cls(p.rate_hz, p.white_sigma_m, p.gm_sigma_m, p.gm_tau_s, p.vertical_sigma_m,
                   p.reported_sigma_h_m, p.fix_quality, p.num_sv_mean)

    def scaled_to(self, total_sigma_m: float) -> GnssNoise:
        """Same shape, white and Gauss-Markov parts (and the reported sigma_h) scaled so that the total
        per-axis 1-sigma is ``total_sigma_m``."""
        if not (math.isfinite(total_sigma_m) and total_sigma_m > 0):
            raise ToolError(f"--gps-sigma must be a positive number of metres, got {total_sigma_m!r}")
        k = total_sigma_m / self.total_sigma_m
        return GnssNoise(self.rate_hz, self.white_sigma_m * k, self.gm_sigma_m * k, self.gm_tau_s,
                         self.vertical_sigma_m * k, self.reported_sigma_h_m * k, self.fix_quality,
                         self.num_sv)

    @property
    def total_sigma_m(self) -> float:
        """Steady 1-sigma per horizontal axis [m]."""
        return math.hypot(self.white_sigma_m, self.gm_sigma_m)


def gnss_errors_m(noise: GnssNoise, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) errors east, north, up [m] at the (increasing) times ``t_s``: exact discretisation of the
    Gauss-Markov process (started from its stationary distribution) plus white noise."""
    n = t_s.size
    z = rng.standard_normal((n, 5))
    gm = np.zeros((n, 2))
    if n:
        gm[0] = noise.gm_sigma_m * z[0, :2]
        phi = np.exp(-np.diff(t_s) / noise.gm_tau_s)
        for i in range(1, n):
            # x_k = phi x_{k-1} + sigma sqrt(1 - phi^2) w_k
            gm[i] = phi[i - 1] * gm[i - 1] + noise.gm_sigma_m * math.sqrt(1.0 - phi[i - 1] ** 2) * z[i, :2]
    out = np.empty((n, 3))
    out[:, :2] = gm + noise.white_sigma_m * z[:, 2:4]
    out[:, 2] = noise.vertical_sigma_m * z[:, 4]
    return out


# ------------------------------------------------------------------------------------------ outputs
def write_truth_csv(path: str | Path, columns: dict[str, np.ndarray], formats: dict[str, str]) -> int:
    """truth.csv with the given columns (equal lengths), each formatted with its format spec; rows."""
    names = list(columns)
    n = len(columns[names[0]])
    try:
        with open(path, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh, lineterminator="\n")
            w.writerow(names)
            for i in range(n):
                w.writerow([format(float(columns[c][i]), formats[c]) for c in names])
    except OSError as exc:
        raise ToolError(f"cannot write truth {str(path)!r}: {exc}") from exc
    return n


def write_json(path: str | Path, data: dict) -> None:
    try:
        Path(path).write_text(json.dumps(data, indent=2, sort_keys=False) + "\n", encoding="utf-8")
    except OSError as exc:
        raise ToolError(f"cannot write {str(path)!r}: {exc}") from exc


def prepare_out_dir(out_dir: str | Path, names: Sequence[str], overwrite: bool) -> Path:
    """Create ``out_dir``; refuse to replace existing outputs unless ``overwrite``."""
    out = Path(out_dir)
    existing = [n for n in names if (out / n).exists()]
    if existing and not overwrite:
        raise ToolError(f"{out} already holds {', '.join(existing)} (use --force to replace)")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ToolError(f"cannot create output directory {str(out)!r}: {exc}") from exc
    for n in existing:
        (out / n).unlink()
    return out


@dataclass(frozen=True)
class Conversion:
    """What an adapter wrote."""

    out_dir: Path  #: output directory
    capture: Path  #: capture.pcap
    track: Path  #: track.db
    truth: Path | None  #: truth.csv (None: the source has no truth)
    metadata: Path  #: metadata.json
    packets: int  #: frames in the capture
    by_module: dict[str, int]  #: datagrams per module

    def as_dict(self) -> dict:
        d = asdict(self)
        return {k: (str(v) if isinstance(v, Path) else v) for k, v in d.items()}


def count_by_module(packets: Sequence[Packet]) -> dict[str, int]:
    out: dict[str, int] = {}
    for p in packets:
        out[p.module] = out.get(p.module, 0) + 1
    return dict(sorted(out.items()))
