"""`station ui`: the operator and review screens in the browser, served by the station."""

from __future__ import annotations

import argparse
import getpass
import sys
from pathlib import Path

from station.errors import UserError


def _hash_password() -> int:
    from station.ui.auth import hash_password

    if sys.stdin.isatty():
        password = getpass.getpass("engineer password: ")
        if getpass.getpass("again: ") != password:
            raise UserError("the two passwords differ; run the command again")
    else:
        password = sys.stdin.readline().rstrip("\r\n")
    try:
        hashed = hash_password(password)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    print("# put this in station.yaml:")
    print("ui:")
    print(f"  engineer_password_hash: '{hashed}'")
    return 0


def _ui(args: argparse.Namespace) -> int:
    if args.hash_password:
        return _hash_password()
    if not 0 <= args.port <= 65535:
        raise UserError(f"--port must be 0..65535, got {args.port}")
    if args.sim_config and not args.sim:
        raise UserError("--sim-config needs --sim (it configures the simulated bench)")
    if args.speed is not None:
        from drivers.sim.config import speed_problem

        if problem := speed_problem(args.speed):
            raise UserError(problem)
    from station.ui.launch import ui_station
    from station.ui.server import serve_forever

    with ui_station(
        Path(args.station) if args.station else None,
        sim=args.sim,
        sim_config=Path(args.sim_config) if args.sim_config else None,
        speed=args.speed,
        sockets=args.sockets,
        out=Path(args.out) if args.out else None,
    ) as station:
        if station.bench is not None:
            print(
                f"simulated bench running at {station.bench.speed:g}x "
                f"(pid {station.bench.endpoints.pid})",
                flush=True,
            )
        if args.host not in ("127.0.0.1", "localhost", "::1"):
            print(
                f"warning: listening on {args.host}: every machine on that network can reach "
                "the station; the engineer password crosses it unencrypted",
                flush=True,
            )
        print(
            f"operator screen: http://{args.host}:{args.port}/   "
            f"review: http://{args.host}:{args.port}/review   (Ctrl-C stops)",
            flush=True,
        )
        try:
            serve_forever(station.app, args.host, args.port)
        except KeyboardInterrupt:  # uvicorn re-raises the Ctrl-C it handled: a normal stop
            pass
        except OSError as exc:
            raise UserError(
                f"cannot listen on {args.host}:{args.port} ({exc.strerror}); choose another --port"
            ) from None
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("ui", help="serve the operator and review screens (browser)")
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default loopback only; 0.0.0.0 for the line network)",
    )
    p.add_argument("--port", type=int, default=8080, help="TCP port (default 8080)")
    p.add_argument("--sim", action="store_true", help="start the simulated bench and run on it")
    p.add_argument("--sim-config", help="simulated bench configuration (YAML), with --sim")
    p.add_argument("--speed", type=float, help="simulated bench speed factor (default 100)")
    p.add_argument(
        "--sockets", type=int, help="simulated fixture sockets (default: the sim config's)"
    )
    p.add_argument("--station", help="station file (default config/station.yaml)")
    p.add_argument("--out", help="run folders go here (default: station.yaml output_folder)")
    p.add_argument(
        "--hash-password",
        action="store_true",
        help="read an engineer password (stdin) and print the station.yaml line",
    )
    p.set_defaults(handler=_ui)
