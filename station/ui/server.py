"""Run the web app with uvicorn, in the foreground (CLI) or in a thread (tests, scripts)."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import uvicorn

from station.ui.connections import ConnectionLimits, capped_protocol

ASGIApp = Any  # the station's app: FastAPI routes inside station.ui.guard.Guard


@dataclass
class BackgroundServer:
    server: uvicorn.Server
    thread: threading.Thread
    url: str
    before_stop: Callable[[], None] | None = None

    def stop(self, timeout_s: float = 10.0) -> None:
        if self.before_stop is not None:
            self.before_stop()
        self.server.should_exit = True
        self.thread.join(timeout_s)


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True)
class Tls:
    """HTTPS: PEM certificate and private key files."""

    certificate: Path
    key: Path


def _config(
    app: ASGIApp,
    host: str,
    port: int,
    log_level: str,
    tls: Tls | None = None,
    limits: ConnectionLimits | None = None,
) -> uvicorn.Config:
    # Short graceful shutdown: open event streams would otherwise hold it up. Connections are
    # capped per client and in total (station/ui/connections.py), whatever the caller says;
    # the accept backlog no deeper than the cap, as asyncio accepts a whole backlog at once
    # and each holds a descriptor until the cap closes it.
    limits = limits or ConnectionLimits()
    return uvicorn.Config(
        app,
        host=host,
        port=port,
        http=capped_protocol(limits),
        backlog=limits.total,
        log_level=log_level,
        timeout_graceful_shutdown=1,
        access_log=False,
        ssl_certfile=str(tls.certificate) if tls else None,
        ssl_keyfile=str(tls.key) if tls else None,
        server_header=False,
    )


def serve_forever(
    app: ASGIApp,
    host: str,
    port: int,
    log_level: str = "warning",
    tls: Tls | None = None,
    limits: ConnectionLimits | None = None,
) -> None:
    uvicorn.Server(_config(app, host, port, log_level, tls, limits)).run()


class SignalFreeServer(uvicorn.Server):
    """uvicorn without signal handlers of its own: the station's exit path
    (station/exit_path.py) owns SIGTERM, SIGINT, SIGHUP and SIGQUIT and stops this server by
    `should_exit` once it has asked the run to stop. (uvicorn's own would re-raise a SIGTERM
    after its shutdown, killing the process before the run is made safe and sealed.)"""

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield

    def install_signal_handlers(self) -> None:  # the name in uvicorn before 0.29
        pass


def station_server(
    app: ASGIApp, host: str, port: int, log_level: str = "warning", tls: Tls | None = None,
    limits: ConnectionLimits | None = None,
) -> SignalFreeServer:
    """The operator screen's server for the foreground (`server.run()`), signals left to the
    caller."""
    return SignalFreeServer(_config(app, host, port, log_level, tls, limits))


def serve_in_thread(
    app: ASGIApp,
    host: str = "127.0.0.1",
    port: int = 0,
    startup_timeout_s: float = 10.0,
    before_stop: Callable[[], None] | None = None,
    tls: Tls | None = None,
    limits: ConnectionLimits | None = None,
) -> BackgroundServer:
    """Start the app on a background thread; returns once it accepts connections."""
    port = port or free_port(host)
    server = uvicorn.Server(_config(app, host, port, "warning", tls, limits))
    thread = threading.Thread(target=server.run, name="station-ui", daemon=True)
    thread.start()
    deadline = time.monotonic() + startup_timeout_s
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise RuntimeError(f"the UI server did not start on {host}:{port}")
        time.sleep(0.02)
    scheme = "https" if tls else "http"
    return BackgroundServer(server, thread, f"{scheme}://{host}:{port}", before_stop)
