"""`station bench`: run the simulated bench in the foreground until SIGINT/SIGTERM."""

from __future__ import annotations

import argparse
from pathlib import Path

from station.errors import UserError
from station.instrument_lock import held_by_a_station


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "bench",
        help="run the simulated bench (instrument twins on loopback and ptys)",
        description="Run the simulated bench until SIGINT/SIGTERM. Writes a JSON state file "
        "with every endpoint (rate_table, chamber, supply, duts, control).",
    )
    p.add_argument("--config", type=Path, help="sim config YAML (default: one empty socket)")
    p.add_argument("--state", type=Path, help="state file to write (default: print to stdout)")
    p.add_argument("--speed", type=float, help="world speed factor (default: the config's, or 1)")
    p.add_argument("--sockets", type=int, help="fixture sockets (default: the config's, or 1)")
    p.add_argument(
        "--lockstep",
        action="store_true",
        help="virtual time: the world moves only when the station's clock asks (control "
        "cmd advance); --speed is then ignored",
    )
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    # imported here so `station --help` stays fast and other commands need no pymodbus
    from drivers.sim.bench import run_bench, twin_class
    from drivers.sim.config import SimConfigError, load_sim_config, speed_problem

    try:
        config = load_sim_config(args.config)
    except SimConfigError as exc:
        raise UserError(str(exc)) from None
    if args.speed is not None and (problem := speed_problem(args.speed)):
        raise UserError(problem)
    if args.sockets is not None:
        if not 1 <= args.sockets <= 64:
            raise UserError(f"--sockets must be 1..64, got {args.sockets}")
        fixture = config.fixture.model_copy(update={"sockets": args.sockets})
        config = config.model_copy(update={"fixture": fixture})
    for role, family in config.instruments.families().items():
        if role == "part":
            continue
        try:
            twin_class(role, family)
        except ValueError as exc:
            raise UserError(str(exc)) from None
    if args.state is not None and not args.state.parent.is_dir():
        raise UserError(f"--state: directory {args.state.parent} does not exist; create it first")
    from drivers.sim.pty_twins import PtyPort  # the simulated bench: loaded only when asked for

    PtyPort.held_elsewhere = staticmethod(held_by_a_station)
    return run_bench(config, args.state, args.speed, lockstep=args.lockstep)
