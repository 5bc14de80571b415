"""benchmarks/bench_bound.py: the information bound of a run with truth, from the command line."""

from __future__ import annotations

import re

import numpy as np
import pytest

from interface_modules.scenario import load_scenario
from interface_modules.tracks import database_path
from tools.bench_replay import load_benchmark_module


def _truth(tmp_path):
    t = 1.7e9 + np.arange(0.0, 200.0, 0.1)
    speed = np.where(t - t[0] < 10.0, 0.0, 8.0)
    s = 150.0 + np.concatenate([[0.0], np.cumsum(speed[:-1] * 0.1)])
    path = tmp_path / "truth.csv"
    np.savetxt(path, np.column_stack([t, s, speed]), delimiter=",", header="epoch,arc_length,speed",
               comments="", fmt="%.6f")
    return path


def _figures(out: str) -> tuple[float, float]:
    m = re.search(r"whole run ([0-9.]+) m .* first 300 s ([0-9.]+) m", out)
    assert m, out
    return float(m.group(1)), float(m.group(2))


def test_bound_of_a_capture(tmp_path, capsys):
    bound = load_benchmark_module("bench_bound")
    db = str(database_path(load_scenario("tram-urban")))
    truth = str(_truth(tmp_path))
    base = ["--truth", truth, "--track", db, "--line", "2", "--gm-tau", "30", "--white", "1.0"]
    assert bound.main(base + ["--gm-sigma", "1.5"]) == 0
    big = _figures(capsys.readouterr().out)
    assert bound.main(base + ["--gm-sigma", "0.5"]) == 0
    small = _figures(capsys.readouterr().out)
    assert 0.0 < small[0] < big[0]
    assert bound.main(base + ["--gm-sigma", "1.5", "--outage", "600", "1400"]) == 0
    assert _figures(capsys.readouterr().out)[0] > big[0]  # no fixes over 800 m: a larger bound


def test_bad_arguments_name_the_value(tmp_path, capsys):
    bound = load_benchmark_module("bench_bound")
    db = str(database_path(load_scenario("tram-urban")))
    with pytest.raises(SystemExit) as exc:
        bound.main(["--truth", str(_truth(tmp_path)), "--track", db, "--gm-sigma", "-1", "--gm-tau", "30",
                    "--white", "1"])
    assert exc.value.code == 2 and "-1" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        bound.main(["--truth", str(tmp_path / "missing.csv"), "--track", db, "--gm-sigma", "1",
                    "--gm-tau", "30", "--white", "1"])
    assert "missing.csv" in capsys.readouterr().err


_CAMPAIGN = """
[campaign]
name = "bound"
duration_s = 60.0
seed = 1

[base.scenario]
name = "jena-line-2-short"
seed = 3

[base.journey]
points = [{{ s_m = 100.0, kind = "stop", departure_s = 5.0 }}, {{ s_m = 3000.0, kind = "stop" }}]

[base.sensors.gps.actual]
gm_sigma_m = {gm}

[[scenarios]]
name = "clean"
seeds = 2
expect = {{ p95_m = 1.0 }}

[[scenarios]]
name = "no-accuracy-bound"
expect = {{ crashes = 0 }}

[[scenarios]]
name = "multipath"
sensor_faults = [{{ kind = "multipath_step", start_s = 20.0, end_s = 30.0, east_m = 30.0, north_m = 0.0 }}]
expect = {{ p95_m = 3.0 }}
"""


def _campaign_bound(tmp_path, capsys, gm: float, rows=()) -> dict[str, float]:
    bound = load_benchmark_module("bench_bound")
    path = tmp_path / f"c{gm}.toml"
    path.write_text(_CAMPAIGN.format(gm=gm), encoding="utf-8")
    argv = ["--campaign", str(path)] + [a for r in rows for a in ("--row", r)]
    assert bound.main(argv) == 0
    found = re.findall(r"^(\S+): information bound p95 ([0-9.]+) m", capsys.readouterr().out, re.M)
    return {name: float(v) for name, v in found}


def test_bound_of_campaign_rows(tmp_path, capsys):
    """The world's own GNSS error sets the bound; by default only rows with a p95 bound and no sensor
    fault are taken (a faulted receiver is outside the bound's model), and --row picks any row."""
    small = _campaign_bound(tmp_path, capsys, 0.5)
    big = _campaign_bound(tmp_path, capsys, 2.0)
    assert set(small) == set(big) == {"clean"}
    assert 0.0 < small["clean"] < big["clean"]
    assert set(_campaign_bound(tmp_path, capsys, 0.5, rows=["multipath"])) == {"multipath"}


def test_bound_of_a_campaign_rejects_an_unknown_row(tmp_path, capsys):
    bound = load_benchmark_module("bench_bound")
    path = tmp_path / "c.toml"
    path.write_text(_CAMPAIGN.format(gm=1.0), encoding="utf-8")
    with pytest.raises(SystemExit):
        bound.main(["--campaign", str(path), "--row", "nope"])
    err = capsys.readouterr().err
    assert "no such row" in err and "nope" in err
