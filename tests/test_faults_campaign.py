"""Campaigns: TOML validation, the replay path (injected == counted, determinism, authenticated link),
the results tables, the stall guard, the live mode on real processes and the netns mode's skip."""

from __future__ import annotations

import csv
import json
import tomllib

import pytest

from tools.faults.campaign import COLUMNS, run_campaign
from tools.faults.config import Impairments
from tools.faults.errors import FaultConfigError
from tools.faults.netns import Namespace, NetnsUnavailable, netem_args
from tools.faults.runner import run_scenario, run_scenario_guarded
from tools.faults.spec import campaign_from_dict, load_campaign
from tools.faults.tomlwrite import dumps

BASE = {
    "scenario": {"name": "t", "seed": 3},
    "journey": {
        "points": [{"s_m": 100.0, "kind": "stop", "departure_s": 3.0}, {"s_m": 1500.0, "kind": "stop"}]
    },
}


def campaign(*rows, duration_s=12.0):
    return campaign_from_dict(
        {
            "campaign": {"name": "t", "duration_s": duration_s, "seed": 2},
            "base": BASE,
            "scenarios": list(rows),
        }
    )


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"base": BASE, "scenarios": [{"name": "a", "nope": 1}]}, "unknown key"),
        ({"base": BASE, "scenarios": [{"name": "a"}, {"name": "a"}]}, "used twice"),
        ({"base": BASE, "scenarios": [{"name": "a b"}]}, "name"),
        ({"base": BASE, "scenarios": [{"name": "a", "expect": {"p96": 1}}]}, "unknown expectation"),
        ({"base": BASE, "scenarios": [{"name": "a", "expect": {"losses_match": False}}]}, "only `true`"),
        ({"base": BASE, "scenarios": [{"name": "a", "input_link": {"loss": 2}}]}, "input_link.loss"),
        ({"base": BASE, "scenarios": [{"name": "a", "obcu": {"silent": [[1]]}}]}, "silent"),
        (
            {"base": BASE, "scenarios": [{"name": "a", "sensor_faults": [{"kind": "melt"}]}]},
            "simulator scenario",
        ),
        ({"base": BASE, "scenarios": []}, "at least one"),
        ({"base": {"scenario": "no-such-scenario"}, "scenarios": [{"name": "a"}]}, "no-such-scenario"),
        ({"campaign": {"speed": 0}, "base": BASE, "scenarios": [{"name": "a"}]}, "speed"),
    ],
)
def test_campaign_errors_name_the_problem(data, message):
    with pytest.raises(FaultConfigError, match=message):
        campaign_from_dict(data)


def test_shipped_campaigns_are_valid():
    for name in ("quick", "reliability"):
        c = load_campaign(f"tools/faults/campaigns/{name}.toml")
        assert c.scenarios and len({s.name for s in c.scenarios}) == len(c.scenarios)


def test_toml_writer_round_trips():
    data = {
        "top": 1,
        "faults": [{"kind": "silent", "start_s": 1.5}],
        "scenario": {"name": 'a "b"', "x": 2.5, "flag": True, "big": float("inf")},
        "journey": {"points": [{"s_m": 1.0}]},
        "s": {"imu": {"rate_hz": 50.0}},
    }
    assert tomllib.loads(dumps(data)) == data


def test_replay_row_injected_equals_counted_and_is_deterministic(tmp_path):
    c = campaign(
        {
            "name": "lossy",
            "input_link": {"loss": 0.2, "reorder": 0.05, "duplicate": 0.02, "truncate": 0.01},
            "expect": {
                "losses_match": True,
                "duplicates_match": True,
                "reorders_match": True,
                "rejected_match": True,
                "accepted_bad": 0,
                "crashes": 0,
            },
        }
    )
    spec = c.scenarios[0]
    row = run_scenario(spec, "replay", str(tmp_path / "a"))
    again = run_scenario(spec, "replay", str(tmp_path / "b"))
    assert row["verdict"] == "PASS", row
    assert row["lost_inj"] == row["lost_det"] > 100
    assert row["dup_inj"] == row["dup_det"] > 10
    assert row["reord_inj"] == row["reord_det"] > 10
    assert row["rej_det"] >= row["rej_inj"] > 0
    assert {k: v for k, v in row.items() if k != "wall_s"} == {
        k: v for k, v in again.items() if k != "wall_s"
    }
    outputs = (tmp_path / "a" / "lossy" / "outputs.csv").read_text()
    assert outputs == (tmp_path / "b" / "lossy" / "outputs.csv").read_text()  # deterministic
    lines = outputs.splitlines()
    assert lines[0].startswith("t_s,truth_arc_m,arc_m,error_m") and len(lines) > 50
    trace = json.loads((tmp_path / "a" / "lossy" / "trace.json").read_text())
    assert trace["input_proxy"]["received"] > 1000  # 12 s of IMU 100 Hz, odometer 20 Hz, GNSS, control


def test_authenticated_link_rejects_every_forged_replayed_and_flipped_datagram(tmp_path):
    c = campaign(
        {
            "name": "auth",
            "auth": True,
            "input_link": {
                "bitflip": 0.05,
                "replay": 0.05,
                "duplicate": 0.02,
                "forge_rate_hz": 200.0,
                "forge_valid_fraction": 0.5,
                "garbage_rate_hz": 200.0,
                "inject_start_s": 2.0,
                "inject_end_s": 10.0,
            },
            "expect": {"auth_bad": 0, "crashes": 0},
        }
    )
    row = run_scenario(c.scenarios[0], "replay", str(tmp_path))
    assert row["verdict"] == "PASS", row
    assert row["auth_bad"] == 0
    trace = json.loads((tmp_path / "auth" / "trace.json").read_text())
    ip, auth = trace["input_proxy"], trace["auth"]
    injected = (
        ip["bitflipped"]
        + ip["replayed"]
        + ip["duplicated"]
        + ip["forged_valid"]
        + ip["forged_invalid"]
        + ip["garbage"]
    )
    assert sum(auth["rejected"].values()) >= injected - ip["bitflipped"] > 1000
    assert auth["rejected"]["auth_tag"] > 0 and auth["rejected"]["auth_replay"] > 0
    # every intact original once; a replayed copy of a corrupted original is its first intact copy
    assert ip["forwarded"] - ip["bitflipped"] <= auth["accepted"] <= ip["forwarded"]
    # per-module keys as `sfa listen` uses them: each module its own KEY_ID, one replay window per KEY_ID
    from interface_modules.live import DEFAULT_KEY_IDS

    assert sorted(auth["modules"].values()) == sorted(DEFAULT_KEY_IDS.values())
    assert auth["windows"] == sorted(DEFAULT_KEY_IDS.values())


def test_campaign_tables_and_stall_guard(tmp_path):
    c = campaign(
        {"name": "clean", "expect": {"crashes": 0, "losses_match": True}},
        {"name": "stalls", "timeout_s": 0.2},
        duration_s=8.0,
    )
    rows = run_campaign(c, "replay", tmp_path, jobs=2)
    assert [r["scenario"] for r in rows] == ["clean", "stalls"]
    assert rows[0]["verdict"] == "PASS"
    assert rows[1]["verdict"] == "FAIL" and rows[1]["crashes"] == 1 and "stalled" in rows[1]["notes"]
    with open(tmp_path / "results.csv", newline="") as fh:
        table = list(csv.reader(fh))
    assert tuple(table[0]) == COLUMNS and len(table) == 3
    md = (tmp_path / "results.md").read_text().splitlines()
    assert md[0].count("|") == len(COLUMNS) + 1 and len(md) == 4
    assert "<table>" in (tmp_path / "results.html").read_text()


def test_guarded_row_matches_in_process_row(tmp_path):
    spec = campaign({"name": "g", "input_link": {"loss": 0.1}}, duration_s=10.0).scenarios[0]
    a = run_scenario_guarded(spec, "replay", str(tmp_path / "a"))
    b = run_scenario(spec, "replay", str(tmp_path / "b"))
    assert {k: v for k, v in a.items() if k != "wall_s"} == {k: v for k, v in b.items() if k != "wall_s"}


def test_live_mode_on_real_processes(tmp_path):
    """obcu, listener, both proxies and the live simulator as real processes on 127.0.0.1."""
    c = campaign(
        {
            "name": "live",
            "speed": 10.0,
            "input_link": {"loss": 0.1, "duplicate": 0.02},
            "output_link": {"duplicate": 0.05},
            "expect": {"crashes": 0},
        },
        duration_s=20.0,
    )
    row = run_scenario(c.scenarios[0], "live", str(tmp_path))
    assert row["mode"] == "live"
    assert row["verdict"] == "PASS", row
    assert row["fresh_outputs"] > 100
    # the proxy's counters came back from its process; loopback under load can only add to what the
    # proxy did (a socket buffer overflow, a hold time exceeded), never hide it: exact equality is
    # the replay path's guarantee, not the operating system's
    assert row["lost_inj"] > 50 and row["lost_det"] >= row["lost_inj"]
    assert row["dup_inj"] > 0 and row["dup_det"] >= row["dup_inj"]
    logs = {p.name for p in (tmp_path / "live").iterdir()}
    assert {"listener.log", "obcu.log", "proxy_in.log", "proxy_out.log", "obcu.csv"} <= logs


def test_netns_mode_runs_or_skips_with_the_reason():
    spec = campaign({"name": "ns", "netns": True, "input_link": {"loss": 0.1}}).scenarios[0]
    assert netem_args(spec.input_link) == ["loss", "10.0000%"]
    assert netem_args(Impairments(delay_s=0.01, jitter_s=0.002, reorder=0.1)) == [
        "delay",
        "10.000ms",
        "2.000ms",
        "reorder",
        "10.0000%",
    ]
    try:
        ns = Namespace.create(spec)
    except NetnsUnavailable as exc:
        assert "skipped" in str(exc)
        return
    try:
        assert ns.inner_addr.startswith("10.213.") and "loss" in ns.qdisc_stats()
    finally:
        ns.destroy()


def test_live_authenticated_row(tmp_path):
    """auth = true live: sfa listen with [auth], sfa obcu and sfa sim --live with the row's key file."""
    c = campaign(
        {
            "name": "live-auth",
            "auth": True,
            "speed": 10.0,
            "input_link": {"bitflip": 0.02, "replay": 0.02, "garbage_rate_hz": 50.0, "inject_start_s": 0.5},
            "expect": {"crashes": 0, "auth_bad": 0},
        },
        duration_s=20.0,
    )
    row = run_scenario(c.scenarios[0], "live", str(tmp_path))
    assert row["verdict"] == "PASS", row
    assert row["fresh_outputs"] > 100  # the authenticated stream got through, the outputs and acks too
    trace = json.loads((tmp_path / "live-auth" / "live.json").read_text())
    rejected = trace["metrics"]["input"]["rejected_by_reason"]
    assert rejected["auth_tag"] > 0 and rejected["auth_replay"] > 0  # bit flips, replays
    assert rejected.get("auth_magic", 0) + rejected.get("auth_short", 0) > 0  # unwrapped garbage
    assert trace["metrics"]["link"]["acks"] > 0


def test_live_listener_runs_at_the_deployed_priority():
    """Live rows start the listener as deploy/systemd/sfa-listener.service does (Nice=-5) where the
    user may raise priority; elsewhere the listener keeps the default and the row notes it."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from tools.faults.live import LISTENER_NICE, _deployed_priority, _niceness

    unit = Path(__file__).resolve().parents[1] / "deploy" / "systemd" / "sfa-listener.service"
    assert f"Nice={LISTENER_NICE}" in unit.read_text().splitlines()
    before = _niceness(os.getpid())
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(5)"],  # noqa: PLW1509
                         preexec_fn=_deployed_priority)
    try:
        got = _niceness(p.pid)
    finally:
        p.kill()
        p.wait(timeout=10)
    assert _niceness(os.getpid()) == before  # only the child changed
    if os.geteuid() == 0:
        assert got == max(before + LISTENER_NICE, -20)
    else:
        assert got in (before, max(before + LISTENER_NICE, -20))


@pytest.mark.parametrize("jobs", ["0", "-2"])
def test_campaign_jobs_below_one_is_a_one_line_error_naming_it(jobs, tmp_path, capsys):
    from sfa import cli

    args = ["faults", "campaign", "tools/faults/campaigns/quick.toml", "--jobs", jobs, "--out", str(tmp_path)]
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert err == f"sfa faults: error: --jobs must be >= 1, got {jobs}\n"
    assert not any(tmp_path.iterdir())  # nothing was run


def test_seeded_repetitions_pool_their_figures_and_counters(tmp_path):
    """``seeds = 3``: three independent runs (simulator and link seeds + k), the row's figures over
    all of them: outputs and injected/counted losses add up, each run's estimates against its own
    truth (no error across two runs' seam)."""
    # duplicates, not losses: a lost GROUND TRUTH (sent once, at the start) leaves a run uninitialised
    row = {"name": "dups", "input_link": {"duplicate": 0.05},
           "expect": {"duplicates_match": True, "max_m": 50.0}}
    spec = campaign({**row, "seeds": 3}).scenarios[0]
    assert [spec.repetition(k).seed for k in range(3)] == [spec.seed, spec.seed + 1, spec.seed + 2]
    assert [spec.repetition(k).base["scenario"]["seed"] for k in range(3)] == [3, 4, 5]
    pooled = run_scenario(spec, "replay", str(tmp_path / "p"))
    singles = [run_scenario(spec.repetition(k), "replay", str(tmp_path / f"s{k}")) for k in range(3)]
    assert pooled["verdict"] == "PASS", pooled
    assert pooled["fresh_outputs"] == sum(r["fresh_outputs"] for r in singles)
    assert pooled["dup_inj"] == pooled["dup_det"] == sum(r["dup_det"] for r in singles) > 0
    assert float(pooled["max_m"]) == max(float(r["max_m"]) for r in singles)
    assert len({r["dup_det"] for r in singles}) > 1  # the repetitions really differ
    assert pooled["notes"].startswith("3 seeds pooled")
    with pytest.raises(FaultConfigError, match="seeds"):
        campaign({**row, "seeds": 0})


# ---------------------------------------------------------------- issue 20: kill -9 and restart, STOP gap
RESTART = {"kill_window_s": [6.0, 8.0], "down_s": 1.0}


def test_restart_table_is_validated_and_the_kill_time_is_seeded():
    with pytest.raises(FaultConfigError, match="kill_window_s"):
        campaign({"name": "a", "restart": {"kill_window_s": [3.0]}})
    with pytest.raises(FaultConfigError, match="before duration_s"):
        campaign({"name": "a", "restart": {"kill_window_s": [3.0, 30.0]}})
    with pytest.raises(FaultConfigError, match="unknown key"):
        campaign({"name": "a", "restart": {"kill_window_s": [3.0, 4.0], "when": 1}})
    spec = campaign({"name": "a", "restart": RESTART, "seeds": 3}).scenarios[0]
    times = [spec.repetition(k).restart.kill_at_s(spec.repetition(k).seed) for k in range(3)]
    assert all(6.0 <= t <= 8.0 for t in times) and len(set(times)) == 3
    assert times == [spec.repetition(k).restart.kill_at_s(spec.repetition(k).seed) for k in range(3)]


def test_kill_and_restart_on_the_replay_path_resumes_and_seq_continues(tmp_path):
    expect = {"crashes": 0, "resume_within_s": 3.0, "seq_continues": True, "warnings": ["resumed"]}
    c = campaign({"name": "kill", "restart": RESTART, "expect": expect},
                 {"name": "kill-no-checkpoint", "restart": RESTART, "expect": expect,
                  "listener": ["checkpoint.enabled=false"]})
    row = run_scenario(c.scenarios[0], "replay", str(tmp_path))
    assert row["verdict"] == "PASS", row
    trace = json.loads((tmp_path / "kill" / "trace.json").read_text())
    rs = trace["restart"]
    assert rs["resumed"] and rs["checkpoint_found"] and rs["lost_while_down"] > 50  # 1 s of IMU at 100 Hz
    assert 6.0 <= rs["kill_s"] <= 8.0 and rs["restart_s"] == pytest.approx(rs["kill_s"] + 1.0)
    assert float(row["resume_s"]) < 0.1
    # the same kill without a checkpoint: the restarted listener waits for GROUND TRUTH (never sent again)
    bad = run_scenario(c.scenarios[1], "replay", str(tmp_path))
    assert bad["verdict"] == "FAIL"
    assert "resume_within_s:FAIL" in bad["checks"] and "seq_continues:FAIL" in bad["checks"]
    assert "warnings:FAIL" in bad["checks"]


def test_authenticated_replays_after_a_restart_are_rejected_only_with_the_checkpoint(tmp_path):
    """The recorded first datagrams of every module (the GROUND TRUTH among them) re-sent after the
    restart: the anti-replay windows come back with the checkpoint; without it the GROUND TRUTH passes."""
    expect = {"crashes": 0, "burst_rejected_match": True, "auth_bad": 0}
    link = {"replay_burst": 5, "replay_burst_at_s": 10.0}  # the first 5 s: before the earliest kill
    c = campaign({"name": "burst", "auth": True, "restart": RESTART, "input_link": link, "expect": expect},
                 {"name": "burst-no-checkpoint", "auth": True, "restart": RESTART, "input_link": link,
                  "expect": expect, "listener": ["checkpoint.enabled=false"]})
    row = run_scenario(c.scenarios[0], "replay", str(tmp_path))
    assert row["verdict"] == "PASS", row
    assert row["burst_inj"] == 4 * 5 and row["auth_replay_rej"] >= row["burst_inj"]
    bad = run_scenario(c.scenarios[1], "replay", str(tmp_path))
    assert bad["verdict"] == "FAIL" and bad["auth_bad"] > 0, bad


def test_masquerades_and_a_stop_after_a_gap_on_the_replay_path(tmp_path):
    gt = {"forge_on_stream": True, "forge_as": "ground_truth", "forge_kind": "ground_truth",
          "forge_rate_hz": 0.5, "forge_valid_fraction": 1.0, "inject_start_s": 6.0, "inject_end_s": 10.0}
    c = campaign(
        {"name": "gt-control", "input_link": gt,
         "expect": {"ground_truth_held_match": True, "max_m": 20.0,
                    "warnings": ["ground_truth_unconfirmed"]}},
        {"name": "cross-key", "auth": True,
         "input_link": {**gt, "forge_as": "gps", "forge_kind": "stop"},
         "expect": {"foreign_rejected_match": True, "auth_bad": 0, "outputs_to_end_s": 2.0,
                    "warnings": ["sender_rejected"]}},
        {"name": "stop-gap", "input_link": {"stop_seq_gap": 1}, "expect": {"stop_exit_within_s": 1.0}},
    )
    rows = {s.name: run_scenario(s, "replay", str(tmp_path)) for s in c.scenarios}
    assert all(r["verdict"] == "PASS" for r in rows.values()), rows
    assert rows["gt-control"]["gt_held"] == rows["gt-control"]["masquerade_inj"] == 2
    assert rows["cross-key"]["foreign_det"] >= rows["cross-key"]["foreign_inj"] == 2
    assert 0.0 < float(rows["stop-gap"]["stop_exit_s"]) <= 1.0  # released by the hold timer, not at once


def _observation(arrival, sim_s: float):
    import numpy as np

    from tools.faults.evaluate import Observation

    t = np.asarray(arrival, dtype=float)
    return Observation(
        name="x", mode="replay", simulated_s=sim_s, truth_epoch=np.array([0.0, sim_s]),
        truth_arc=np.array([0.0, sim_s]), start_epoch_s=0.0, fresh_arrival=t, fresh_epoch=t, fresh_arc=t,
        fresh_lo=t - 1.0, fresh_hi=t + 1.0, fresh_age=np.zeros(t.size), fresh_reasons=None, metrics={},
        link_transitions=[], input_proxy={}, output_proxy={}, input_blackouts=(), output_blackouts=(),
        sensor_fault_windows=[], crashes=0,
    )


def test_outputs_lost_counts_long_gaps_per_run_not_the_seams_of_pooled_runs():
    import numpy as np

    from tools.faults.evaluate import evaluate, evaluate_pooled

    steady = np.arange(0.0, 20.0, 0.01)
    gap = steady[(steady < 5.0) | (steady >= 7.0)]  # 2 s without an output: about 200 missing
    one = evaluate(_observation(gap, 20.0), {})
    assert 195 <= one["outputs_lost"] <= 205 and float(one["longest_gap_s"]) == pytest.approx(2.0, abs=0.02)
    assert evaluate(_observation(steady, 20.0), {})["outputs_lost"] == 0
    pooled = evaluate_pooled([_observation(gap, 20.0), _observation(steady, 20.0)], {"max_gap_s": 1.0})
    assert pooled["outputs_lost"] == one["outputs_lost"] and pooled["longest_gap_s"] == one["longest_gap_s"]
    assert "max_gap_s:FAIL" in pooled["checks"]


def test_outputs_to_end_is_judged_on_the_arrival_axis():
    """Live arrivals are wall seconds: a row at speed 10 ends at duration / 10 on that axis."""
    import numpy as np

    from tools.faults.evaluate import evaluate

    obs = _observation(np.arange(0.0, 9.0, 0.01), 90.0)
    assert "outputs_to_end_s:FAIL" in evaluate(obs, {"outputs_to_end_s": 2.0})["checks"]
    obs.run_s = 9.0
    assert "outputs_to_end_s:PASS" in evaluate(obs, {"outputs_to_end_s": 2.0})["checks"]
    assert evaluate(obs, {})["outputs_lost"] == 0
