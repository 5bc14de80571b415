"""Scenario files (TOML) -> frozen, validated configuration.

A scenario names a track and line, a journey profile (stopping and passing points with times),
the train, the sensors and their rates, network timing, fault zones, the seed and the sequence
numbers each module starts from. ``docs/simulator.md`` documents every key with an example;
the shipped scenarios live in ``interface_modules/scenarios/``. Every time in a scenario is in
seconds from the scenario start (sensor-set time ``start_epoch_s``).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .asbuilt import AsBuiltConfig
from .ato_driver import AtoPidConfig
from .errors import ScenarioError
from .faults import KIND_SENSOR, Fault
from .motion import DriverConfig
from .presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from .trains import KMH, TRAIN_PRESETS, TrainSpec

SCENARIO_DIR = Path(__file__).resolve().parent / "scenarios"
DEFAULT_START_EPOCH_S = 1_700_000_000.0  #: 2023-11-14 22:13:20 UTC, sensor-set (POSIX) time


@dataclass(frozen=True)
class Zone:
    """An arc-length range of the line [m] (tunnels, speed restrictions)."""

    from_m: float  #: start [m]
    to_m: float  #: end [m]
    name: str = ""  #: label for events
    limit_kmh: float | None = None  #: speed limit inside the zone [km/h] (speed restrictions only)


@dataclass(frozen=True)
class SegmentConfig:
    """One piece of a synthetic track: length [m], curvature [1/m, > 0 right], grade [-]."""

    length_m: float
    curvature_per_m: float = 0.0
    grade: float = 0.0


@dataclass(frozen=True)
class TrackConfig:
    """Which track and line to run on, its tunnels and speed limits."""

    database: str = "default"  #: "default" (bundled), a .db path, "gtfs:DIR", "geojson:FILE" or "synthetic"
    line_id: int | None = None  #: line of the database; None: the database's default line
    gtfs_shape_id: str | None = None  #: shape to import for "gtfs:" databases
    line_speed_kmh: float = 50.0  #: line speed [km/h]
    speed_limits: tuple[Zone, ...] = ()  #: lower limits on zones [km/h]
    tunnels: tuple[Zone, ...] = ()  #: tunnels: GNSS outage zones, events on entry/exit
    tunnel_gnss_mode: str = "no_fix"  #: "no_fix" (fix_quality 0 datagrams) or "silent" inside tunnels
    segments: tuple[SegmentConfig, ...] = ()  #: geometry for database = "synthetic"
    cant_design_speed_kmh: float | None = None  #: cant balances this speed in curves [km/h]; None: no cant
    max_cant_mm: float = 150.0  #: largest cant [mm]
    #: the truth's path: the database's line made as-built (interface_modules.asbuilt); disabled, the
    #: truth runs on the database itself (perfect-knowledge mode, label it so in every table)
    as_built: AsBuiltConfig = dataclasses.field(default_factory=AsBuiltConfig)


@dataclass(frozen=True)
class JourneyPoint:
    """A stopping or passing point of the journey profile."""

    s_m: float  #: arc length on the line [m]
    kind: str = "stop"  #: "stop" or "pass"
    name: str = ""  #: station or timing-point name
    arrival_s: float | None = None  #: scheduled arrival (stop) or passing time (pass) [s]
    departure_s: float | None = None  #: scheduled departure (stops) [s]
    dwell_s: float = 0.0  #: minimum dwell (stops) [s]


@dataclass(frozen=True)
class ModuleConfig:
    """One interface module (its own socket and sequence counter)."""

    name: str  #: imu, odometer, gps or control
    enabled: bool = True  #: whether the module exists in this scenario
    preset: str = ""  #: sensor preset (interface_modules.presets); unused for control
    rate_hz: float | None = None  #: output rate [Hz]; None: the preset's rate (control: strobe rate 1 Hz)
    port: int = 0  #: UDP source port [1..65535]
    seq_start: int = 0  #: first sequence number [0..65535]
    send_epoch: bool = True  #: send the optional epoch field
    send_delay_s: float = 2.0e-4  #: fixed processing delay from sampling to sending [s]
    send_jitter_s: float = 1.0e-4  #: median of the lognormal extra send delay [s]
    antenna_height_m: float = 3.5  #: GPS antenna above the rail [m] (gps only)
    #: the sensor's actual errors where they differ from its preset's datasheet figures: (field of the
    #: preset's spec, value) pairs, from the [sensors.NAME.actual] table (the filter is not told)
    actual: tuple[tuple[str, float], ...] = ()


@dataclass(frozen=True)
class NetworkConfig:
    """Path from the modules to the listener's host, as the capture sees it."""

    host: str = "127.0.0.1"  #: source address of the modules in captures
    listener_host: str = "127.0.0.1"  #: destination address in captures
    listener_port: int = 48000  #: UDP destination port
    delay_s: float = 3.0e-4  #: fixed network delay [s]
    jitter_s: float = 5.0e-5  #: median of the lognormal network jitter [s]
    jitter_sigma: float = 0.8  #: lognormal shape (sigma of log) of both jitters [-]
    host_clock_offset_s: float = 0.0  #: capture clock minus sensor-set time [s]


@dataclass(frozen=True)
class Scenario:
    """A complete, validated scenario."""

    name: str
    description: str
    seed: int  #: seed of every sensor and network error
    start_epoch_s: float  #: sensor-set time of the scenario start [s]
    truth_rate_hz: float  #: truth (and dynamics) rate [Hz]
    tail_s: float  #: simulated time after the last arrival [s]
    max_duration_s: float | None  #: truncate the run [s]
    track: TrackConfig
    train_preset: str
    train: TrainSpec
    journey: tuple[JourneyPoint, ...]
    imu: ModuleConfig
    odometer: ModuleConfig
    gps: ModuleConfig
    control: ModuleConfig
    network: NetworkConfig
    faults: tuple[Fault, ...] = ()
    #: the driver: AtoPidConfig (``[driver] kind = "ato-pid"``, the default: the ATO seed's gain-scheduled
    #: PID with actuator lag) or DriverConfig (``kind = "pi"``: the earlier feedforward + PI driver)
    driver: DriverConfig | AtoPidConfig = dataclasses.field(default_factory=AtoPidConfig)
    source: str = ""  #: file the scenario came from
    base_dir: str = ""  #: directory relative paths are resolved against

    @property
    def modules(self) -> tuple[ModuleConfig, ...]:
        """The four modules, in a fixed order."""
        return (self.imu, self.odometer, self.gps, self.control)

    def with_overrides(self, **changes: Any) -> Scenario:
        """A copy with top-level fields replaced (validated again)."""
        return validate(dataclasses.replace(self, **changes))


_DEFAULT_PORTS = {"imu": 47001, "odometer": 47002, "gps": 47003, "control": 47000}
_DEFAULT_PRESETS = {"imu": "mems-train", "odometer": "wheel-odometer", "gps": "standalone", "control": ""}


def scenario_names() -> list[str]:
    """Names of the shipped scenarios."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))


def resolve_scenario_path(name_or_path: str | Path) -> Path:
    """A shipped scenario's name, or a path to a TOML file."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.is_file():
            raise ScenarioError(f"scenario file {str(p)!r} not found")
        return p
    shipped = SCENARIO_DIR / f"{name_or_path}.toml"
    if shipped.is_file():
        return shipped
    raise ScenarioError(f"unknown scenario {str(name_or_path)!r} (shipped: {', '.join(scenario_names())})")


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load and validate a scenario by shipped name or path."""
    path = resolve_scenario_path(name_or_path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"cannot read scenario {str(path)!r}: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"scenario {str(path)!r} is not valid TOML: {exc}") from exc
    return scenario_from_dict(data, source=str(path), base_dir=str(path.parent))


def scenario_from_dict(data: dict[str, Any], *, source: str = "<dict>", base_dir: str = ".") -> Scenario:
    """Build a scenario from parsed TOML (the same structure as the files)."""
    if not isinstance(data, dict):
        raise ScenarioError("a scenario is a TOML table")
    _known(data, "", {"scenario", "track", "train", "journey", "sensors", "network", "faults", "driver"})
    head = _table(data, "scenario")
    _known(
        head,
        "scenario",
        {"name", "description", "seed", "start_epoch_s", "truth_rate_hz", "tail_s", "max_duration_s"},
    )
    track_t = _table(data, "track")
    _known(
        track_t,
        "track",
        {
            "database",
            "line_id",
            "gtfs_shape_id",
            "line_speed_kmh",
            "speed_limits",
            "tunnels",
            "tunnel_gnss_mode",
            "segments",
            "cant_design_speed_kmh",
            "max_cant_mm",
            "as_built",
        },
    )
    as_built_t = track_t.get("as_built", {})
    if not isinstance(as_built_t, dict):
        raise ScenarioError("track.as_built must be a table")
    try:
        as_built = _dataclass_from(AsBuiltConfig, as_built_t, "track.as_built")
    except ValueError as exc:
        raise ScenarioError(f"track.{exc}") from None
    track = TrackConfig(
        database=_get(track_t, "track", "database", str, "default"),
        line_id=_get(track_t, "track", "line_id", int, None),
        gtfs_shape_id=_get(track_t, "track", "gtfs_shape_id", str, None),
        line_speed_kmh=_get(track_t, "track", "line_speed_kmh", float, 50.0),
        speed_limits=tuple(
            _zone(z, f"track.speed_limits[{i}]", True)
            for i, z in enumerate(_list(track_t, "track", "speed_limits"))
        ),
        tunnels=tuple(
            _zone(z, f"track.tunnels[{i}]", False) for i, z in enumerate(_list(track_t, "track", "tunnels"))
        ),
        tunnel_gnss_mode=_get(track_t, "track", "tunnel_gnss_mode", str, "no_fix"),
        cant_design_speed_kmh=_get(track_t, "track", "cant_design_speed_kmh", float, None),
        max_cant_mm=_get(track_t, "track", "max_cant_mm", float, 150.0),
        as_built=as_built,
        segments=tuple(
            _dataclass_from(SegmentConfig, z, f"track.segments[{i}]")
            for i, z in enumerate(_list(track_t, "track", "segments"))
        ),
    )
    train_t = _table(data, "train")
    _known(train_t, "train", {"preset", "overrides"})
    train_preset = _get(train_t, "train", "preset", str, "tram")
    if train_preset not in TRAIN_PRESETS:
        raise ScenarioError(f"train.preset {train_preset!r} unknown (known: {', '.join(TRAIN_PRESETS)})")
    train = TRAIN_PRESETS[train_preset]
    overrides = train_t.get("overrides", {})
    if overrides:
        if not isinstance(overrides, dict):
            raise ScenarioError("train.overrides must be a table")
        train = _replace_checked(train, overrides, "train.overrides")
    journey_t = _table(data, "journey")
    _known(journey_t, "journey", {"points"})
    points = tuple(
        _dataclass_from(JourneyPoint, p, f"journey.points[{i}]")
        for i, p in enumerate(_list(journey_t, "journey", "points"))
    )
    sensors_t = _table(data, "sensors")
    _known(sensors_t, "sensors", set(_DEFAULT_PORTS))
    modules = {}
    for name in ("imu", "odometer", "gps", "control"):
        t = sensors_t.get(name, {})
        if not isinstance(t, dict):
            raise ScenarioError(f"sensors.{name} must be a table")
        defaults = {"name": name, "port": _DEFAULT_PORTS[name], "preset": _DEFAULT_PRESETS[name]}
        if "name" in t:
            raise ScenarioError(f"sensors.{name}.name is implied by the table name")
        t = dict(t)
        actual = t.pop("actual", {})
        if not isinstance(actual, dict):
            raise ScenarioError(f"sensors.{name}.actual must be a table")
        module = _dataclass_from(ModuleConfig, {**defaults, **t}, f"sensors.{name}")
        modules[name] = dataclasses.replace(module, actual=_actual_pairs(actual, f"sensors.{name}.actual"))
    network = _dataclass_from(NetworkConfig, _table(data, "network"), "network")
    faults_l = data.get("faults", [])
    if not isinstance(faults_l, list):
        raise ScenarioError("faults must be an array of tables ([[faults]])")
    faults = []
    for i, f in enumerate(faults_l):
        if not isinstance(f, dict) or "kind" not in f:
            raise ScenarioError(f"faults[{i}] must be a table with a kind")
        fdata = {"sensor": KIND_SENSOR.get(str(f["kind"]), ""), **f}
        faults.append(_dataclass_from(Fault, fdata, f"faults[{i}]"))
    driver = _driver(_table(data, "driver"))
    scenario = Scenario(
        name=_get(head, "scenario", "name", str, Path(source).stem),
        description=_get(head, "scenario", "description", str, ""),
        seed=_get(head, "scenario", "seed", int, 1),
        start_epoch_s=_get(head, "scenario", "start_epoch_s", float, DEFAULT_START_EPOCH_S),
        truth_rate_hz=_get(head, "scenario", "truth_rate_hz", float, 100.0),
        tail_s=_get(head, "scenario", "tail_s", float, 5.0),
        max_duration_s=_get(head, "scenario", "max_duration_s", float, None),
        track=track,
        train_preset=train_preset,
        train=train,
        journey=points,
        imu=modules["imu"],
        odometer=modules["odometer"],
        gps=modules["gps"],
        control=modules["control"],
        network=network,
        faults=tuple(faults),
        driver=driver,
        source=source,
        base_dir=base_dir,
    )
    return validate(scenario)


def validate(sc: Scenario) -> Scenario:
    """Check cross-field consistency; return the scenario or raise ScenarioError."""
    if sc.seed < 0:
        raise ScenarioError("scenario.seed must be >= 0")
    if not 0.0 <= sc.start_epoch_s <= 1e10:
        raise ScenarioError("scenario.start_epoch_s must be in 0..1e10 s")
    if not 1.0 <= sc.truth_rate_hz <= 10_000.0:
        raise ScenarioError("scenario.truth_rate_hz must be in 1..10000 Hz")
    if sc.tail_s < 0:
        raise ScenarioError("scenario.tail_s must be >= 0")
    if sc.max_duration_s is not None and sc.max_duration_s <= 0:
        raise ScenarioError("scenario.max_duration_s must be > 0")
    if sc.track.line_speed_kmh <= 0:
        raise ScenarioError("track.line_speed_kmh must be > 0")
    if sc.track.tunnel_gnss_mode not in ("no_fix", "silent"):
        raise ScenarioError("track.tunnel_gnss_mode must be 'no_fix' or 'silent'")
    if sc.track.cant_design_speed_kmh is not None and sc.track.cant_design_speed_kmh <= 0:
        raise ScenarioError("track.cant_design_speed_kmh must be > 0")
    if not 0.0 <= sc.track.max_cant_mm <= 200.0:
        raise ScenarioError("track.max_cant_mm must be in 0..200 mm")
    if sc.track.database == "synthetic" and not sc.track.segments:
        raise ScenarioError("a synthetic track needs [[track.segments]]")
    for z in sc.track.speed_limits + sc.track.tunnels:
        if not z.from_m < z.to_m:
            raise ScenarioError(f"zone {z.name or ''} needs from_m < to_m")
        if z.limit_kmh is not None and z.limit_kmh <= 0:
            raise ScenarioError("speed limits must be > 0 km/h")
    for i, p in enumerate(sc.journey):
        if p.kind not in ("stop", "pass"):
            raise ScenarioError(f"journey.points[{i}].kind must be 'stop' or 'pass'")
        if p.dwell_s < 0:
            raise ScenarioError(f"journey.points[{i}].dwell_s must be >= 0")
        if p.kind == "pass" and p.departure_s is not None:
            raise ScenarioError(f"journey.points[{i}]: a passing point has no departure (use arrival_s)")
    stops = [p for p in sc.journey if p.kind == "stop"]
    if len(stops) < 2 or sc.journey[0].kind != "stop" or sc.journey[-1].kind != "stop":
        raise ScenarioError("journey.points must start and end with a stop and have at least two stops")
    times = [t for p in sc.journey for t in (p.arrival_s, p.departure_s) if t is not None]
    if any(b < a for a, b in zip(times, times[1:], strict=False)):
        raise ScenarioError("journey times must not decrease along the journey")
    for i, (a, b) in enumerate(zip(sc.journey, sc.journey[1:], strict=False)):
        if a.s_m == b.s_m:
            raise ScenarioError(f"journey.points[{i}] and [{i + 1}] are at the same arc length")
    for m in sc.modules:
        where = f"sensors.{m.name}"
        if not 1 <= m.port <= 65535:
            raise ScenarioError(f"{where}.port must be in 1..65535")
        if not 0 <= m.seq_start <= 65535:
            raise ScenarioError(f"{where}.seq_start must be in 0..65535")
        if m.rate_hz is not None and m.rate_hz <= 0:
            raise ScenarioError(f"{where}.rate_hz must be > 0")
        if m.send_delay_s < 0 or m.send_jitter_s < 0:
            raise ScenarioError(f"{where}: send delay and jitter must be >= 0")
    for m, table in ((sc.imu, IMU_PRESETS), (sc.odometer, ODOMETER_PRESETS), (sc.gps, GPS_PRESETS)):
        if m.preset not in table:
            raise ScenarioError(f"sensors.{m.name}.preset {m.preset!r} unknown (known: {', '.join(table)})")
        known = {f.name for f in dataclasses.fields(next(iter(table.values())))}
        for key, _value in m.actual:
            if key not in known or key == "rate_hz":
                raise ScenarioError(
                    f"sensors.{m.name}.actual.{key}: not an error of the {m.name} model "
                    f"(known: {', '.join(sorted(known - {'rate_hz'}))})")
    ports = [m.port for m in sc.modules if m.enabled]
    if len(set(ports)) != len(ports):
        raise ScenarioError("each enabled module needs its own source port")
    if not sc.control.enabled:
        raise ScenarioError("the control module (GROUND TRUTH, STROBE, STOP) cannot be disabled")
    net = sc.network
    if not 1 <= net.listener_port <= 65535:
        raise ScenarioError("network.listener_port must be in 1..65535")
    if net.delay_s < 0 or net.jitter_s < 0 or net.jitter_sigma < 0:
        raise ScenarioError("network delay, jitter and jitter_sigma must be >= 0")
    for f in sc.faults:
        f.validate()
    return sc


def actual_spec(module: ModuleConfig):
    """The sensor's actual error model: its preset's spec with the scenario's ``actual`` values."""
    table = {"imu": IMU_PRESETS, "odometer": ODOMETER_PRESETS, "gps": GPS_PRESETS}[module.name]
    spec = table[module.preset]
    if not module.actual:
        return spec
    types = {f.name: f.type for f in dataclasses.fields(spec)}
    changes = {k: (int(v) if types[k] in ("int", int) else bool(v) if types[k] in ("bool", bool) else v)
               for k, v in module.actual}
    return dataclasses.replace(spec, **changes)


def rate_of(sc: Scenario, module: ModuleConfig) -> float:
    """Output rate of a module [Hz]: configured, else the preset's (control: 1 Hz strobes)."""
    if module.rate_hz is not None:
        return module.rate_hz
    if module.name == "imu":
        return IMU_PRESETS[module.preset].rate_hz
    if module.name == "odometer":
        return ODOMETER_PRESETS[module.preset].rate_hz
    if module.name == "gps":
        return GPS_PRESETS[module.preset].rate_hz
    return 1.0


# ---------------------------------------------------------------------------------------------------------
# parsing helpers: every error names the key


def _table(data: dict, key: str) -> dict:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise ScenarioError(f"[{key}] must be a table")
    return value


def _list(data: dict, where: str, key: str) -> list:
    value = data.get(key, [])
    if not isinstance(value, list):
        raise ScenarioError(f"{where}.{key} must be an array of tables")
    return value


def _known(data: dict, where: str, keys: set[str]) -> None:
    unknown = sorted(set(data) - keys)
    if unknown:
        prefix = f"{where}." if where else ""
        raise ScenarioError(f"unknown key {prefix}{unknown[0]} (known: {', '.join(sorted(keys))})")


def _coerce(value: Any, typ: type, where: str) -> Any:
    if typ is float and isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    if typ is int and isinstance(value, int) and not isinstance(value, bool):
        return value
    if typ is bool and isinstance(value, bool):
        return value
    if typ is str and isinstance(value, str):
        return value
    raise ScenarioError(f"{where} must be {typ.__name__}, not {type(value).__name__} ({value!r})")


def _get(data: dict, where: str, key: str, typ: type, default: Any) -> Any:
    if key not in data:
        return default
    return _coerce(data[key], typ, f"{where}.{key}")


_TYPE_OF = {
    "float": float,
    "int": int,
    "str": str,
    "bool": bool,
    "float | None": float,
    "int | None": int,
    "str | None": str,
}


def _dataclass_from(cls: type, data: Any, where: str) -> Any:
    if not isinstance(data, dict):
        raise ScenarioError(f"{where} must be a table")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    _known(data, where, set(fields))
    kwargs = {}
    for key, value in data.items():
        typ = _TYPE_OF.get(str(fields[key].type))
        if typ is None:
            raise ScenarioError(f"{where}.{key} cannot be set in a scenario")
        kwargs[key] = _coerce(value, typ, f"{where}.{key}")
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise ScenarioError(f"{where}: {exc}") from exc


def _actual_pairs(data: dict, where: str) -> tuple[tuple[str, float], ...]:
    pairs = []
    for key, value in sorted(data.items()):
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(float(value)):
            raise ScenarioError(f"{where}.{key} must be a finite number, got {value!r}")
        pairs.append((str(key), float(value)))
    return tuple(pairs)


#: ``[driver] kind`` -> its typed configuration
DRIVER_KINDS: dict[str, type] = {"pi": DriverConfig, "ato-pid": AtoPidConfig}


def _driver(data: dict) -> DriverConfig | AtoPidConfig:
    data = dict(data)
    kind = data.pop("kind", "ato-pid")
    if kind not in DRIVER_KINDS:
        raise ScenarioError(f"driver.kind {kind!r} unknown (known: {', '.join(DRIVER_KINDS)})")
    try:
        return _dataclass_from(DRIVER_KINDS[kind], data, "driver")
    except ValueError as exc:
        raise ScenarioError(str(exc)) from None


def _zone(data: Any, where: str, needs_limit: bool) -> Zone:
    zone = _dataclass_from(Zone, data, where)
    if needs_limit and zone.limit_kmh is None:
        raise ScenarioError(f"{where}.limit_kmh is required")
    return zone


def _replace_checked(spec: TrainSpec, overrides: dict, where: str) -> TrainSpec:
    fields = {f.name: f for f in dataclasses.fields(spec)}
    _known(overrides, where, set(fields))
    kwargs = {k: _coerce(v, _TYPE_OF[str(fields[k].type)], f"{where}.{k}") for k, v in overrides.items()}
    return dataclasses.replace(spec, **kwargs)


__all__ = [
    "KMH",
    "JourneyPoint",
    "ModuleConfig",
    "NetworkConfig",
    "Scenario",
    "SegmentConfig",
    "TrackConfig",
    "Zone",
    "load_scenario",
    "rate_of",
    "actual_spec",
    "resolve_scenario_path",
    "scenario_from_dict",
    "scenario_names",
]
