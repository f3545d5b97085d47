"""Put the UI station together: settings, (simulated) bench, engine runner, controller, app.

Shared by `station ui`, the browser tests, the screenshot script and the UI benchmark, so
they all run the same station.
"""

from __future__ import annotations

import contextlib
import logging
import ssl
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from common.yaml_input import ConfigError, read_yaml
from station.certify import recovered_run_sealer
from station.errors import UserError
from station.station_file import load_settings
from station.ui import catalog
from station.ui.app import create_app
from station.ui.auth import Operator, OperatorBook, check_hash_format
from station.ui.connections import ConnectionLimits
from station.ui.controller import Controller
from station.ui.guard import LOOPBACK_HOSTS, allowed_hosts
from station.ui.history import History
from station.ui.hub import Hub
from station.ui.requests import Security
from station.ui.runner_adapter import EngineRunner, engine_available
from station.ui.server import Tls

log = logging.getLogger(__name__)

INSTRUMENT_POLL_S = 10.0  # between runs; the engine owns the instruments during a run


@dataclass
class UiStation:
    app: Any  # ASGI: the FastAPI routes inside station.ui.guard.Guard
    controller: Controller
    runner: EngineRunner
    bench: Any  # drivers.sim.launcher.BenchHandle | None
    tls: Tls | None = None
    recovered: list[Path] = field(default_factory=list)
    limits: ConnectionLimits = ConnectionLimits()  # station.yaml ui.max_connections...
    sim_config_speed: float | None = None  # the sim config's `speed:` (a --speed overrides it)

    def bench_line(self) -> str:
        """How the simulated bench runs, in one line: lockstep (the default, as `station run
        --sim`), or the --speed asked for, saying when it overrides the sim config's."""
        if self.bench is None:
            return ""
        pid = self.bench.endpoints.pid
        if self.bench.endpoints.lockstep:
            return (
                f"simulated bench running in lockstep (pid {pid}): station time is physics "
                "time; --speed X gives a scaled clock"
            )
        speed = self.bench.speed
        over = self.sim_config_speed
        note = (
            f"; --speed {speed:g} overrides the sim config's speed: {over:g}"
            if over is not None and over != speed else ""
        )
        return f"simulated bench running at {speed:g}x (pid {pid}){note}"


def is_loopback(host: str) -> bool:
    return host.strip("[]").lower() in LOOPBACK_HOSTS or host.startswith("127.")


def usable_tls(certificate: Path, key: Path, names: tuple[str, str], where: str = "") -> Tls:
    """The HTTPS files, checked to load as a PEM certificate and its matching private key;
    UserError naming them (`names`: how the user gave them, `where`: in which file) when not."""
    tls = Tls(certificate, key)
    for what, path in zip(names, (certificate, key), strict=True):
        if not path.is_file():
            raise UserError(f"{where}{what} {path}: no such file")
    try:
        ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(certificate, key)
    except (ssl.SSLError, OSError) as exc:
        raise UserError(
            f"{where}{names[0]}/{names[1]} cannot be used ({exc}); "
            "give a PEM certificate and its matching private key"
        ) from None
    return tls


def refuse_clear_text(host: str, tls: Tls | None, secrets: str, remedy: str) -> None:
    """UserError when listening on `host`, beyond loopback, without HTTPS: `secrets` would
    cross that network in clear; `remedy` says how to give the certificate and key."""
    if tls is None and not is_loopback(host):
        raise UserError(
            f"refusing to listen on {host} without HTTPS: every machine on that network could "
            f"read {secrets}; {remedy}, or listen on 127.0.0.1"
        )


def security_of(settings: Any, host: str) -> tuple[Security, Tls | None]:
    """The app's admission rules and HTTPS files from station.yaml's ui section.

    Listening beyond loopback needs HTTPS (ui.tls_certificate and ui.tls_key): the session
    cookie, PINs and the engineer password would otherwise cross the line network in clear."""
    ui = settings.settings.ui
    problems: list[str] = []
    if ui.engineer_password_hash:
        try:
            check_hash_format(ui.engineer_password_hash)
        except ValueError as exc:
            problems.append(str(exc))
    else:
        log.warning(
            "no ui.engineer_password_hash in %s: the engineer role is disabled",
            settings.source.path,
        )
    book = OperatorBook(
        tuple(Operator(o.name, o.pin_hash, o.badge_hash, o.role) for o in ui.operators)
    )
    try:
        book.check()
    except ValueError as exc:
        problems.append(str(exc))
    if problems:
        raise UserError(f"{settings.source.path}: " + "; ".join(problems))
    if book.open:
        log.warning(
            "no ui.operators in %s: operators sign in with a name only", settings.source.path
        )
    tls: Tls | None = None
    if ui.tls_certificate and ui.tls_key:
        tls = usable_tls(
            settings.resolve(ui.tls_certificate),
            settings.resolve(ui.tls_key),
            ("ui.tls_certificate", "ui.tls_key"),
            f"{settings.source.path}: ",
        )
    refuse_clear_text(
        host,
        tls,
        "the operators' PINs and the engineer password",
        f"set ui.tls_certificate and ui.tls_key (PEM files) in {settings.source.path}",
    )
    if ui.language and ui.language not in catalog.available():
        raise UserError(
            f"{settings.source.path}: ui.language {ui.language!r} has no message catalog; "
            f"use one of {', '.join(catalog.available())} or leave it out"
        )
    security = Security(
        engineer_password_hash=ui.engineer_password_hash,
        operators=book,
        require_operator=ui.require_operator,
        language=ui.language,
        hosts=allowed_hosts(host, ui.allowed_hosts),
        https=tls is not None,
        settings=settings,
    )
    return security, tls


def _sim_parts(sim_config: Path | None) -> tuple[dict[str, dict[str, Any]], int, float | None]:
    """Parts of the sim config by serial, the number of sockets it needs, and the speed it
    states (None when it states none)."""
    if sim_config is None:
        return {}, 0, None
    # the simulated bench: loaded only when asked for
    from drivers.sim.config import SimConfigError, load_sim_config

    try:
        config = load_sim_config(sim_config)  # bounded reader and schema: refused in one line
        data = read_yaml(sim_config).data or {}
    except (SimConfigError, ValueError) as exc:
        raise UserError(f"--sim-config {exc}") from None
    parts = data.get("parts") or [] if isinstance(data, dict) else []
    by_serial = {str(p["serial"]): dict(p) for p in parts if isinstance(p, dict) and "serial" in p}
    stated = isinstance(data, dict) and "speed" in data
    return by_serial, config.socket_count, config.speed if stated else None


@contextlib.contextmanager
def ui_station(
    station_file: Path | None = None,
    *,
    sim: bool = False,
    sim_config: Path | None = None,
    speed: float | None = None,
    sockets: int | None = None,
    out: Path | None = None,
    host: str = "127.0.0.1",
) -> Iterator[UiStation]:
    """The whole UI station; with `sim` the simulated bench runs for the block's duration."""
    if not engine_available():
        raise UserError("the end-of-line engine (station/uut.py) is not in this build")
    settings = _load_settings(station_file)
    security, tls = security_of(settings, host)
    if sim_config is None and sim and settings.settings.sim_config:
        sim_config = settings.resolve(settings.settings.sim_config)
    if sim_config is not None and not sim_config.is_file():
        raise UserError(f"--sim-config {sim_config}: no such file")
    parts, config_sockets, config_speed = _sim_parts(sim_config)
    bench_cm: Any = contextlib.nullcontext(None)
    if sim:
        bench_cm = _sim_bench(settings, sim_config, speed, sockets, config_sockets)
    with bench_cm as bench:
        runner = _engine_runner(settings, bench, out, parts)
        controller = Controller(runner, Hub())
        history, recovered = _history(settings, runner)
        app = create_app(controller, history, security=security)
        stop_watch = threading.Event()
        controller.watch_instruments(INSTRUMENT_POLL_S, stop_watch)
        try:
            ui = settings.settings.ui
            limits = ConnectionLimits(ui.max_connections, ui.max_connections_per_client)
            yield UiStation(app, controller, runner, bench, tls, recovered, limits=limits,
                            sim_config_speed=config_speed)
        finally:
            stop_watch.set()
            controller.hub.close()
            runner.close()


def _load_settings(station_file: Path | None) -> Any:
    try:
        return load_settings(station_file)
    except ConfigError as exc:
        raise UserError(str(exc)) from None


def _sim_bench(
    settings: Any,
    sim_config: Path | None,
    speed: float | None,
    sockets: int | None,
    config_sockets: int,
) -> Any:
    """The simulated bench's context manager (not started yet)."""
    from drivers.sim.launcher import launch_bench

    # the station's fixture (station.yaml instruments.fixture.sockets), grown to hold
    # every part the sim config places
    n = sockets or max(settings.settings.instruments.fixture.sockets, config_sockets)
    if not 1 <= n <= 32:  # one 1280 x 800 screen shows up to 32 sockets (8 x 4)
        raise UserError(f"--sockets must be 1..32, got {n}")
    # lockstep, as `station run --sim`: station time is physics time, whatever the load
    # on the machine; a --speed asks for a scaled clock (and is said, never assumed)
    return launch_bench(config=sim_config, speed=speed, sockets=n, lockstep=speed is None)


def _engine_runner(
    settings: Any, bench: Any, out: Path | None, parts: dict[str, dict[str, Any]]
) -> EngineRunner:
    """The engine runner on the bench's endpoints (a real station's when `bench` is None),
    its default procedure loaded already."""
    endpoints = None
    control = None
    if bench is not None:
        from station.endpoints import Endpoints

        endpoints = Endpoints.of_bench(bench.endpoints)
        control = bench.control
    runner = EngineRunner(settings, out=out, endpoints=endpoints, control=control, sim_parts=parts)
    runner.warm_up()
    return runner


def _history(settings: Any, runner: EngineRunner) -> tuple[History, list[Path]]:
    """The run history the review reads, and the runs it recovered (marked ERROR)."""
    # The engine indexes each run in the results database (station.yaml results_db, or
    # results.sqlite next to the runs when --out moves them): the review reads it there.
    db_path = (
        settings.results_db
        if runner.out.resolve() == settings.output_folder.resolve()
        else runner.out / "results.sqlite"
    )
    history = History(runner.out, db_path, seal=recovered_run_sealer(settings))
    # A station that died mid-run left that run RUNNING: ERROR now, before the screens open.
    recovered = history.recover()
    for folder in recovered:
        log.warning("marked as ERROR (the station stopped during that run): %s", folder)
    if settings.central_db:  # runs queued before a restart go to the line's db now
        from station.db.connect import database_url
        from station.db.sync import wake_station_sync

        wake_station_sync(settings, database_url(db_path), force=True)
    return history, recovered
