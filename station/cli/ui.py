"""`station ui`: the operator and review screens in the browser, served by the station."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

from station.errors import UserError
from station.exit_path import ExitPath, exit_bound_s
from station.secret_input import read_secret
from station.ui.auth import hash_badge, hash_password, hash_pin
from station.uut import safe_state_policy_of


def _hash_secret(kind: str) -> int:
    makers: dict[str, tuple[str, Callable[[str], str], str]] = {
        "password": ("engineer password", hash_password, "engineer_password_hash"),
        "pin": ("PIN", hash_pin, "pin_hash"),
        "badge": ("badge code", hash_badge, "badge_hash"),
    }
    what, make, key = makers[kind]
    try:
        hashed = make(read_secret(what))
    except ValueError as exc:
        raise UserError(str(exc)) from None
    print("# put this in station.yaml:")
    print("ui:")
    if kind == "password":
        print(f"  {key}: '{hashed}'")
    else:
        print("  operators:")
        print("    - name: <operator name>")
        print(f"      {key}: '{hashed}'")
    return 0


def _ui(args: argparse.Namespace) -> int:
    for kind in ("password", "pin", "badge"):
        if getattr(args, f"hash_{kind}"):
            return _hash_secret(kind)
    if not 0 <= args.port <= 65535:
        raise UserError(f"--port must be 0..65535, got {args.port}")
    if args.sim_config and not args.sim:
        raise UserError("--sim-config needs --sim (it configures the simulated bench)")
    if args.speed is not None:
        # the simulated bench: loaded only when asked for
        from drivers.sim.config import speed_problem

        if problem := speed_problem(args.speed):
            raise UserError(problem)
    # fastapi/uvicorn: loaded only when serving
    from station.ui.launch import ui_station

    # signals and uncaught thread exceptions: one exit path (station/exit_path.py); before
    # the screen is up a signal unwinds as Ctrl-C does
    exit_path = ExitPath("ui")
    with exit_path, ui_station(
        Path(args.station) if args.station else None,
        sim=args.sim,
        sim_config=Path(args.sim_config) if args.sim_config else None,
        speed=args.speed,
        sockets=args.sockets,
        out=Path(args.out) if args.out else None,
        host=args.host,
    ) as station:
        if station.bench is not None:
            print(station.bench_line(), flush=True)
        for folder in station.recovered:
            print(f"marked as ERROR (the station stopped during that run): {folder}", flush=True)
        scheme = "https" if station.tls else "http"
        print(
            f"operator screen: {scheme}://{args.host}:{args.port}/   "
            f"review: {scheme}://{args.host}:{args.port}/review   (Ctrl-C stops)",
            flush=True,
        )
        exit_path.bound_s = exit_bound_s(safe_state_policy_of(station.runner.settings))
        ended_run = _serve(station, args, exit_path)
    # a signal that ended a run is an abort (2); a screen stopped between runs stopped cleanly
    return 2 if ended_run else 0


def _serve(station: Any, args: argparse.Namespace, exit_path: Any) -> bool:
    """Serve until a signal; True when that signal ended a run in progress. The run itself
    ends (safe state, record sealed) as `ui_station` closes, after the server stopped."""
    from station.ui.server import station_server  # fastapi/uvicorn: loaded only when serving

    server = station_server(station.app, args.host, args.port, tls=station.tls,
                            limits=station.limits)
    ended = {"run": False}

    def stop(reason: str, error: bool) -> None:
        if error:  # a station thread failed: that run ends ERROR, the screen stays up
            station.runner.abort(reason, error=True)
            return
        ended["run"] = station.runner.busy()
        station.runner.abort(reason)
        server.should_exit = True

    exit_path.attach(stop)
    try:
        server.run()  # returns once `stop` has set should_exit (no KeyboardInterrupt now)
    except OSError as exc:
        raise UserError(
            f"cannot listen on {args.host}:{args.port} ({exc.strerror}); choose another --port"
        ) from None
    return ended["run"]


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("ui", help="serve the operator and review screens (browser)")
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default loopback only; 0.0.0.0 for the line network, "
        "which needs ui.tls_certificate and ui.tls_key in station.yaml)",
    )
    p.add_argument("--port", type=int, default=8080, help="TCP port (default 8080)")
    p.add_argument("--sim", action="store_true", help="start the simulated bench and run on it")
    p.add_argument("--sim-config", help="simulated bench configuration (YAML), with --sim")
    p.add_argument(
        "--speed",
        type=float,
        help="simulated bench speed factor: a scaled clock (default: lockstep, as station run "
        "--sim; a sim config's speed: is used only by station bench)",
    )
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
    p.add_argument(
        "--hash-pin",
        action="store_true",
        help="read an operator's PIN (stdin) and print the station.yaml lines",
    )
    p.add_argument(
        "--hash-badge",
        action="store_true",
        help="read an operator's badge code (stdin or a scan) and print the station.yaml lines",
    )
    p.set_defaults(handler=_ui)
