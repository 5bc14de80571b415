"""The run report an engineer reads at a glance: one self-contained HTML page, the same for replay and demo.

:class:`ReportData` holds what a run produced (estimates, truth, fixes, filter updates, outages, fault
windows, baselines, metrics, and the OBCU link where there is an OBCU); :func:`build_figures` draws it
as matplotlib figures (kept as objects, so tests read their data instead of pixels) and
:func:`write_report` writes the PNGs and ``report.html`` with the figures embedded.

Figures: along-track error and interval against time (GNSS outages and fault windows shaded); the
status and reasons strip; speed; innovations and gating; a map zoomed to the run (estimates, fixes,
true path). A baseline that holds its last value between measurements (the 1 Hz GNSS projection) is
drawn as steps at its fresh values and labelled as held, not as the sawtooth its staleness makes.
"""

from __future__ import annotations

import base64
import csv
import html
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tools.estimates_schema import COLUMNS, REASON_BITS, REASONS_COLUMN, STATUS_CODES
from tools.replay_report import json_default as _json_default

STATUS_COLOURS = {0: "0.65", 1: "tab:green", 2: "tab:orange", 3: "tab:red"}
MAP_MARGIN = 0.05  #: map margin on each side, as a fraction of the run's extent
MAP_MIN_SPAN_M = 40.0  #: smallest map span (a train standing still) [m]
FIGURES = ("error", "status", "speed", "innovations", "map")
_M_PER_DEG_LAT = 111_320.0

# events of interface_modules (docs/simulator.md) that open a window, and the events that close it
_WINDOW_END = {
    "tunnel_in": ("tunnel_out",),
    "gnss_lost": ("gnss_fix",),
    "multipath_step": ("multipath_end", "multipath_step_end"),
    "multipath_ramp": ("multipath_end", "multipath_ramp_end"),
}
_NOT_FAULTS = {"depart", "arrive", "pass", "reverse", "tunnel_out", "gnss_fix", "multipath_end"}


@dataclass
class ReportData:
    """Everything a report shows. Arrays are numpy; times are sensor-set seconds."""

    title: str
    kind: str  #: "replay" or "demo"
    estimates: dict[str, np.ndarray]  #: new estimates: epoch, arc_length, speed, sigma, interval_low/high,
    #: status, line_id, lat, lon
    reasons: np.ndarray | None = None  #: reason bits per estimate (None: not recorded)
    reasons_note: str = ""  #: where the reasons come from when not from these estimates
    truth: dict[str, np.ndarray] | None = None  #: epoch, arc_length, speed[, lat, lon]
    fixes: dict[str, np.ndarray] | None = None  #: t, lat, lon, fix_quality of the GNSS datagrams
    updates: dict[str, np.ndarray] | None = None  #: t, kind, outcome, nis per filter measurement
    updates_note: str = ""  #: where the updates come from when not from these estimates
    outages: list[tuple[float, float]] = field(default_factory=list)  #: GNSS outages (sensor time)
    faults: list[tuple[float, float, str]] = field(default_factory=list)  #: fault windows, known events
    baselines: dict[str, dict[str, Any]] = field(default_factory=dict)  #: name -> epoch, arc_length, held
    comparison: list[dict[str, Any]] | None = None  #: side-by-side accuracy rows
    metrics: dict[str, Any] = field(default_factory=dict)
    link: dict[str, Any] | None = None  #: the OBCU link section (only where there is an OBCU)
    track: Any = None  #: TrackDatabase for the map's lines
    warnings: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)  #: other files of the run, listed in the report

    @property
    def t0(self) -> float:
        e = self.estimates["epoch"]
        return float(e[0]) if e.size else 0.0


# --------------------------------------------------------------------------------------------------
# Inputs


def read_events_csv(path: str | Path) -> list[tuple[float, str, str]]:
    """events.csv of ``sfa sim`` (epoch, kind, detail); bad rows are skipped."""
    out: list[tuple[float, str, str]] = []
    with open(path, newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            try:
                out.append((float(row["epoch"]), row["kind"], row.get("detail") or ""))
            except (KeyError, TypeError, ValueError):
                continue
    return out


def fault_windows(events, end_s: float, start_epoch_s: float | None = None) -> list[tuple[float, float, str]]:
    """Windows ``(start, end, label)`` of the faults and zones in ``events`` (``(epoch, kind, detail)``).

    A kind K opens a window that the next ``K_end`` (or its zone's exit: tunnel_out, gnss_fix,
    multipath_end) closes, the one with the same detail first; a detail "for L s" closes it L seconds
    later, "until X s" at ``start_epoch_s + X`` (scenario time). A window left open ends at ``end_s``.
    ``restart`` is a point (zero-length window); journey events (depart, arrive, ...) and the
    odometer's single dropped samples are not drawn."""
    windows: list[tuple[float, float, str]] = []
    open_: list[tuple[str, str, float]] = []
    for t, kind, detail in sorted(events, key=lambda e: e[0]):
        closers = [w for w in open_ if kind == f"{w[0]}_end" or kind in _WINDOW_END.get(w[0], ())]
        if closers:
            w = next((c for c in closers if c[1] == detail), closers[0])
            open_.remove(w)
            windows.append((w[2], t, f"{w[0]} {w[1]}".strip()))
            continue
        if kind in _NOT_FAULTS or kind.endswith("_end") or kind == "odo_dropout":
            continue
        label = f"{kind} {detail}".strip()
        m_for = re.search(r"for ([0-9.]+) s", detail)
        m_until = re.search(r"until ([0-9.]+) s", detail)
        if kind == "restart":
            windows.append((t, t, label))
        elif m_for:
            windows.append((t, t + float(m_for.group(1)), label))
        elif m_until and start_epoch_s is not None:
            windows.append((t, max(t, start_epoch_s + float(m_until.group(1))), label))
        else:
            open_.append((kind, detail, t))
    windows += [(start, max(start, end_s), f"{k} {d}".strip()) for k, d, start in open_]
    return sorted(windows)


def run_extent(data: ReportData) -> tuple[float, float, float, float]:
    """(lon_min, lon_max, lat_min, lat_max) of the run: the estimated and the true path."""
    lons, lats = [data.estimates["lon"]], [data.estimates["lat"]]
    if data.truth is not None and "lat" in data.truth:
        lons.append(data.truth["lon"])
        lats.append(data.truth["lat"])
    lon, lat = np.concatenate(lons), np.concatenate(lats)
    ok = np.isfinite(lon) & np.isfinite(lat)
    if not ok.any():
        return (math.nan, math.nan, math.nan, math.nan)
    return (float(lon[ok].min()), float(lon[ok].max()), float(lat[ok].min()), float(lat[ok].max()))


def map_limits(extent: tuple[float, float, float, float]) -> tuple[tuple[float, float], tuple[float, float]]:
    """x (lon) and y (lat) limits: the extent plus :data:`MAP_MARGIN` a side, at least MAP_MIN_SPAN_M."""
    x0, x1, y0, y1 = extent
    cos = max(0.1, math.cos(math.radians(0.5 * (y0 + y1))))
    min_lat = MAP_MIN_SPAN_M / _M_PER_DEG_LAT
    min_lon = min_lat / cos

    def pad(a: float, b: float, least: float) -> tuple[float, float]:
        span = max(b - a, least)
        mid = 0.5 * (a + b)
        half = 0.5 * span * (1.0 + 2.0 * MAP_MARGIN)
        return (mid - half, mid + half)

    return pad(x0, x1, min_lon), pad(y0, y1, min_lat)


def nees_verdict(metrics: dict[str, Any]) -> tuple[str, str]:
    """(verdict, comment) of the NEES mean against its 95 % band."""
    nees, band, n = metrics.get("nees_mean"), metrics.get("nees_band_95"), metrics.get("nees_samples")
    if nees is None or not band or band[0] is None:
        return ("not computed", "NEES needs the truth and the estimate's sigma.")
    lo, hi = band
    source = f" ({metrics['nees_source']})" if metrics.get("nees_source") else ""
    head = f"NEES mean {nees:.3g} over {n} one-per-second samples{source}; 95 % band [{lo:.3g}, {hi:.3g}]"
    caveat = (
        " The band assumes independent samples; neighbouring seconds are still correlated, so the"
        " real band is wider."
    )
    if nees < lo:
        return (
            "below the band (pessimistic)",
            f"{head}: the errors are smaller than the filter's sigma says (the reported sigma is about "
            f"{1 / math.sqrt(max(nees, 1e-12)):.2g} times the errors' actual spread). "
            "The intervals are wider than needed: safe, but less useful. Typical causes: sensor noise "
            "presets larger than these sensors' noise, or fault inflation still active." + caveat,
        )
    if nees > hi:
        return (
            "above the band (optimistic)",
            f"{head}: the errors are larger than the filter's sigma says (about "
            f"{math.sqrt(nees):.2g} times). The intervals may not contain the truth as often as they "
            "claim: check interval_coverage. Typical causes: sensor errors larger than the presets, "
            "map or lever-arm errors." + caveat,
        )
    return ("inside the band (consistent)", f"{head}: the sigma the filter reports matches its errors.")


# --------------------------------------------------------------------------------------------------
# Figures


def _shade(ax, data: ReportData, annotate: bool = False) -> None:
    """Shade the GNSS outages (grey) and the fault windows (red; named on the top edge if ``annotate``)."""
    t0 = data.t0
    for k, (a, b) in enumerate(data.outages):
        ax.axvspan(a - t0, b - t0, color="0.85", zorder=0, label="GNSS outage" if k == 0 else None)
    for k, (a, b, label) in enumerate(data.faults):
        if b > a:
            ax.axvspan(a - t0, b - t0, color="tab:red", alpha=0.12, zorder=0,
                       label="fault / zone window" if k == 0 else None)  # fmt: skip
        else:
            ax.axvline(a - t0, color="tab:red", lw=0.8, ls=":", zorder=0)
        if annotate:
            ax.text(a - t0, 0.98, label, transform=ax.get_xaxis_transform(), rotation=90, fontsize=6,
                    va="top", ha="right", color="tab:red")  # fmt: skip


def _error_figure(plt, data: ReportData):
    from tools.accuracy import along_track_errors

    est, t0 = data.estimates, data.t0
    t = est["epoch"] - t0
    fig, ax = plt.subplots(figsize=(10, 4))
    truth = data.truth
    if truth is not None:
        err = along_track_errors(est["epoch"], est["arc_length"], truth["epoch"], truth["arc_length"])
        s_true = est["arc_length"] - err
        if np.isfinite(est["interval_low"]).any():
            ax.fill_between(t, est["interval_low"] - s_true, est["interval_high"] - s_true, alpha=0.3,
                            label="confidence interval", step="post")  # fmt: skip
        ax.plot(t, err, lw=0.8, label="estimate error", color="tab:blue")
        for name, b in data.baselines.items():
            bt, bs = np.asarray(b["epoch"]), np.asarray(b["arc_length"])
            if bt.size == 0:
                continue
            if b.get("held"):
                fresh = np.concatenate(([True], np.diff(bs) != 0))  # a new fix: the value changes
                berr = along_track_errors(bt[fresh], bs[fresh], truth["epoch"], truth["arc_length"])
                ax.plot(bt[fresh] - t0, berr, lw=0.7, alpha=0.8, drawstyle="steps-post",
                        label=f"{name} (held between fixes: error at each fix, drawn as steps)")  # fmt: skip
            else:
                berr = along_track_errors(bt, bs, truth["epoch"], truth["arc_length"])
                ax.plot(bt - t0, berr, lw=0.6, alpha=0.7, label=f"{name} error")
        ax.set_ylabel("along-track error [m]")
        spread = np.concatenate((err, est["interval_low"] - s_true, est["interval_high"] - s_true))
        finite = np.abs(spread[np.isfinite(spread)])
        lim = max(0.2, 1.3 * float(np.percentile(finite, 99))) if finite.size else 5.0
        ax.set_ylim(-lim, lim)  # the estimate's scale: a baseline far off leaves the plot (see the table)
    else:
        ax.plot(t, est["interval_high"] - est["arc_length"], lw=0.8, label="interval, over-reading side")
        ax.plot(t, est["interval_low"] - est["arc_length"], lw=0.8, label="interval, under-reading side")
        ax.set_ylabel("interval around the estimate [m]")
    _shade(ax, data, annotate=True)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("time since the first estimate [s]")
    ax.set_title("along-track error and confidence interval" if truth is not None else "confidence interval")
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    return fig


def _runs(values: np.ndarray) -> list[tuple[int, int, int]]:
    """(start index, end index exclusive, value) of the runs of equal values."""
    if values.size == 0:
        return []
    edges = np.flatnonzero(np.diff(values)) + 1
    starts = np.concatenate(([0], edges))
    ends = np.concatenate((edges, [values.size]))
    return [(int(a), int(b), int(values[a])) for a, b in zip(starts, ends, strict=True)]


def _status_figure(plt, data: ReportData):
    from matplotlib.patches import Patch

    est, t0 = data.estimates, data.t0
    t = est["epoch"] - t0
    t_end = np.append(t[1:], t[-1] + (t[-1] - t[-2] if t.size > 1 else 1.0)) if t.size else t
    status = np.asarray(est["status"], dtype=np.int64)
    reasons = None if data.reasons is None else np.asarray(data.reasons, dtype=np.int64)
    present = [] if reasons is None else [b for b in REASON_BITS if np.any(reasons & b)]
    rows = 1 + len(present)
    fig, ax = plt.subplots(figsize=(10, 1.2 + 0.3 * rows))
    for a, b, code in _runs(status):
        ax.broken_barh([(t[a], t_end[b - 1] - t[a])], (rows - 1 - 0.4, 0.8),
                       color=STATUS_COLOURS.get(code, "k"))  # fmt: skip
    labels = ["status"]
    for k, bit in enumerate(present):
        y = rows - 2 - k
        on = (reasons & bit) != 0
        for a, b, v in _runs(on.astype(np.int64)):
            if v:
                ax.broken_barh([(t[a], t_end[b - 1] - t[a])], (y - 0.35, 0.7), color="tab:purple")
        labels.append(REASON_BITS[bit])
    ax.set_yticks(range(rows - 1, -1, -1), labels, fontsize=7)
    ax.set_ylim(-0.6, rows - 0.4)
    if t.size:
        ax.set_xlim(float(t[0]), float(t_end[-1]))
    _shade(ax, data)
    ax.set_xlabel("time since the first estimate [s]")
    note = ""
    if reasons is None:
        note = " (reasons not recorded for this run)"
    elif data.reasons_note:
        note = f" (reasons: {data.reasons_note})"
    ax.set_title("filter status and the reasons for it" + note, fontsize=9)
    handles = [Patch(color=STATUS_COLOURS[c], label=STATUS_CODES[c][0]) for c in sorted(STATUS_CODES)]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=7)
    fig.tight_layout()
    return fig


def _speed_figure(plt, data: ReportData):
    est, t0 = data.estimates, data.t0
    fig, ax = plt.subplots(figsize=(10, 3))
    ax.plot(est["epoch"] - t0, est["speed"] * 3.6, lw=0.8, label="estimate")
    if data.truth is not None:
        ax.plot(data.truth["epoch"] - t0, data.truth["speed"] * 3.6, lw=0.8, alpha=0.7, label="truth")
    _shade(ax, data)
    ax.set_ylabel("speed [km/h]")
    ax.set_xlabel("time since the first estimate [s]")
    ax.set_title("speed")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    return fig


def _innovations_figure(plt, data: ReportData):
    fig, ax = plt.subplots(figsize=(10, 3))
    upd, t0 = data.updates, data.t0
    drawn = False
    if upd is not None and np.asarray(upd["t"]).size:
        for kind, colour in (("gps", "tab:blue"), ("odo", "tab:orange")):
            sel = (upd["kind"] == kind) & np.isfinite(upd["nis"])
            if not sel.any():
                continue
            drawn = True
            ax.semilogy(upd["t"][sel] - t0, np.maximum(upd["nis"][sel], 1e-6), ".", ms=2, color=colour,
                        label=f"{kind} NIS")  # fmt: skip
            gated = sel & (upd["outcome"] == 1)
            if gated.any():
                ax.semilogy(upd["t"][gated] - t0, np.maximum(upd["nis"][gated], 1e-6), "x", ms=4,
                            color="red", label=f"{kind} gated ({int(gated.sum())})")  # fmt: skip
    if not drawn:
        ax.text(0.5, 0.5, "no innovations recorded for this run", ha="center", va="center",
                transform=ax.transAxes)  # fmt: skip
    _shade(ax, data)
    ax.set_ylabel("normalised innovation squared")
    ax.set_xlabel("time since the first estimate [s]")
    note = f" ({data.updates_note})" if data.updates_note else ""
    ax.set_title("innovations and gating" + note, fontsize=9)
    if drawn:
        ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    return fig


def _map_figure(plt, data: ReportData):
    est = data.estimates
    extent = run_extent(data)
    size = (8.0, 8.0)
    if math.isfinite(extent[0]):  # the figure takes the run's shape (the axes keep the limits exactly)
        (x0, x1), (y0, y1) = map_limits(extent)
        wide = (x1 - x0) * math.cos(math.radians(0.5 * (y0 + y1))) / (y1 - y0)
        size = (8.0, min(9.0, max(3.5, 7.0 / wide + 1.0)))
    fig, ax = plt.subplots(figsize=size)
    if data.track is not None:
        for lid in sorted({int(x) for x in est["line_id"] if x >= 0}):
            try:
                line = data.track.line(lid)
            except Exception:  # noqa: BLE001 - a line id the database lacks is simply not drawn
                continue
            ax.plot(line.lon_deg, line.lat_deg, color="0.6", lw=2.0, label=f"track line {lid}", zorder=1)
    if data.truth is not None and "lat" in data.truth:
        ax.plot(data.truth["lon"], data.truth["lat"], "k--", lw=0.9, label="true path", zorder=3)
    f = data.fixes
    if f is not None and np.asarray(f["t"]).size:
        fix = f["fix_quality"] != 0
        ax.plot(f["lon"][fix], f["lat"][fix], ".", ms=4, color="tab:orange", label="GNSS fixes", zorder=2)
    ok = np.isfinite(est["lat"]) & np.isfinite(est["lon"])
    ax.plot(est["lon"][ok], est["lat"][ok], lw=1.2, color="tab:blue", label="estimates", zorder=4)
    if math.isfinite(extent[0]):
        (x0, x1), (y0, y1) = map_limits(extent)
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect(1.0 / max(0.1, math.cos(math.radians(0.5 * (y0 + y1)))), adjustable="box")
        span_m = (y1 - y0) * _M_PER_DEG_LAT
        ax.set_title(f"map of the run ({span_m:,.0f} m north-south shown)", fontsize=9)
    ax.set_xlabel("longitude [deg]")
    ax.set_ylabel("latitude [deg]")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.legend(loc="best", fontsize=7)
    fig.tight_layout()
    return fig


def build_figures(data: ReportData) -> dict[str, Any]:
    """The report's matplotlib figures by name (:data:`FIGURES`); empty when there is no estimate."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if data.estimates["epoch"].size == 0:
        return {}
    return {
        "error": _error_figure(plt, data),
        "status": _status_figure(plt, data),
        "speed": _speed_figure(plt, data),
        "innovations": _innovations_figure(plt, data),
        "map": _map_figure(plt, data),
    }


# --------------------------------------------------------------------------------------------------
# HTML


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}" if math.isfinite(v) else "-"
    return str(v)


_SUMMARY = (
    ("rms_m", "RMS along-track error", "m"),
    ("p50_m", "median |error|", "m"),
    ("p95_m", "95th percentile |error|", "m"),
    ("max_m", "largest |error|", "m"),
    ("outage_max_m", "largest |error| in GNSS outages", "m"),
    ("interval_coverage", "fraction of estimates whose interval contains the truth", "-"),
    ("etcs_compliance", "fraction within ETCS 5 m + 5 % of distance since the last fix", "-"),
    ("messages", "input datagrams", "count"),
    ("new_estimates", "new estimates", "count"),
    ("retransmissions", "retransmissions", "count"),
)


def _table(rows: list[tuple[str, ...]], head: tuple[str, ...] | None = None) -> str:
    h = "" if head is None else "<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in head) + "</tr>"
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table>{h}{body}</table>"


def _status_table(data: ReportData) -> str:
    status = np.asarray(data.estimates["status"], dtype=np.int64)
    rows = [(f"{c} {name}", f"{100 * float(np.mean(status == c)):.1f} %", meaning)
            for c, (name, meaning) in sorted(STATUS_CODES.items())] if status.size else []  # fmt: skip
    out = _table(rows, ("status", "time share", "meaning"))
    if data.reasons is not None and status.size:
        r = np.asarray(data.reasons, dtype=np.int64)
        rr = [(name, f"{100 * float(np.mean((r & bit) != 0)):.1f} %") for bit, name in REASON_BITS.items()
              if np.any(r & bit)]  # fmt: skip
        if rr:
            out += _table(rr, ("reason", "time share"))
    return out


def _dictionary() -> str:
    rows = [(c.name, c.unit, c.description) for c in (*COLUMNS, REASONS_COLUMN)]
    codes = ", ".join(f"{k} {n}" for k, (n, _) in sorted(STATUS_CODES.items()))
    bits = ", ".join(f"{b} {n}" for b, n in REASON_BITS.items())
    return (
        "<details><summary>Data dictionary of estimates.csv / estimates.parquet</summary>"
        + _table(rows, ("column", "unit", "meaning"))
        + f"<p>status codes: {html.escape(codes)}.<br>reason bits: {html.escape(bits)}.</p></details>"
    )


def _link_section(link: dict[str, Any]) -> str:
    rows = []
    for k, v in link.items():
        if isinstance(v, dict | list):
            v = json.dumps(v, default=_json_default)
        rows.append((str(k), _fmt(v)))
    return "<h2>OBCU link</h2>" + _table(rows, ("figure", "value"))


def write_report(data: ReportData, out: str | Path, filename: str = "report.html") -> Path:
    """Write the figures (PNG) and the self-contained ``report.html`` into ``out``; return the HTML path."""
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figures = build_figures(data)
    imgs = []
    for name, fig in figures.items():
        png = out / f"{name}.png"
        fig.savefig(png, dpi=100)
        plt.close(fig)
        b64 = base64.b64encode(png.read_bytes()).decode()
        imgs.append(f'<figure><img alt="{name}" src="data:image/png;base64,{b64}">'
                    f"<figcaption>{name}</figcaption></figure>")  # fmt: skip
    m = data.metrics
    summary = _table([(label, _fmt(m.get(key)), unit) for key, label, unit in _SUMMARY if key in m],
                     ("figure", "value", "unit"))  # fmt: skip
    verdict, comment = nees_verdict(m)
    nees = f"<h2>Consistency (NEES): {html.escape(verdict)}</h2><p>{html.escape(comment)}</p>"
    warn = "".join(f"<p class='warn'>warning: {html.escape(w)}</p>" for w in data.warnings)
    comp = ""
    if data.comparison:
        cols = ("label", "p95_m", "max_m", "rms_m", "interval_coverage")
        held = {n for n, b in data.baselines.items() if b.get("held")}
        rows = [tuple(_fmt(r.get(c)) for c in cols)
                + ("holds its last fix between fixes: its error includes the distance travelled since"
                   if r.get("label") in held else "",) for r in data.comparison]  # fmt: skip
        comp = "<h2>Side by side (same measurements)</h2>" + _table(rows, (*cols, "note"))
    link = _link_section(data.link) if data.link is not None else ""
    files = ""
    if data.files:
        files = "<p>files: " + ", ".join(html.escape(f) for f in data.files) + "</p>"
    shown = dict(m.get("pipeline", {}))
    counters_note = ""
    if data.link is None and shown.pop("link", None) is not None:  # a replay has no OBCU: no acks, so
        counters_note = " (the OBCU link counters are left out: there is no OBCU in a replay)"  # "down"
    counters = html.escape(json.dumps(shown, indent=2, default=_json_default))
    page = (
        "<!doctype html><html><head><meta charset='utf-8'>"
        f"<title>{html.escape(data.title)}</title><style>body{{font-family:sans-serif;max-width:1100px;"
        "margin:auto}table{border-collapse:collapse;margin:6px 0}td,th{border:1px solid #ccc;"
        "padding:3px 8px;text-align:left}img{max-width:100%}pre{background:#f6f6f6;padding:8px;"
        "overflow:auto}.warn{color:#a40;font-weight:bold}</style></head><body>"
        f"<h1>{html.escape(data.title)}</h1>{warn}{summary}{nees}<h2>Status</h2>{_status_table(data)}"
        f"{comp}{''.join(imgs)}{link}{files}{_dictionary()}"
        f"<details><summary>Pipeline counters{counters_note}</summary><pre>{counters}</pre></details>"
        "</body></html>\n"
    )
    path = out / filename
    path.write_text(page, encoding="utf-8")
    return path


def replay_report_data(result, metrics, truth, track, baselines=None, comparison=None, events=None,
                       title: str = "sfa replay") -> ReportData:  # fmt: skip
    """The report of a replay (:mod:`tools.replay`): no OBCU link section (there is no OBCU)."""
    new = result.new_estimates()
    faults = []
    if events:
        end = float(new["epoch"][-1]) if new["epoch"].size else 0.0
        start = float(truth["epoch"][0]) if truth is not None else None  # sfa sim: truth starts at t = 0
        faults = [w for w in fault_windows(events, end, start) if w[0] <= end]
    reasons = result.new_reasons() if hasattr(result, "new_reasons") else None
    return ReportData(
        title=title,
        kind="replay",
        estimates=new,
        reasons=reasons,
        truth=truth,
        fixes=result.gps,
        updates=result.updates,
        outages=[tuple(o) for o in metrics.get("gnss_outages", [])],
        faults=faults,
        baselines=baselines or {},
        comparison=comparison,
        metrics=metrics,
        track=track,
        warnings=list(result.capture.get("warnings", [])),
    )
