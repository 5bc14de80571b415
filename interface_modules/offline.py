"""Offline generation: scenario -> truth, events and the datagrams the listener's host would capture.

No sockets, no files, no clocks: ``generate`` is a pure function of the scenario and the seed, so
the same seed gives byte-identical packets. The train's motion does not depend on the seed (the
driver is deterministic) unless the truth runs on an as-built path (``track.as_built``), which is
drawn from the seed; every sensor and network error does. Random streams are independent per
module (``numpy.random.default_rng([seed, stream])``), so enabling or reconfiguring one module
never changes another module's errors.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from . import faults as faults_mod
from .asbuilt import ReferenceMap, as_built_line
from .assemble import Packet, control_messages, control_schedule, send_times, sensor_payloads
from .errors import SimError
from .faults import Fault
from .journey import build_legs
from .motion import Trajectory, drive
from .scenario import Scenario, actual_spec, load_scenario, rate_of
from .sensors.gps import simulate_gps
from .sensors.imu import CantModel, simulate_imu
from .sensors.odometer import simulate_odometer
from .sensors.stream import SampleStream
from .tracks import open_line

#: random stream index per purpose (the second entropy word after the seed)
RNG_STREAMS = {
    "imu": 1,
    "odometer": 2,
    "gps": 3,
    "net:imu": 11,
    "net:odometer": 12,
    "net:gps": 13,
    "net:control": 14,
    "as-built": 21,
}


@dataclass
class SimRun:
    """Result of one offline generation (see docs/architecture.md, "interface_modules")."""

    scenario: Scenario
    seed: int
    truth: dict[str, np.ndarray]  #: epoch, arc_length, speed, accel, lat, lon, line_id, direction (100 Hz)
    events: list[tuple[float, str, str]]  #: (epoch [s], kind, detail), time-ordered
    packets: list[Packet]  #: capture order (arrival time)
    streams: dict[str, SampleStream] = field(default_factory=dict)  #: per-sensor samples and their truth
    trajectory: Trajectory | None = None  #: the driver's truth trajectory (seconds from the start)
    ports: dict[str, int] = field(default_factory=dict)  #: module -> UDP source port

    def messages(self) -> list:
        """Decoded InputMessage of every packet, in capture order (uses listener.codec)."""
        from listener.codec import decode_input

        return [decode_input(p.payload) for p in self.packets]

    def packets_of(self, module: str) -> list[Packet]:
        """The packets one module sent, in order."""
        return [p for p in self.packets if p.module == module]

    @property
    def duration_s(self) -> float:
        """Simulated time covered by the truth [s]."""
        t = self.truth["epoch"]
        return float(t[-1] - t[0]) if t.size else 0.0


def rng_for(seed: int, purpose: str) -> np.random.Generator:
    """The seeded generator of one purpose (see RNG_STREAMS)."""
    return np.random.default_rng([int(seed), RNG_STREAMS[purpose]])


def simulate_truth(sc: Scenario, track, max_duration_s: float | None = None) -> Trajectory:
    """The train's truth trajectory for the scenario (seed-independent)."""
    legs = build_legs(sc, track)
    limit = sc.max_duration_s if max_duration_s is None else max_duration_s
    return drive(sc.train, legs, dt_s=1.0 / sc.truth_rate_hz, tail_s=sc.tail_s, max_time_s=limit,
                 driver=sc.driver)


def cant_model(sc: Scenario) -> CantModel | None:
    """The scenario's cant rule (None: no cant); rail spacing from the train's gauge."""
    if sc.track.cant_design_speed_kmh is None:
        return None
    spacing = 1.5 if sc.train.gauge == "standard" else 1.06
    return CantModel(sc.track.cant_design_speed_kmh / 3.6, sc.track.max_cant_mm / 1000.0, spacing)


def scenario_faults(sc: Scenario) -> tuple[Fault, ...]:
    """Configured faults plus one GNSS outage per tunnel."""
    tunnels = tuple(
        Fault(
            kind="gnss_outage",
            sensor="gps",
            from_m=z.from_m,
            to_m=z.to_m,
            mode=sc.track.tunnel_gnss_mode,
            label=z.name or "tunnel",
        )
        for z in sc.track.tunnels
    )
    return sc.faults + tunnels


def zone_events(traj: Trajectory, sc: Scenario) -> list[tuple[float, str, str]]:
    """Tunnel entry/exit events from the truth arc length."""
    events = []
    for z in sc.track.tunnels:
        inside = (traj.s_m >= z.from_m) & (traj.s_m <= z.to_m)
        change = np.flatnonzero(np.diff(inside.astype(np.int8)))
        if inside.size and inside[0]:
            events.append((float(traj.t_s[0]), "tunnel_in", z.name))
        for i in change:
            kind = "tunnel_in" if inside[i + 1] else "tunnel_out"
            events.append((float(traj.t_s[i + 1]), kind, z.name))
    return events


def fault_events(all_faults: tuple[Fault, ...]) -> list[tuple[float, str, str]]:
    """Events of the module-level faults (silent, restart, stuck); sensor models add their own."""
    events = []
    for f in all_faults:
        if f.kind in ("silent", "stuck"):
            events.append((float(f.start_s), f.kind, f.sensor))
            if f.end_s is not None:
                events.append((float(f.end_s), f"{f.kind}_end", f.sensor))
        elif f.kind == "restart":
            events.append((float(f.start_s), "restart", f.sensor))
    return events


def generate(
    scenario: Scenario | str, seed: int | None = None, *, track=None, max_duration_s: float | None = None
) -> SimRun:
    """Run the scenario offline (see module doc). ``seed`` None uses the scenario's seed."""
    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    seed = sc.seed if seed is None else int(seed)
    if seed < 0:
        raise SimError("seed must be >= 0")
    reference = open_line(sc) if track is None else track
    sc, line, to_reference = truth_path(sc, reference, seed)
    traj = simulate_truth(sc, planning_view(line, reference, to_reference), max_duration_s)
    if traj.t_s.size == 0:
        raise SimError("the scenario produced no motion (empty truth)")
    all_faults = scenario_faults(sc)
    rate = sc.truth_rate_hz
    events: list[tuple[float, str, str]] = (
        list(traj.events) + zone_events(traj, sc) + fault_events(all_faults)
    )

    streams: dict[str, SampleStream] = {}
    if sc.imu.enabled:
        streams["imu"] = simulate_imu(
            traj,
            line,
            actual_spec(sc.imu),
            rate_of(sc, sc.imu),
            faults_mod.of_sensor(all_faults, "imu"),
            rng_for(seed, "imu"),
            rate,
            cant_model(sc),
        )
    if sc.odometer.enabled:
        streams["odometer"] = simulate_odometer(
            traj,
            actual_spec(sc.odometer),
            rate_of(sc, sc.odometer),
            faults_mod.of_sensor(all_faults, "odometer"),
            rng_for(seed, "odometer"),
            rate,
        )
    if sc.gps.enabled:
        streams["gps"] = simulate_gps(
            traj,
            line,
            actual_spec(sc.gps),
            rate_of(sc, sc.gps),
            faults_mod.of_sensor(all_faults, "gps"),
            rng_for(seed, "gps"),
            rate,
            antenna_height_m=sc.gps.antenna_height_m,
        )
    for stream in streams.values():
        events.extend(stream.events)

    from listener.codec import encode_input

    offset = sc.start_epoch_s + sc.network.host_clock_offset_s
    columns: list[tuple[np.ndarray, np.ndarray, int, list[bytes], str]] = []
    for name, stream in streams.items():
        module = getattr(sc, name)
        mfaults = faults_mod.of_sensor(all_faults, name)
        t, payloads = sensor_payloads(stream, module, sc.start_epoch_s, mfaults)
        send, arrival = send_times(t, module, sc.network, rng_for(seed, f"net:{name}"))
        columns.append((send, arrival, module.port, payloads, name))
    ctl = sc.control
    cfaults = faults_mod.of_sensor(all_faults, "control")
    end_s = float(traj.t_s[-1])
    t_ctl, kinds = control_schedule(end_s, rate_of(sc, ctl), cfaults)
    send, arrival = send_times(t_ctl, ctl, sc.network, rng_for(seed, "net:control"))
    msgs = control_messages(
        kinds,
        t_ctl,
        send,
        ctl,
        sc.start_epoch_s,
        float(traj.v_mps[0]),
        float(to_reference(traj.s_m[0])),
        getattr(line, "line_id", None),
        cfaults,
    )
    columns.append((send, arrival, ctl.port, [encode_input(m) for m in msgs], "control"))

    packets = _merge(columns, sc.start_epoch_s, offset)
    truth = truth_arrays(traj, line, sc.start_epoch_s)
    truth["arc_length"] = np.asarray(to_reference(truth["arc_length"]), dtype=float)
    events_epoch = sorted(((sc.start_epoch_s + t, k, d) for t, k, d in events), key=lambda e: e[0])
    return SimRun(
        scenario=sc,
        seed=seed,
        truth=truth,
        events=events_epoch,
        packets=packets,
        streams=streams,
        trajectory=traj,
        ports={m.name: m.port for m in sc.modules if m.enabled},
    )


def truth_path(sc: Scenario, reference, seed: int):
    """(scenario, line, to_reference): the path the truth runs on and the map of its arc length to the
    reference line's (the filter's database). With ``track.as_built`` enabled on a database line, the
    as-built path of ``interface_modules.asbuilt`` (seeded by the scenario seed), the journey's and
    zones' arc lengths moved onto it; otherwise the reference itself and the identity."""
    cfg = sc.track.as_built
    if not cfg.enabled or not hasattr(reference, "east_m"):
        return sc, reference, _identity
    built = as_built_line(reference, cfg, rng_for(seed, "as-built"))
    ref_map = ReferenceMap(built, reference)

    def moved(z):
        return dataclasses.replace(
            z, from_m=float(ref_map.inverse(z.from_m)), to_m=float(ref_map.inverse(z.to_m)))

    track = dataclasses.replace(
        sc.track,
        speed_limits=tuple(moved(z) for z in sc.track.speed_limits),
        tunnels=tuple(moved(z) for z in sc.track.tunnels),
    )
    journey = tuple(dataclasses.replace(p, s_m=float(ref_map.inverse(p.s_m))) for p in sc.journey)
    return dataclasses.replace(sc, track=track, journey=journey), built, ref_map


def _identity(s):
    return s


class _PlanningView:
    """The as-built path as the driver plans on it: its own arc length, grade and everything else, but
    the curvature of the reference line (the design alignment that the line's curve speed limits are
    set from) at the same place. The as-built path's short-wavelength lateral offset is survey error
    and track irregularity: its curvature (a 0.14 m, 40 m wavelength component alone is a 290 m
    radius) would make the driver brake for curves no speed board shows. The sensors still see the
    as-built path's own curvature."""

    def __init__(self, built, reference, to_reference) -> None:
        self._built = built
        self._reference = reference
        self._to_reference = to_reference

    def __getattr__(self, name):
        return getattr(self._built, name)

    def curvature_at(self, s_m):
        return self._reference.curvature_at(self._to_reference(s_m))


def planning_view(line, reference, to_reference):
    """What the driver plans on (``_PlanningView``); the line itself without an as-built path."""
    if line is reference:
        return line
    return _PlanningView(line, reference, to_reference)


def _merge(columns, start_epoch_s: float, offset_s: float) -> list[Packet]:
    """All modules' packets in arrival order (ties: by port, then sending order)."""
    arrival = np.concatenate([c[1] for c in columns])
    ports = np.concatenate([np.full(c[1].size, c[2]) for c in columns])
    order_in = np.concatenate([np.arange(c[1].size) for c in columns])
    order = np.lexsort((order_in, ports, arrival))
    sends = np.concatenate([c[0] for c in columns])
    payloads = [p for c in columns for p in c[3]]
    names = [c[4] for c in columns for _ in c[3]]
    arr_l = np.round(arrival + offset_s, 6).tolist()  # capture timestamps have microsecond resolution
    send_l = (sends + start_epoch_s).tolist()
    port_l = ports.tolist()
    return [Packet(arr_l[i], port_l[i], payloads[i], send_l[i], names[i]) for i in order.tolist()]


def truth_arrays(traj: Trajectory, line, start_epoch_s: float) -> dict[str, np.ndarray]:
    """The truth table of a run (one row per truth step)."""
    lat, lon = line.latlon_at(traj.s_m)
    line_id = getattr(line, "line_id", 0)
    return {
        "epoch": start_epoch_s + traj.t_s,
        "arc_length": traj.s_m.copy(),
        "speed": traj.v_mps.copy(),
        "accel": traj.a_mps2.copy(),
        "lat": np.asarray(lat, dtype=float),
        "lon": np.asarray(lon, dtype=float),
        "line_id": np.full(traj.t_s.size, float(line_id)),
        "direction": traj.direction.astype(float),
    }
