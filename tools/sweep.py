"""Parameter sweeps over replays: which sensors are enabled, filter noise settings, gates.

A sweep is the Cartesian product of axes. An axis is either a sensor-set axis
(``imu+odo,imu+gps,all``: each item a ``+``-joined subset of imu, odo/odometer, gps, or ``all``) or a
filter field axis (``gps_white_sigma_m=0.3,0.5,1``: any :class:`sfa.config.FilterConfig` field, values
parsed as TOML scalars). Aliases: ``gps.sigma`` means ``gps_nominal_sigma_h_m`` and
``gps_white_sigma_m`` scaled together is not implied; use the field names for anything else.
A sweep file is TOML: ``[[config]]`` tables, each with optional ``label``, ``sensors`` (list) and any
FilterConfig fields.

Each configuration replays the capture in its own process (``concurrent.futures``), so a sweep uses
the local cores; results come back in the order the configurations were listed.
"""

from __future__ import annotations

import itertools
import tomllib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from tools.errors import ToolError

ALIASES = {
    "gps.sigma": "gps_nominal_sigma_h_m",
    "gps.white": "gps_white_sigma_m",
    "gps.gate": "gate_prob_gps",
    "odo.gate": "gate_prob_odo",
    "imu.noise": "accel_noise_density_mps2_rthz",
}
_SENSOR_NAMES = {"imu": "imu", "odo": "odometer", "odometer": "odometer", "gps": "gps"}


@dataclass(frozen=True)
class SweepConfig:
    label: str
    sensors: frozenset[str]
    overrides: tuple[tuple[str, Any], ...]


def _parse_value(text: str) -> Any:
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _sensor_set(item: str) -> frozenset[str]:
    if item == "all":
        return frozenset({"imu", "odometer", "gps"})
    out = set()
    for part in item.split("+"):
        name = _SENSOR_NAMES.get(part.strip())
        if name is None:
            raise ToolError(f"--sweep: unknown sensor {part!r} (imu, odo, gps or all)")
        out.add(name)
    return frozenset(out)


def _field_names() -> set[str]:
    import dataclasses

    from sfa.config import FilterConfig

    return {f.name for f in dataclasses.fields(FilterConfig)}


def parse_axes(specs: list[str]) -> list[list[tuple[str, Any]]]:
    """Each ``--sweep`` spec -> a list of (key, value) alternatives; key "sensors" or a field name."""
    fields = _field_names()
    axes: list[list[tuple[str, Any]]] = []
    for spec in specs:
        if "=" in spec:
            key, _, values = spec.partition("=")
            key = ALIASES.get(key.strip(), key.strip())
            if key not in fields:
                raise ToolError(f"--sweep {spec!r}: {key!r} is not a filter setting")
            items = [v.strip() for v in values.split(",") if v.strip()]
            if not items:
                raise ToolError(f"--sweep {spec!r}: no values")
            axes.append([(key, _parse_value(v)) for v in items])
        else:
            items = [v.strip() for v in spec.split(",") if v.strip()]
            if not items:
                raise ToolError(f"--sweep {spec!r}: no sensor sets")
            axes.append([("sensors", _sensor_set(v)) for v in items])
    return axes


def configs_from_axes(axes: list[list[tuple[str, Any]]]) -> list[SweepConfig]:
    out = []
    for combo in itertools.product(*axes):
        sensors = frozenset({"imu", "odometer", "gps"})
        overrides = []
        parts = []
        for key, value in combo:
            if key == "sensors":
                sensors = value
                parts.append("+".join(sorted(value)))
            else:
                overrides.append((key, value))
                parts.append(f"{key}={value}")
        out.append(SweepConfig(",".join(parts) or "default", sensors, tuple(overrides)))
    return out


def configs_from_file(path: str | Path) -> list[SweepConfig]:
    fields = _field_names()
    try:
        data = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ToolError(f"sweep file {path}: {exc}") from exc
    tables = data.get("config")
    if not isinstance(tables, list) or not tables:
        raise ToolError(f"sweep file {path}: expected one or more [[config]] tables")
    out = []
    for i, t in enumerate(tables, start=1):
        if not isinstance(t, dict):
            raise ToolError(f"sweep file {path}: config {i} is not a table")
        sensors = frozenset({"imu", "odometer", "gps"})
        overrides = []
        for key, value in t.items():
            if key == "label":
                continue
            if key == "sensors":
                if not isinstance(value, list):
                    raise ToolError(f"sweep file {path}: config {i}: sensors must be a list")
                sensors = _sensor_set("+".join(str(v) for v in value))
                continue
            key = ALIASES.get(key, key)
            if key not in fields:
                raise ToolError(f"sweep file {path}: config {i}: {key!r} is not a filter setting")
            overrides.append((key, value))
        out.append(SweepConfig(str(t.get("label", f"config {i}")), sensors, tuple(overrides)))
    return out


def _run_one(args: tuple) -> dict[str, Any]:
    capture, track_path, base_options, cfg, truth = args
    from tools.replay import replay_capture
    from tools.replay_metrics import replay_metrics
    from track_db import TrackDatabase

    track = TrackDatabase.open(track_path)
    options = replace(base_options, sensors=cfg.sensors, filter_overrides=cfg.overrides, label=cfg.label)
    result = replay_capture(capture, track, options)
    m = replay_metrics(result, truth)
    m.pop("pipeline", None)
    return m


def run_sweep(capture, track_path, base_options, configs: list[SweepConfig], truth, jobs: int) -> list[dict]:
    """Replay ``capture`` once per configuration, ``jobs`` at a time; metrics in configuration order."""
    work = [(str(capture), str(track_path), base_options, cfg, truth) for cfg in configs]
    if jobs <= 1 or len(work) == 1:
        return [_run_one(w) for w in work]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        return list(pool.map(_run_one, work))


TABLE_COLUMNS = (
    "label",
    "p95_m",
    "max_m",
    "rms_m",
    "outage_max_m",
    "interval_coverage",
    "nees_mean",
    "etcs_compliance",
    "new_estimates",
)


def write_table(rows: list[dict], out: Path, stem: str = "sweep") -> tuple[Path, Path]:
    """The sweep table as CSV and Markdown."""
    import csv

    csv_path, md_path = out / f"{stem}.csv", out / f"{stem}.md"
    with open(csv_path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(TABLE_COLUMNS)
        for r in rows:
            w.writerow([_cell(r.get(c)) for c in TABLE_COLUMNS])
    lines = ["| " + " | ".join(TABLE_COLUMNS) + " |", "|" + "---|" * len(TABLE_COLUMNS)]
    lines += ["| " + " | ".join(_cell(r.get(c)) for c in TABLE_COLUMNS) + " |" for r in rows]
    md_path.write_text("\n".join(lines) + "\n")
    return csv_path, md_path


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)
