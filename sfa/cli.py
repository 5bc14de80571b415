"""The single ``sfa`` command: a thin dispatcher over the packages' own CLI modules.

Each subcommand lives in the package that owns it, in a module exposing::

    def add_arguments(parser: argparse.ArgumentParser) -> None
    def run(args: argparse.Namespace) -> int

Those modules must import only the standard library at module level (heavy imports go inside
``run``) so that ``sfa --help`` stays fast. Library errors are turned into a one-line reason on
stderr and a non-zero exit status here, at the boundary, and nowhere else.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

#: subcommand -> (module implementing it, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "track": ("track_db.cli", "digitised track databases: import, info, export, locate"),
    "sim": ("interface_modules.cli", "train and sensor simulator: live interface modules or capture"),
    "listen": ("listener.cli", "the listener daemon: UDP inputs -> SFA filter -> OBCU"),
    "obcu": ("listener.obcu_cli", "mock on-board control unit: receives outputs, acks, logs"),
    "replay": ("tools.replay_cli", "offline replay of a capture through the listener pipeline"),
    "demo": ("tools.demo", "the whole system on loopback with the bundled track"),
    "convert": ("tools.convert_cli", "convert real sensor logs (smartLoc, Dresden) into captures and tracks"),
    "faults": ("tools.faults_cli", "fault-injection proxy and reliability campaigns"),
    "bench": ("tools.bench", "the benchmark suite"),
}

#: modules whose base exception classes are reported as one-line errors
ERROR_MODULES = (
    "sfa.errors",
    "listener.errors",
    "interface_modules.errors",
    "track_db.errors",
    "tools.errors",
)


def _known_errors() -> tuple[type[BaseException], ...]:
    found: list[type[BaseException]] = [OSError]
    for name in ERROR_MODULES:
        try:
            mod = importlib.import_module(name)
        except ImportError:
            continue
        base = getattr(mod, "BASE_ERROR", None)
        if isinstance(base, type) and issubclass(base, BaseException):
            found.append(base)
    return tuple(found)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sfa",
        description="SFA train and tram positioning service.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        try:
            module = importlib.import_module(module_name)
        except ImportError:
            continue  # command not built yet in this checkout
        p = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    run = getattr(args, "_run", None)
    if run is None:
        parser.print_help()
        return 2
    known = _known_errors()
    try:
        return int(run(args) or 0)
    except KeyboardInterrupt:
        return 130
    except known as exc:  # library errors become a one-line reason at the boundary
        print(f"sfa {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
