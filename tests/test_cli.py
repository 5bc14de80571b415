"""The ``sfa`` dispatcher: every command documented, has --help, errors become one-line reasons."""

import subprocess
import sys

import pytest

from sfa import cli


def test_every_available_command_has_help():
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(sub.choices) <= set(cli.COMMANDS)
    for name, p in sub.choices.items():
        assert p.format_help().strip(), name
        assert p.description == cli.COMMANDS[name][1]


def test_no_command_prints_help_and_fails(capsys):
    assert cli.main([]) == 2
    assert "usage: sfa" in capsys.readouterr().out


def test_unknown_command_is_an_argparse_error():
    with pytest.raises(SystemExit) as exc:
        cli.main(["no-such-command"])
    assert exc.value.code == 2


def test_python_m_sfa_runs_the_dispatcher():
    out = subprocess.run(
        [sys.executable, "-m", "sfa", "--help"], capture_output=True, text=True, timeout=60, check=True
    )
    assert "SFA train and tram positioning service" in out.stdout


def test_numba_cache_is_keyed_by_the_sources(tmp_path):
    code = (
        "import os, sys\n"
        "from sfa.cli import configure_numba_cache, source_fingerprint\n"
        "p = configure_numba_cache()\n"
        "import numba\n"
        "print(p, numba.config.CACHE_DIR, source_fingerprint())\n"
    )
    env = {k: v for k, v in __import__("os").environ.items() if "NUMBA" not in k}
    env["SFA_NUMBA_CACHE_BASE"] = str(tmp_path)
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env, check=True
    ).stdout.split()
    assert out[0] == out[1] == str(tmp_path / out[2])
    assert len(out[2]) == 16


def test_sfa_command_turns_on_numba_slp_vectorizer_unless_set():
    code = (
        "from sfa.cli import configure_numba_codegen\n"
        "first = configure_numba_codegen()\n"
        "import numba\n"
        "print(first, configure_numba_codegen(), numba.config.SLP_VECTORIZE)\n"
    )
    env = {k: v for k, v in __import__("os").environ.items() if "NUMBA_SLP" not in k}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env, check=True
    ).stdout.split()
    assert out == ["True", "False", "1"]  # set, then a no-op once numba is imported
    env["NUMBA_SLP_VECTORIZE"] = "0"  # an explicit setting wins
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env, check=True
    ).stdout.split()
    assert out == ["False", "False", "0"]


def test_replay_jobs_must_be_positive(capsys):
    """``sfa replay --jobs 0`` is a one-line argparse error naming the option and the value."""
    with pytest.raises(SystemExit) as exc:
        cli.main(["replay", "capture.pcap", "--track", "t.db", "--out", "o", "--jobs", "0"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--jobs" in err and "must be >= 1, got '0'" in err  # track_db.cli.count_from_1
