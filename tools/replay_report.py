"""Files a replay writes: estimates.csv, estimates.parquet, metrics.json, estimates.geojson.

The figures and report.html are :mod:`tools.report` (the same report as the demo's).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from tools.replay import ESTIMATE_COLUMNS

_INT_COLUMNS = {"seq", "retransmit", "status", "line_id"}


def write_estimates_csv(result, path: Path) -> None:
    """One row per output datagram, in order. Floats use repr: the file is bit-exact."""
    est = result.estimates
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(ESTIMATE_COLUMNS)
        cols = [est[c] for c in ESTIMATE_COLUMNS]
        for i in range(est["epoch"].size):
            w.writerow(
                [
                    str(int(c[i])) if name in _INT_COLUMNS else repr(float(c[i]))
                    for name, c in zip(ESTIMATE_COLUMNS, cols, strict=True)
                ]
            )


def json_default(value: Any) -> Any:
    """``json.dumps`` default: numpy scalars as Python numbers, anything else as its str."""
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return str(value)


def _finite(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    return obj


def write_metrics_json(metrics: dict[str, Any], path: Path) -> None:
    path.write_text(json.dumps(_finite(metrics), indent=2, sort_keys=True, default=json_default) + "\n")


def write_geojson(result, path: Path, every_s: float = 1.0) -> None:
    """The estimated path as a LineString plus one Point per ``every_s`` with its figures (for QGIS)."""
    new = result.new_estimates()
    ok = np.isfinite(new["lat"]) & np.isfinite(new["lon"])
    t, lat, lon = new["epoch"][ok], new["lat"][ok], new["lon"][ok]
    features: list[dict] = []
    if t.size >= 2:
        features.append(
            {
                "type": "Feature",
                "properties": {
                    "name": f"{result.label} estimated path",
                    "epoch_start": float(t[0]),
                    "epoch_end": float(t[-1]),
                },
                "geometry": {
                    "type": "LineString",
                    "coordinates": [
                        [round(float(a), 8), round(float(b), 8)] for a, b in zip(lon, lat, strict=True)
                    ],
                },
            }
        )
    if t.size:
        keep = np.concatenate(([True], np.floor(t[1:] / every_s) != np.floor(t[:-1] / every_s)))
        idx = np.nonzero(ok)[0][keep]
        for i in idx:
            features.append(
                {
                    "type": "Feature",
                    "properties": {
                        "epoch": float(new["epoch"][i]),
                        "arc_length_m": float(new["arc_length"][i]),
                        "speed_mps": float(new["speed"][i]),
                        "sigma_m": _f(new["sigma"][i]),
                        "status": int(new["status"][i]),
                        "line_id": int(new["line_id"][i]),
                    },
                    "geometry": {
                        "type": "Point",
                        "coordinates": [round(float(new["lon"][i]), 8), round(float(new["lat"][i]), 8)],
                    },
                }
            )
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}) + "\n")


def _f(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None
