"""``sfa faults campaign``: run every scenario of a campaign in parallel and write the results tables.

Executors: local child processes (``--jobs`` at once, default the number of cores; each scenario in
its own process with a wall-time budget, so a hang is a result and not a stuck campaign) or, with
``--executor dask --scheduler ADDRESS``, an existing Dask cluster
(``dask.distributed.Client.submit``); Dask is optional and only imported when asked for. Each
scenario is independent and deterministic, so results do not depend on the executor or the order.

Outputs in ``--out DIR``: ``results.csv``, ``results.md``, ``results.html`` (one row per scenario,
same columns), ``campaign.json`` (rows plus the command), and a directory per scenario with its
artefacts.
"""

from __future__ import annotations

import csv
import html
import json
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from tools.faults.errors import CampaignError
from tools.faults.runner import run_scenario, run_scenario_guarded, wall_budget_s
from tools.faults.spec import Campaign

#: column order of the tables (a row may lack some: shown as "-")
COLUMNS = (
    "scenario", "mode", "verdict", "sim_s", "crashes", "fresh_outputs", "p95_m", "max_m", "coverage",
    "fault_coverage", "reasons", "told_s", "told_status", "nominal_age_max_s", "lost_inj", "lost_det",
    "dup_inj", "dup_det", "reord_inj", "reord_det",
    "rej_inj", "rej_det", "net_drops", "flips", "forged_valid", "accepted_bad", "resyncs",
    "foreign_inj", "foreign_det", "jump_inj", "late_det", "jump_drops", "trust_warnings", "auth_acc",
    "auth_rej", "auth_bad", "age_p99_s", "age_max_s", "stale_fresh",
    "degraded_after_s", "recover_s", "memory_growth_mb", "latency_p99_ms", "link_timeline", "checks",
    "wall_s", "notes",
)


def run_campaign(
    campaign: Campaign,
    mode: str,
    out_dir: str | Path,
    *,
    jobs: int | None = None,
    executor: str = "local",
    scheduler: str | None = None,
    only: list[str] | None = None,
    progress: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Run the scenarios (all, or those named in ``only``); returns the rows in campaign order."""
    if mode not in ("replay", "live"):
        raise CampaignError(f"mode {mode!r}: expected replay or live")
    specs = list(campaign.scenarios)
    if only:
        unknown = sorted(set(only) - {s.name for s in specs})
        if unknown:
            raise CampaignError(f"no scenario named {unknown[0]!r} in {campaign.source}")
        specs = [s for s in specs if s.name in only]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows: dict[str, dict[str, Any]] = {}
    if executor == "dask":
        rows = _run_dask(specs, mode, out, scheduler, progress)
    elif executor == "local":
        workers = max(1, min(jobs or os.cpu_count() or 1, len(specs)))
        # each scenario runs in its own child process (killed if it stalls); threads only wait
        with ThreadPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(run_scenario_guarded, spec, mode, str(out)): spec.name for spec in specs}
            for fut, name in futures.items():
                rows[name] = fut.result()
                if progress:
                    progress(rows[name])
    else:
        raise CampaignError(f"executor {executor!r}: expected local or dask")
    ordered = [rows[s.name] for s in specs]
    write_tables(ordered, out, title=f"{campaign.name} ({mode})")
    return ordered


def _run_dask(specs, mode, out: Path, scheduler: str | None, progress) -> dict[str, dict[str, Any]]:
    try:
        from dask.distributed import Client
    except ImportError as exc:
        raise CampaignError("--executor dask needs the 'distributed' package "
                            "(pip install 'dask[distributed]')") from exc
    if not scheduler:
        raise CampaignError("--executor dask needs --scheduler ADDRESS (an existing Dask scheduler)")
    from dask.distributed import TimeoutError as DaskTimeout

    rows = {}
    with Client(scheduler) as client:
        # run_scenario, not the guarded child process: Dask's worker processes are daemonic and may
        # not start children. The wall-time budget is kept on the client side instead: a row past it
        # is reported as stalled (a crash) and its task cancelled (a hung worker thread is not killed)
        futures = {s.name: (s, client.submit(run_scenario, s, mode, str(out), pure=False)) for s in specs}
        # rows queue behind each other on a small cluster: allow a row its budget once per wave
        waves = -(-len(specs) // max(1, sum(client.nthreads().values())))
        t0 = time.monotonic()
        for name, (spec, fut) in futures.items():
            budget = wall_budget_s(spec, mode)
            try:
                rows[name] = fut.result(timeout=max(0.0, t0 + budget * waves - time.monotonic()))
            except (DaskTimeout, TimeoutError):
                fut.cancel()
                rows[name] = {"scenario": name, "mode": mode, "verdict": "FAIL", "crashes": 1,
                              "checks": "crashes:FAIL", "wall_s": round(time.monotonic() - t0, 1),
                              "notes": f"stalled: no result after {budget:.0f} s of wall time on the Dask "
                                       "cluster (a hang counts as a crash)"}
            if progress:
                progress(rows[name])
    return rows


def _cell(row: dict[str, Any], col: str) -> str:
    value = row.get(col, "-")
    return "-" if value is None or value == "" else str(value)


def write_tables(rows: list[dict[str, Any]], out: Path, title: str = "campaign") -> dict[str, Path]:
    """results.csv, results.md, results.html with :data:`COLUMNS`; returns their paths."""
    paths = {"csv": out / "results.csv", "md": out / "results.md", "html": out / "results.html"}
    with open(paths["csv"], "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(COLUMNS)
        for row in rows:
            writer.writerow([_cell(row, c) for c in COLUMNS])
    lines = [f"| {' | '.join(COLUMNS)} |", f"|{'---|' * len(COLUMNS)}"]
    for row in rows:
        lines.append("| " + " | ".join(_cell(row, c).replace("|", "/") for c in COLUMNS) + " |")
    paths["md"].write_text("\n".join(lines) + "\n")
    head = "".join(f"<th>{html.escape(c)}</th>" for c in COLUMNS)
    body = []
    for row in rows:
        verdict = _cell(row, "verdict")
        colour = {"PASS": "#e6f4ea", "FAIL": "#fce8e6", "ERROR": "#fff4e5"}.get(verdict, "#ffffff")
        cells = "".join(f"<td>{html.escape(_cell(row, c))}</td>" for c in COLUMNS)
        body.append(f'<tr style="background:{colour}">{cells}</tr>')
    paths["html"].write_text(
        "<!doctype html><html><head><meta charset=\"utf-8\">"
        f"<title>{html.escape(title)}</title><style>table{{border-collapse:collapse;font:12px sans-serif}}"
        "td,th{border:1px solid #ccc;padding:2px 4px;vertical-align:top}</style></head><body>"
        f"<h1>{html.escape(title)}</h1><table><tr>{head}</tr>{''.join(body)}</table></body></html>\n"
    )
    (out / "campaign.json").write_text(json.dumps({"title": title, "rows": rows}, indent=1, default=str))
    return paths
