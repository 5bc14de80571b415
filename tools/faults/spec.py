"""Campaign files (TOML): a base simulator scenario and a matrix of fault scenarios, validated.

```toml
[campaign]
name = "quick"
duration_s = 120.0            # simulated seconds per scenario (a scenario may override)
seed = 1                      # seeds the links' fault cores (the simulator keeps its scenario seed)
speed = 10.0                  # live mode: simulated seconds per wall second
listener = ["link.extended=true"]   # listener --set overrides for every scenario

[base]                        # the simulator scenario: `scenario = "NAME-OR-PATH"`, or inline tables
scenario.name = "jena-line-2"
journey.points = [{ s_m = 100.0, kind = "stop", departure_s = 5.0 }, { s_m = 3000.0, kind = "stop" }]

[[scenarios]]
name = "loss20-reorder5-dup1"
input_link = { loss = 0.2, reorder = 0.05, duplicate = 0.01 }   # Impairments fields
output_link = { blackouts = [[60.0, 5.0]] }                     # listener <-> OBCU (both ways)
obcu = { drop_acks = [[30.0, 3.0]], silent = [], restart_at_s = [] }
sensor_faults = [{ kind = "gnss_outage", start_s = 40.0, end_s = 80.0 }]   # interface_modules.faults
listener = ["link.degraded_after_s=2.0"]
expect = { crashes = 0, p95_m = 5.0, coverage = 0.99, losses_match = true }
seeds = 10      # independent repetitions (simulator and link seeds + 0..9), figures pooled
restart = { kill_window_s = [30.0, 60.0], down_s = 1.0 }   # kill -9 at a seeded time, restart 1 s later
```
Every key is checked; an unknown one is an error naming it. ``expect`` keys are in :data:`EXPECT_KEYS`.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from tools.faults.config import Impairments, impairments_from_dict
from tools.faults.errors import FaultConfigError

#: expectation keys and what each bounds (the campaign reports PASS/FAIL per key)
EXPECT_KEYS = {
    "crashes": "most crashes (non-zero exits, tracebacks) [count]",
    "p95_m": "largest p95 along-track error of fresh outputs [m]",
    "max_m": "largest maximum along-track error [m]",
    "coverage": "least fraction of fresh outputs whose interval holds the truth",
    "fault_coverage": "least interval coverage inside the sensor-fault windows",
    "losses_match": "input-link drops the listener can see == its lost count (true)",
    "duplicates_match": "injected duplicates (+ replays) == duplicates + late + probation drops (true)",
    "reorders_match": "injected reorders == reordered counted (true)",
    "accepted_bad": "most invalid datagrams (forged-invalid, garbage) accepted [count]",
    "rejected_match": "every injected invalid datagram counted as rejected (true)",
    "max_fresh_age_s": "largest age of a fresh output at the OBCU [s]",
    "degraded_within_s": "link DEGRADED at most this long after an output-link blackout starts [s]",
    "recover_within_s": "link UP again at most this long after a blackout ends [s]",
    "reasons": "filter reasons that must be reported during the sensor-fault windows (any of them)",
    "memory_growth_mb": "live: largest listener RSS growth during the run [MB]",
    "latency_p99_ms": "live: largest p99 output lag above the best one [ms]",
    "latency_delta_ms": "live, injections: largest rise of the p99 output lag during the injection window "
                        "over the equally long stretch before it [ms]",
    "auth_bad": "authenticated link: most accepted datagrams that are not a first copy of an original",
    "foreign_rejected_match": "every GROUND TRUTH / STOP forged from a foreign source rejected by the "
                              "sender table (true)",
    "late_max": "most datagrams dropped as late by the sequence buffers [count]",
    "outputs_to_end_s": "fresh outputs until at most this long before the scenario's end [s]",
    "resume_within_s": "restart rows: first fresh output at most this long after the restart [s]",
    "seq_continues": "restart rows: the first output after the restart has a SEQ newer (serial order) than "
                     "every output before the kill, so the OBCU takes it as fresh (true)",
    "warnings": "warning events the listener must have logged (each of them)",
    "status_reasons": "reasons a non-nominal status must have carried (each of them; status events and, "
                      "replay path, the outputs)",
    "max_gap_s": "longest time between two fresh outputs, from the first to the end [s]",
    "stop_exit_within_s": "the listener stopped at most this long after the STOP datagram arrived [s]",
    "ground_truth_held_match": "every GROUND TRUTH forged as the control module held by plausibility, none "
                               "confirmed (true)",
    "burst_rejected_match": "authenticated link: every datagram of the replay burst rejected as a replay "
                            "(true; record only datagrams the listener accepted before: a restart row's "
                            "burst must come from before the earliest kill)",
}


@dataclass(frozen=True)
class Restart:
    """A ``kill -9`` of the listener and its restart (``restart`` table of a row).

    Repetition k kills at a time drawn uniformly from ``kill_window_s`` with
    ``numpy.random.default_rng([seed, 3])`` (the repetition's link seed), seconds from the run start;
    the listener is started again ``down_s`` later with the same configuration and checkpoint file."""

    kill_window_s: tuple[float, float]  #: (earliest, latest) kill time from the run start [s]
    down_s: float = 1.0  #: from the kill to the new process's start [s]

    def kill_at_s(self, seed: int) -> float:
        import numpy as np

        a, b = self.kill_window_s
        return float(np.random.default_rng([seed, 3]).uniform(a, b))


@dataclass(frozen=True)
class ObcuMisbehaviour:
    """Mock OBCU misbehaviour, seconds from the run start (``sfa obcu`` options)."""

    drop_acks: tuple[tuple[float, float], ...] = ()  #: (start, duration) windows without acks [s]
    silent: tuple[tuple[float, float], ...] = ()  #: (start, duration) windows ignoring everything [s]
    restart_at_s: tuple[float, ...] = ()  #: times the OBCU forgets its state [s]


@dataclass(frozen=True)
class ScenarioSpec:
    """One row of the matrix."""

    name: str
    duration_s: float  #: simulated seconds [s]
    seed: int  #: seed of the links' fault cores
    base: dict[str, Any]  #: the simulator scenario (parsed TOML), sensor faults merged in
    input_link: Impairments | None = None  #: interface modules -> listener
    output_link: Impairments | None = None  #: listener <-> OBCU
    obcu: ObcuMisbehaviour = field(default_factory=ObcuMisbehaviour)
    sensor_faults: tuple[dict[str, Any], ...] = ()  #: the [[faults]] tables added to the scenario
    listener: tuple[str, ...] = ()  #: listener KEY=VALUE overrides
    expect: dict[str, Any] = field(default_factory=dict)
    speed: float = 10.0  #: live: simulated seconds per wall second
    netns: bool = False  #: live: run the listener in a network namespace behind tc netem
    timeout_s: float | None = None  #: wall time before the run counts as stalled (None: from duration) [s]
    auth: bool = False  #: authenticated links with per-module input keys (replay path and live)
    #: independent repetitions: repetition k runs the simulator scenario with seed + k and the links with
    #: seed + k; the row's figures pool every repetition's outputs (``evaluate.pool``). A coverage or
    #: p95 of one correlated 10-minute run varies by several percent from seed to seed; pooled, it is
    #: the statistic the bound means.
    seeds: int = 1
    restart: Restart | None = None  #: kill -9 and restart of the listener (replay path and live)

    def repetition(self, k: int) -> ScenarioSpec:
        """Repetition ``k`` alone (0: this row's seeds)."""
        if k == 0:
            return replace(self, seeds=1)
        base = {key: (dict(v) if isinstance(v, dict) else v) for key, v in self.base.items()}
        head = dict(base.get("scenario", {}))
        head["seed"] = int(head.get("seed", 0)) + k
        base["scenario"] = head
        return replace(self, seed=self.seed + k, base=base, seeds=1)

    def scenario_dict(self) -> dict[str, Any]:
        """The simulator scenario to run: the base with this row's faults and duration."""
        data = {k: (dict(v) if isinstance(v, dict) else v) for k, v in self.base.items()}
        head = dict(data.get("scenario", {}))
        head["max_duration_s"] = float(self.duration_s)
        data["scenario"] = head
        data["faults"] = list(data.get("faults", [])) + [dict(f) for f in self.sensor_faults]
        return data


@dataclass(frozen=True)
class Campaign:
    name: str
    source: str
    scenarios: tuple[ScenarioSpec, ...]


_CAMPAIGN_KEYS = {"name", "duration_s", "seed", "speed", "listener"}
_ROW_KEYS = {"name", "duration_s", "seed", "input_link", "output_link", "obcu", "sensor_faults", "listener",
             "expect", "speed", "netns", "description", "timeout_s", "auth", "seeds", "restart"}


def _number(value: Any, where: str, low: float = 0.0, strict: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(float(value)):
        raise FaultConfigError(f"{where}: expected a finite number, got {value!r}")
    if float(value) < low or (strict and float(value) == low):
        raise FaultConfigError(f"{where}: must be {'>' if strict else '>='} {low}, got {value!r}")
    return float(value)


def _seeds(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 100:
        raise FaultConfigError(f"{where}: an integer from 1 to 100, got {value!r}")
    return value


def _flag(value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise FaultConfigError(f"{where}: true or false, got {value!r}")
    return value


def _windows(value: Any, where: str) -> tuple[tuple[float, float], ...]:
    if not isinstance(value, list):
        raise FaultConfigError(f"{where}: expected [[start_s, duration_s], ...]")
    out = []
    for i, w in enumerate(value):
        if not isinstance(w, list) or len(w) != 2:
            raise FaultConfigError(f"{where}[{i}]: expected [start_s, duration_s]")
        out.append((_number(w[0], f"{where}[{i}]", 0.0, strict=False), _number(w[1], f"{where}[{i}]")))
    return tuple(out)


def _obcu(data: Any, where: str) -> ObcuMisbehaviour:
    if not isinstance(data, dict):
        raise FaultConfigError(f"{where}: expected a table")
    unknown = set(data) - {"drop_acks", "silent", "restart_at_s"}
    if unknown:
        raise FaultConfigError(
            f"{where}.{sorted(unknown)[0]}: unknown key (known: drop_acks, silent, restart_at_s)"
        )
    restarts = data.get("restart_at_s", [])
    if not isinstance(restarts, list):
        raise FaultConfigError(f"{where}.restart_at_s: expected a list of times")
    return ObcuMisbehaviour(
        drop_acks=_windows(data.get("drop_acks", []), f"{where}.drop_acks"),
        silent=_windows(data.get("silent", []), f"{where}.silent"),
        restart_at_s=tuple(_number(t, f"{where}.restart_at_s", 0.0, strict=False) for t in restarts),
    )


def _restart(data: Any, where: str) -> Restart | None:
    if data is None:
        return None
    if not isinstance(data, dict):
        raise FaultConfigError(f"{where}: expected a table")
    unknown = set(data) - {"kill_window_s", "down_s"}
    if unknown:
        raise FaultConfigError(f"{where}.{sorted(unknown)[0]}: unknown key (known: down_s, kill_window_s)")
    w = data.get("kill_window_s")
    if not isinstance(w, list) or len(w) != 2:
        raise FaultConfigError(f"{where}.kill_window_s: expected [earliest_s, latest_s]")
    a = _number(w[0], f"{where}.kill_window_s", 0.0, strict=False)
    b = _number(w[1], f"{where}.kill_window_s", a, strict=False)
    return Restart((a, b), _number(data.get("down_s", 1.0), f"{where}.down_s", 0.0, strict=False))


def _overrides(value: Any, where: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(v, str) and "=" in v for v in value):
        raise FaultConfigError(f"{where}: expected a list of \"KEY=VALUE\" strings")
    return tuple(value)


def _expect(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise FaultConfigError(f"{where}: expected a table")
    for key, v in value.items():
        if key not in EXPECT_KEYS:
            raise FaultConfigError(f"{where}.{key}: unknown expectation (known: {', '.join(EXPECT_KEYS)})")
        if key.endswith("_match") or key == "seq_continues":
            if v is not True:
                raise FaultConfigError(f"{where}.{key}: only `true` is meaningful")
        elif key in ("reasons", "warnings", "status_reasons"):
            if not isinstance(v, list) or not v or not all(isinstance(r, str) for r in v):
                raise FaultConfigError(f"{where}.{key}: expected a non-empty list of names")
        else:
            _number(v, f"{where}.{key}", 0.0, strict=False)
    return dict(value)


def _base(data: Any, root: Path) -> dict[str, Any]:
    """The base scenario as a parsed TOML tree (loaded from a file or given inline)."""
    from interface_modules.scenario import resolve_scenario_path

    if not isinstance(data, dict):
        raise FaultConfigError("[base]: expected a table")
    if "scenario" in data and isinstance(data["scenario"], str):
        if len(data) != 1:
            raise FaultConfigError("[base]: either scenario = \"NAME-OR-PATH\" alone, or inline tables")
        ref = data["scenario"]
        candidate = root / ref
        try:
            local = candidate.suffix == ".toml" and candidate.exists()
            path = resolve_scenario_path(candidate if local else ref)
            return tomllib.loads(Path(path).read_text(encoding="utf-8"))
        except Exception as exc:  # ScenarioError, OSError, TOML errors: one clear message
            raise FaultConfigError(f"[base] scenario {ref!r}: {exc}") from exc
    return data


def campaign_from_dict(data: dict[str, Any], source: str = "<dict>", root: Path | None = None) -> Campaign:
    """Validate a parsed campaign; every scenario's simulator scenario is validated too."""
    from interface_modules.errors import SimError
    from interface_modules.scenario import scenario_from_dict

    root = root or Path(".")
    if not isinstance(data, dict):
        raise FaultConfigError("a campaign is a TOML table")
    unknown = set(data) - {"campaign", "base", "scenarios"}
    if unknown:
        raise FaultConfigError(
            f"{sorted(unknown)[0]}: unknown top-level key (known: campaign, base, scenarios)"
        )
    head = data.get("campaign", {})
    if not isinstance(head, dict):
        raise FaultConfigError("[campaign]: expected a table")
    bad = set(head) - _CAMPAIGN_KEYS
    if bad:
        known = ", ".join(sorted(_CAMPAIGN_KEYS))
        raise FaultConfigError(f"campaign.{sorted(bad)[0]}: unknown key (known: {known})")
    duration = _number(head.get("duration_s", 120.0), "campaign.duration_s")
    seed = head.get("seed", 1)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise FaultConfigError(f"campaign.seed: a non-negative integer, got {seed!r}")
    speed = _number(head.get("speed", 10.0), "campaign.speed")
    common = _overrides(head.get("listener", []), "campaign.listener")
    base = _base(data.get("base", {}), root)
    rows = data.get("scenarios", [])
    if not isinstance(rows, list) or not rows:
        raise FaultConfigError("[[scenarios]]: at least one scenario is needed")
    specs = []
    names: set[str] = set()
    for i, row in enumerate(rows):
        where = f"scenarios[{i}]"
        if not isinstance(row, dict):
            raise FaultConfigError(f"{where}: expected a table")
        bad = set(row) - _ROW_KEYS
        if bad:
            known = ", ".join(sorted(_ROW_KEYS))
            raise FaultConfigError(f"{where}.{sorted(bad)[0]}: unknown key (known: {known})")
        name = row.get("name")
        if not isinstance(name, str) or not name or not all(ch.isalnum() or ch in "-_." for ch in name):
            raise FaultConfigError(f"{where}.name: a non-empty name of letters, digits, '-', '_', '.'")
        if name in names:
            raise FaultConfigError(f"{where}.name: {name!r} is used twice")
        names.add(name)
        where = f"scenario {name!r}"
        faults = row.get("sensor_faults", [])
        if not isinstance(faults, list) or not all(isinstance(f, dict) for f in faults):
            raise FaultConfigError(f"{where}.sensor_faults: expected a list of tables")
        row_seed = row.get("seed", seed + i)
        if isinstance(row_seed, bool) or not isinstance(row_seed, int) or row_seed < 0:
            raise FaultConfigError(f"{where}.seed: a non-negative integer")
        netns = row.get("netns", False)
        if not isinstance(netns, bool):
            raise FaultConfigError(f"{where}.netns: true or false")
        spec = ScenarioSpec(
            name=name,
            duration_s=_number(row.get("duration_s", duration), f"{where}.duration_s"),
            seed=row_seed,
            base=base,
            input_link=None if "input_link" not in row else impairments_from_dict(row["input_link"],
                                                                                   f"{where}.input_link"),
            output_link=None if "output_link" not in row else impairments_from_dict(row["output_link"],
                                                                                     f"{where}.output_link"),
            obcu=_obcu(row.get("obcu", {}), f"{where}.obcu"),
            sensor_faults=tuple(dict(f) for f in faults),
            listener=common + _overrides(row.get("listener", []), f"{where}.listener"),
            expect=_expect(row.get("expect", {}), f"{where}.expect"),
            speed=_number(row.get("speed", speed), f"{where}.speed"),
            netns=netns,
            timeout_s=None if "timeout_s" not in row else _number(row["timeout_s"], f"{where}.timeout_s"),
            auth=_flag(row.get("auth", False), f"{where}.auth"),
            seeds=_seeds(row.get("seeds", 1), f"{where}.seeds"),
            restart=_restart(row.get("restart"), f"{where}.restart"),
        )
        if spec.restart is not None and spec.restart.kill_window_s[1] >= spec.duration_s:
            raise FaultConfigError(f"{where}.restart.kill_window_s: must end before duration_s")
        try:
            scenario_from_dict(spec.scenario_dict(), source=f"{source}:{name}", base_dir=str(root))
        except SimError as exc:
            raise FaultConfigError(f"{where}: simulator scenario: {exc}") from exc
        specs.append(spec)
    name = head.get("name", Path(source).stem)
    if not isinstance(name, str):
        raise FaultConfigError("campaign.name: expected a string")
    return Campaign(name=name, source=source, scenarios=tuple(specs))


def load_campaign(path: str | Path) -> Campaign:
    """Read and validate a campaign file."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise FaultConfigError(f"{p}: cannot read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise FaultConfigError(f"{p}: not valid TOML: {exc}") from exc
    return campaign_from_dict(data, source=str(p), root=p.resolve().parent)
