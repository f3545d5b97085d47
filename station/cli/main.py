"""The `station` command line.

Each group of commands lives in its own module (`station/cli/*.py`) exposing
`register(subparsers)`, which adds its subcommands with a `handler(args) -> int` default.
Errors meant for the user are `UserError`: printed as one clear line, exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from station import __version__
from station.errors import UserError

COMMAND_MODULES = (
    "station.cli.bench",  # bench
    "station.cli.run",  # run, demo, schema
    "station.cli.analyze",  # analyze stop-method | allan
    "station.cli.reports",  # report, history, lot-report
    "station.cli.discrepancy",  # discrepancy
    "station.cli.ui",  # ui
    "station.cli.line",  # line, sync, export
    "station.cli.signing",  # verify, approve
    "station.cli.archive",  # archive
    "station.cli.procedure",  # procedure convert
)


def build_parser(modules: Sequence[str] = COMMAND_MODULES) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="station",
        description="End-of-line calibration station for MEMS gyroscopes.",
    )
    parser.add_argument("--version", action="version", version=f"station {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in modules:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue  # that command group is not part of this build
            raise
        module.register(subparsers)
    return parser


class _PlainFormatter(logging.Formatter):
    """A log line as a person at the terminal reads it: "station run: warning: socket 1: ...";
    the time and the module that said it are for whoever debugs (-v)."""

    def __init__(self, command: str) -> None:
        super().__init__()
        self.prefix = f"station {command}: " if command else "station: "

    def formatMessage(self, record: logging.LogRecord) -> str:  # noqa: N802 - logging's name
        return f"{self.prefix}{record.levelname.lower()}: {record.message}"


def main(argv: Sequence[str] | None = None, modules: Sequence[str] = COMMAND_MODULES) -> int:
    """Run one command; `modules` (the command groups to offer) defaults to every one."""
    parser = build_parser(modules)
    args = parser.parse_args(argv)
    to_stderr = logging.StreamHandler()
    to_stderr.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s")
                           if args.verbose else _PlainFormatter(args.command or ""))
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2), handlers=[to_stderr])
    if args.verbose < 2:  # the drivers say what failed in their own errors, once
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    handler = getattr(args, "handler", None)
    if handler is None:
        parser.print_help()
        return 2
    try:
        return int(handler(args))
    except UserError as exc:  # one line per problem, each naming the command
        for line in str(exc).splitlines() or [""]:
            print(f"station {args.command}: error: {line}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"station {args.command}: interrupted", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
