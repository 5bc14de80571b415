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
