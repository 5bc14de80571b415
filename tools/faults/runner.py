"""Run one campaign scenario (replay path or live processes) and evaluate it into a results row.

:func:`run_scenario` is what the campaign's executors call, one scenario per worker process; it
takes only picklable arguments and returns a plain dict, so a process pool or a Dask cluster can run
it unchanged. Per-scenario artefacts (scenario TOML, logs, traces, and each run's ``outputs.csv``: its
error and interval over time, :mod:`tools.faults.timeline`) go into ``out_dir/<name>/``.
"""

from __future__ import annotations

import json
import math
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np

from tools.faults.errors import CampaignError, ModeUnsupported
from tools.faults.evaluate import Observation, evaluate_pooled
from tools.faults.spec import ScenarioSpec
from tools.faults.timeline import write_outputs_csv


def build_scenario(spec: ScenarioSpec):
    """The validated simulator scenario of ``spec``."""
    from interface_modules.scenario import scenario_from_dict

    return scenario_from_dict(spec.scenario_dict(), source=f"campaign:{spec.name}")


def listener_config(spec: ScenarioSpec, sc, track_path: Path):
    """The listener configuration: extended output, the scenario's filter presets, the row's overrides."""
    from listener.config import load_config

    overrides = [
        "link.extended=true",
        f'filter.imu="{sc.imu.preset}"',
        f'filter.odometer="{sc.odometer.preset}"',
        f'filter.gps="{sc.gps.preset}"',
        f'track="{track_path}"',
        *spec.listener,
    ]
    return load_config(None, overrides), overrides


def fault_windows(sc, sim) -> list[tuple[float, float]]:
    """(start_s, end_s) of every sensor fault of the scenario, from the scenario start."""
    end = float(sim.truth["epoch"][-1] - sc.start_epoch_s)
    out = []
    for f in sc.faults:
        if f.start_s is not None:
            out.append((float(f.start_s), end if f.end_s is None else float(f.end_s)))
        elif f.from_m is not None and f.to_m is not None:  # a zone: when the train is inside it
            s = np.asarray(sim.truth["arc_length"])
            t = np.asarray(sim.truth["epoch"]) - sc.start_epoch_s
            inside = (s >= f.from_m) & (s < f.to_m)
            if inside.any():
                out.append((float(t[inside][0]), float(t[inside][-1])))
    return out


def output_outages(spec: ScenarioSpec) -> tuple[tuple[float, float], ...]:
    """Windows in which the OBCU link is cut: output-link blackouts, a silent OBCU, withheld acks."""
    return (spec.output_link.blackouts if spec.output_link else ()) + spec.obcu.silent + spec.obcu.drop_acks


def campaign_master_key(spec: ScenarioSpec) -> bytes:
    """The master key of an authenticated row (fixed per row: the replay path stays deterministic)."""
    return b"sfa-campaign-master-key:" + spec.name.encode()


def run_replay(spec: ScenarioSpec, out_dir: Path) -> Observation:
    """The replay path: offline datagrams through the whole system on scripted time."""
    from interface_modules.offline import generate
    from interface_modules.tracks import database_path
    from listener.obcu import ObcuConfig
    from tools.faults.replay_path import run_replay_path
    from track_db import TrackDatabase

    sc = build_scenario(spec)
    track_path = database_path(sc)
    if track_path is None:
        raise CampaignError(f"{spec.name}: synthetic tracks have no database the listener can open")
    sim = generate(sc)
    cfg, _ = listener_config(spec, sc, track_path)
    obcu_cfg = ObcuConfig(drop_acks=spec.obcu.drop_acks, silent=spec.obcu.silent,
                          restart_at_s=spec.obcu.restart_at_s)
    with TrackDatabase.open(track_path) as track:
        trace = run_replay_path(sim.packets, track, cfg, input_link=spec.input_link,
                                output_link=spec.output_link, obcu_config=obcu_cfg, seed=spec.seed,
                                auth_master=campaign_master_key(spec) if spec.auth else None,
                                restart=None if spec.restart is None else (
                                    spec.restart.kill_at_s(spec.seed), spec.restart.down_s),
                                work_dir=out_dir)
    t0 = trace.start_s
    fresh = trace.fresh
    arrival = np.array([f.arrival_s for f in fresh]) - t0
    epoch = np.array([f.epoch_s for f in fresh])
    obs = Observation(
        name=spec.name, mode="replay", simulated_s=float(sim.duration_s),
        truth_epoch=np.asarray(sim.truth["epoch"], float),
        truth_arc=np.asarray(sim.truth["arc_length"], float),
        start_epoch_s=sc.start_epoch_s,
        fresh_arrival=arrival, fresh_epoch=epoch,
        fresh_arc=np.array([f.arc_length_m for f in fresh]),
        fresh_lo=np.array([f.interval_low_m for f in fresh]),
        fresh_hi=np.array([f.interval_high_m for f in fresh]),
        fresh_age=np.array([f.arrival_s for f in fresh]) - epoch,
        fresh_reasons=[f.reasons for f in fresh],
        metrics=trace.metrics, link_transitions=trace.link_transitions,
        input_proxy=trace.input_proxy, output_proxy=trace.output_proxy,
        input_blackouts=spec.input_link.blackouts if spec.input_link else (),
        output_blackouts=output_outages(spec),
        sensor_fault_windows=fault_windows(sc, sim),
        crashes=1 if trace.crash else 0, crash_detail=trace.crash, wall_s=trace.wall_s,
        corruption=bool(spec.input_link and (spec.input_link.bitflip > 0 or spec.input_link.forge_on_stream)),
    )
    obs.auth = trace.auth
    obs.restart = trace.restart
    obs.status_reasons = set(trace.status_reasons)
    if trace.stop_s is not None and trace.stop_arrival_s is not None:
        obs.stop_exit_s = trace.stop_s - trace.stop_arrival_s
    obs.fresh_status = np.array([f.status for f in fresh], dtype=np.int64)
    if trace.crash:
        obs.notes.append("crash: " + trace.crash.strip().splitlines()[-1])
    (out_dir / "trace.json").write_text(json.dumps({
        "metrics": trace.metrics, "input_proxy": trace.input_proxy, "output_proxy": trace.output_proxy,
        "obcu": trace.obcu_stats, "auth": trace.auth, "link_transitions": trace.link_transitions,
        "events": trace.events, "crash": trace.crash, "restart": trace.restart,
        "stop_arrival_s": trace.stop_arrival_s, "stop_s": trace.stop_s,
    }, indent=1, default=str))
    return obs


def run_scenario(spec: ScenarioSpec, mode: str, out_dir: str) -> dict[str, Any]:
    """Run and evaluate one scenario; never raises for a failure of the system under test.

    A failure of the harness itself (bad scenario, a process that cannot start) becomes a row with
    ``verdict`` ERROR and the reason in ``notes``, so one broken row does not lose the campaign.
    """
    out = Path(out_dir) / spec.name
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:
        if mode == "replay":
            run = run_replay
        elif mode == "live":
            from tools.faults.live import run_live

            run = run_live
        else:
            raise CampaignError(f"unknown mode {mode!r} (replay or live)")
        runs = []  # independent repetitions (seeds > 1: each in its own directory), pooled
        for k in range(spec.seeds):
            where = out if spec.seeds == 1 else out / f"seed{k}"
            where.mkdir(exist_ok=True)
            runs.append(run(spec.repetition(k), where))
            write_outputs_csv(runs[-1], where / "outputs.csv")  # the run's error and interval over time
            runs[-1].wall_s = time.perf_counter() - t0 - sum(r.wall_s for r in runs[:-1])
        row = evaluate_pooled(runs, spec.expect)
    except ModeUnsupported as exc:
        row = {"scenario": spec.name, "mode": mode, "verdict": "SKIP", "notes": str(exc),
               "wall_s": round(time.perf_counter() - t0, 1)}
    except Exception as exc:  # the harness failed: report it in the table, keep the campaign going
        (out / "error.txt").write_text(traceback.format_exc())
        row = {"scenario": spec.name, "mode": mode, "verdict": "ERROR",
               "notes": f"{type(exc).__name__}: {exc}", "wall_s": round(time.perf_counter() - t0, 1)}
    (out / "row.json").write_text(json.dumps(row, indent=1, default=_json_default))
    return row


def wall_budget_s(spec: ScenarioSpec, mode: str) -> float:
    """Wall time a scenario may take before it counts as stalled [s] (``timeout_s`` overrides)."""
    if spec.timeout_s is not None:
        return spec.seeds * spec.timeout_s
    if mode == "live":
        return spec.seeds * (spec.duration_s / spec.speed + 300.0)
    return spec.seeds * (120.0 + 2.0 * spec.duration_s)


def _child(spec: ScenarioSpec, mode: str, out_dir: str) -> None:  # pragma: no cover - runs in a child
    run_scenario(spec, mode, out_dir)


def run_scenario_guarded(spec: ScenarioSpec, mode: str, out_dir: str) -> dict[str, Any]:
    """:func:`run_scenario` in a child process with a wall-time budget.

    A system under test that hangs (a single datagram keeping the listener busy for hours is a
    denial of service) must not hang the campaign: past the budget the child is killed and the row
    says *stalled*, counted as a crash.
    """
    import multiprocessing

    out = Path(out_dir) / spec.name
    out.mkdir(parents=True, exist_ok=True)
    (out / "row.json").unlink(missing_ok=True)
    budget = wall_budget_s(spec, mode)
    t0 = time.perf_counter()
    ctx = multiprocessing.get_context("spawn")
    proc = ctx.Process(target=_child, args=(spec, mode, out_dir), daemon=True)
    proc.start()
    proc.join(budget)
    if proc.is_alive():
        proc.kill()
        proc.join(10.0)
        row = {"scenario": spec.name, "mode": mode, "verdict": "FAIL", "crashes": 1, "checks": "crashes:FAIL",
               "wall_s": round(time.perf_counter() - t0, 1),
               "notes": f"stalled: no result after {budget:.0f} s of wall time (a hang counts as a crash)"}
        (out / "row.json").write_text(json.dumps(row, indent=1))
        return row
    try:
        return json.loads((out / "row.json").read_text())
    except (OSError, ValueError):
        return {"scenario": spec.name, "mode": mode, "verdict": "ERROR",
                "wall_s": round(time.perf_counter() - t0, 1),
                "notes": f"the scenario's process exited with status {proc.exitcode} and no result"}


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return str(value)
