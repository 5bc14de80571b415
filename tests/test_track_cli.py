"""``sfa track``: import, info, export, locate (in-process and as real processes)."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest

from sfa import cli
from track_db import TrackDatabase, default_database_path


def sfa(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sfa", "track", *args],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


@pytest.fixture
def csv_track(tmp_path):
    src = tmp_path / "line.csv"
    rows = ["lat,lon,alt"] + [
        f"{50.9 + 1e-4 * k:.7f},{11.6 + 5e-5 * k:.7f},{150 + 0.1 * k:.2f}" for k in range(50)
    ]
    src.write_text("\n".join(rows) + "\n")
    return src


def test_import_info_export_locate_as_processes(tmp_path, csv_track):
    out = tmp_path / "t.db"
    r = sfa("import", str(csv_track), "-o", str(out), "--name", "test line")
    assert r.returncode == 0, r.stderr
    assert "imported 1 line(s)" in r.stdout
    r = sfa("info", str(out), "--json")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["lines"][0]["name"] == "test line" and info["lines"][0]["n_vertices"] == 50
    db = TrackDatabase.open(out)
    lat, lon = db.line().latlon_at(100.0)
    r = sfa("locate", f"{float(lat):.9f}", f"{float(lon):.9f}", "--track", str(out), "--json")
    assert r.returncode == 0, r.stderr
    located = json.loads(r.stdout)
    assert located["line_id"] == 1 and located["s_m"] == pytest.approx(100.0, abs=0.01)
    assert abs(located["offset_m"]) < 0.01


def test_failed_import_is_a_one_line_error_and_writes_nothing(tmp_path):
    src = tmp_path / "bad.csv"
    src.write_text("lat,lon\n50.0,11.0\n50.0,11.0\n")
    out = tmp_path / "t.db"
    r = sfa("import", str(src), "-o", str(out))
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0
    assert r.stderr.startswith("sfa track: error: bad.csv: line 3: duplicated point")
    assert not out.exists()


def test_existing_output_needs_force_or_append(tmp_path, csv_track, capsys):
    out = tmp_path / "t.db"
    assert cli.main(["track", "import", str(csv_track), "-o", str(out)]) == 0
    before = out.read_bytes()
    assert cli.main(["track", "import", str(csv_track), "-o", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert out.read_bytes() == before
    assert cli.main(["track", "import", str(csv_track), "-o", str(out), "--append", "--name", "again"]) == 0
    assert [i.name for i in TrackDatabase.open(out).lines()] == ["line", "again"]
    assert cli.main(["track", "import", str(csv_track), "-o", str(out), "--force"]) == 0
    assert len(TrackDatabase.open(out).lines()) == 1


def test_info_of_the_bundled_database(capsys):
    assert cli.main(["track", "info"]) == 0
    out = capsys.readouterr().out
    assert "17 lines" in out and "junctions: 54 branch points" in out
    assert "tightest radius" in out


def test_export_geojson(tmp_path):
    out = tmp_path / "net.geojson"
    assert cli.main(["track", "export", str(default_database_path()), "--geojson", str(out)]) == 0
    doc = json.loads(out.read_text(encoding="utf-8"))
    kinds = [f["properties"]["feature"] for f in doc["features"]]
    assert kinds.count("line") == 17
    assert kinds.count("junction") == len(TrackDatabase.open(default_database_path()).junctions())
    assert kinds.count("stop") > 0
    line = next(f for f in doc["features"] if f["properties"]["feature"] == "line")
    assert line["geometry"]["type"] == "LineString"
    lon, lat = line["geometry"]["coordinates"][0]
    assert 11.5 < lon < 11.7 and 50.8 < lat < 51.0
    assert "OpenStreetMap" in doc["attribution"]


def test_locate_on_one_line_and_bad_input(capsys):
    db = TrackDatabase.open(default_database_path())
    lat, lon = db.line(2).latlon_at(5000.0)
    assert cli.main(["track", "locate", str(lat), str(lon), "--line", "2"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("line 2 (3: Lobeda-Ost -> Jena-Ost): s = 5000.000 m")
    assert cli.main(["track", "locate", "50.9", "11.6", "--line", "99"]) == 2
    assert "no line 99" in capsys.readouterr().err
    assert cli.main(["track", "info", "/nonexistent/t.db"]) == 2
    assert "no such file" in capsys.readouterr().err


@pytest.mark.parametrize("sub", ["import", "info", "export", "locate"])
def test_every_subcommand_has_help(sub, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", sub, "--help"])
    assert exc.value.code == 0
    assert "usage: sfa track " + sub in capsys.readouterr().out


def test_locate_out_of_range_latitude_is_a_one_line_error_naming_it():
    r = sfa("locate", "200", "11.6")
    assert r.returncode == 2
    assert r.stderr == "sfa track: error: latitude 200 deg is outside -90..90 deg\n"
    r = sfa("locate", "50.9", "-181")
    assert r.returncode == 2
    assert r.stderr == "sfa track: error: longitude -181 deg is outside -180..180 deg\n"


def test_locate_far_from_every_line_warns_naming_the_distance():
    r = sfa("locate", "0", "0")
    assert r.returncode == 0, r.stderr
    # Jena is ~5,745 km from (0, 0) along the WGS84 geodesic
    assert re.fullmatch(
        r"warning: \(0, 0\) is 5,7\d\d\.\d km from the nearest line, line \d+ \(.+\) "
        r"\(more than --warn-offset-m 100 m\): not on this track\n",
        r.stderr,
    ), r.stderr
    db = TrackDatabase.open(default_database_path())
    lat, lon = db.line(2).latlon_at(5000.0)
    r = sfa("locate", f"{float(lat):.9f}", f"{float(lon):.9f}")
    assert r.returncode == 0 and r.stderr == ""  # on the track: no warning
    off = ("--line", "2", "--warn-offset-m", "50", "--json")
    r = sfa("locate", f"{float(lat) + 0.001:.9f}", f"{float(lon):.9f}", *off)
    assert r.returncode == 0
    m = re.fullmatch(r"warning: .* is (\d+\.\d) m from line 2 \(3: Lobeda-Ost -> Jena-Ost\) .*\n", r.stderr)
    assert m, r.stderr
    # the named distance is the lateral offset (a point beside the line, not beyond its end)
    assert 50 < float(m.group(1)) == pytest.approx(abs(json.loads(r.stdout)["offset_m"]), abs=0.1)


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--smoothing-sigma-m", "-3", "must be a positive number of metres, got '-3'"),
        ("--profile-step-m", "0", "must be a positive number of metres, got '0'"),
        ("--max-gap-m", "nan", "must be a positive number of metres, got 'nan'"),
        ("--junction-tolerance-m", "one", "'one' is not a number of metres"),
        ("--default-line", "0", "must be >= 1, got '0'"),
    ],
)
def test_import_options_out_of_range_name_the_option_and_value(tmp_path, csv_track, option, value, message):
    out = tmp_path / "t.db"
    r = sfa("import", str(csv_track), "-o", str(out), option, value)
    assert r.returncode == 2
    assert r.stderr.splitlines()[-1] == f"sfa track import: error: argument {option}: {message}"
    assert "BuildConfig" not in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()
