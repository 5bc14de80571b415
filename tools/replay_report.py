"""Files a replay writes: estimates.csv, metrics.json, estimates.geojson, PNG figures, report.html."""

from __future__ import annotations

import base64
import csv
import html
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


def _json_default(value: Any) -> Any:
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
    path.write_text(json.dumps(_finite(metrics), indent=2, sort_keys=True, default=_json_default) + "\n")


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


def write_figures(
    result, metrics: dict[str, Any], truth, track, out: Path, baselines: dict[str, Any] | None = None
) -> list[Path]:
    """PNG figures: error/interval (outages shaded), speed, innovations/gating, map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tools.accuracy import along_track_errors

    new = result.new_estimates()
    if new["epoch"].size == 0:
        return []
    t0 = float(new["epoch"][0])
    t = new["epoch"] - t0
    outages = metrics.get("gnss_outages", [])
    paths: list[Path] = []

    def shade(ax):
        for a, b in outages:
            ax.axvspan(a - t0, b - t0, color="0.85", zorder=0)

    fig, ax = plt.subplots(figsize=(10, 4))
    if truth is not None:
        err = along_track_errors(new["epoch"], new["arc_length"], truth["epoch"], truth["arc_length"])
        s_true = new["arc_length"] - err
        ax.fill_between(
            t,
            new["interval_low"] - s_true,
            new["interval_high"] - s_true,
            alpha=0.3,
            label="confidence interval",
        )
        ax.plot(t, err, lw=0.8, label=f"{result.label} error")
        for name, b in (baselines or {}).items():
            bt = b["epoch"]
            berr = along_track_errors(bt, b["arc_length"], truth["epoch"], truth["arc_length"])
            ax.plot(bt - t0, berr, lw=0.6, alpha=0.7, label=f"{name} error")
        ax.set_ylabel("along-track error [m]")
        lim = max(5.0, 1.5 * float(np.nanpercentile(np.abs(err), 99)))
        ax.set_ylim(-lim, lim)
    else:
        ax.plot(t, new["interval_high"] - new["arc_length"], lw=0.8, label="interval half-width (over)")
        ax.plot(t, new["interval_low"] - new["arc_length"], lw=0.8, label="interval half-width (under)")
        ax.set_ylabel("interval around the estimate [m]")
    shade(ax)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("time [s] (GNSS outages shaded)")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    paths.append(out / "error.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(10, 3))
    ax.plot(t, new["speed"] * 3.6, lw=0.8, label="estimate")
    if truth is not None:
        ax.plot(truth["epoch"] - t0, truth["speed"] * 3.6, lw=0.8, alpha=0.7, label="truth")
    shade(ax)
    ax.set_ylabel("speed [km/h]")
    ax.set_xlabel("time [s]")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    paths.append(out / "speed.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)

    upd = result.updates
    fig, ax = plt.subplots(figsize=(10, 3))
    for kind, colour in (("gps", "tab:blue"), ("odo", "tab:orange")):
        sel = (upd["kind"] == kind) & np.isfinite(upd["nis"])
        if sel.any():
            gated = sel & (upd["outcome"] == 1)
            ax.semilogy(
                upd["t"][sel] - t0,
                np.maximum(upd["nis"][sel], 1e-6),
                ".",
                ms=2,
                color=colour,
                label=f"{kind} NIS",
            )
            if gated.any():
                ax.semilogy(
                    upd["t"][gated] - t0,
                    np.maximum(upd["nis"][gated], 1e-6),
                    "x",
                    ms=4,
                    color="red",
                    label=f"{kind} gated",
                )
    shade(ax)
    ax.set_ylabel("normalised innovation squared")
    ax.set_xlabel("time [s]")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    paths.append(out / "innovations.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7, 7))
    line_ids = sorted({int(x) for x in new["line_id"] if x >= 0})
    for lid in line_ids:
        try:
            line = track.line(lid)
        except Exception:  # noqa: BLE001 - a line id the database lacks is simply not drawn
            continue
        ax.plot(line.lon_deg, line.lat_deg, color="0.5", lw=1.5, label=f"track line {lid}")
    g = result.gps
    if g["t"].size:
        fix = g["fix_quality"] != 0
        ax.plot(g["lon"][fix], g["lat"][fix], ".", ms=3, color="tab:orange", label="GNSS fixes")
    ok = np.isfinite(new["lat"])
    ax.plot(new["lon"][ok], new["lat"][ok], lw=1.0, color="tab:blue", label="estimates")
    ax.set_aspect(
        1.0 / max(0.1, math.cos(math.radians(float(np.nanmean(new["lat"][ok])) if ok.any() else 0)))
    )
    ax.set_xlabel("longitude [deg]")
    ax.set_ylabel("latitude [deg]")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    paths.append(out / "map.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)
    return paths


def write_html(
    metrics: dict[str, Any],
    figures: list[Path],
    path: Path,
    title: str,
    comparison: list[dict[str, Any]] | None = None,
) -> None:
    """A self-contained report: figures embedded as data URIs, the metrics as tables."""
    keys = (
        "rms_m",
        "p50_m",
        "p95_m",
        "max_m",
        "outage_max_m",
        "interval_coverage",
        "nees_mean",
        "etcs_compliance",
        "messages",
        "new_estimates",
        "retransmissions",
    )
    rows = "".join(
        f"<tr><th>{html.escape(k)}</th><td>{html.escape(_fmt(metrics.get(k)))}</td></tr>"
        for k in keys
        if k in metrics
    )
    comp = ""
    if comparison:
        cols = ["label", "p95_m", "max_m", "rms_m", "interval_coverage"]
        head = "".join(f"<th>{c}</th>" for c in cols)
        body = "".join(
            "<tr>" + "".join(f"<td>{html.escape(_fmt(r.get(c)))}</td>" for c in cols) + "</tr>"
            for r in comparison
        )
        comp = f"<h2>Side by side</h2><table><tr>{head}</tr>{body}</table>"
    imgs = "".join(
        f'<figure><img alt="{p.stem}" src="data:image/png;base64,'
        f'{base64.b64encode(p.read_bytes()).decode()}"><figcaption>{p.stem}</figcaption></figure>'
        for p in figures
    )
    counters = html.escape(json.dumps(_finite(metrics.get("pipeline", {})), indent=2, default=_json_default))
    path.write_text(
        "<!doctype html><html><head><meta charset='utf-8'>"
        f"<title>{html.escape(title)}</title><style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}"
        "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}"
        "img{max-width:100%}pre{background:#f6f6f6;padding:8px;overflow:auto}</style></head><body>"
        f"<h1>{html.escape(title)}</h1><table>{rows}</table>{comp}{imgs}"
        f"<h2>Pipeline counters</h2><pre>{counters}</pre></body></html>\n"
    )


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}" if math.isfinite(v) else "-"
    return str(v)
