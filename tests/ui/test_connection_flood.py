"""A flood of idle connections to the operator screen (issue 25 finding 8): 1,100 of them
used to leave START refused ("the connection to the rate table dropped") with the lights
green. The server caps connections per client and in total (station/ui/connections.py); the
instrument links wait by poll (drivers/fd_wait.py), whatever their descriptor numbers."""

from __future__ import annotations

import contextlib
import json
import os
import resource
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from station.ui.connections import ConnectionLimits
from station.ui.server import serve_in_thread
from tests.ui.stationkit import (
    FAIL_SERIAL,
    PASS_SERIAL,
    make_station_config,
    start_ui_process,
    station_client,
    stop_ui_process,
)

FLOOD = 2000


@contextlib.contextmanager
def descriptors(n: int) -> Iterator[None]:
    """This process (and the processes it starts) may hold `n` descriptors."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < n:
        pytest.skip(f"the hard descriptor limit {hard} is below the {n} this test needs")
    if soft == resource.RLIM_INFINITY or soft >= n:
        yield
        return
    resource.setrlimit(resource.RLIMIT_NOFILE, (n, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def flood(port: int, count: int, within_s: float = 60.0) -> list[socket.socket]:
    """`count` idle connections to the screen's port (they send nothing), opened in at most
    `within_s` wall seconds; the server may close any of them."""
    held: list[socket.socket] = []
    deadline = time.monotonic() + within_s
    for _ in range(count):
        if time.monotonic() > deadline:
            break
        try:
            held.append(socket.create_connection(("127.0.0.1", port), timeout=2.0))
        except OSError:
            break
    return held


def close_all(held: list[socket.socket]) -> None:
    for s in held:
        s.close()


def test_idle_connections_give_way_and_time_out(app: object) -> None:
    """In process: a per-client cap of 8 holds 8 idle connections however many come; a
    request still gets through (an idle one gives way); idle ones close after
    first_request_s."""
    limits = ConnectionLimits(total=16, per_client=8, first_request_s=1.0)
    server = serve_in_thread(app, limits=limits)
    limiter = server.server.config.http_protocol_class.connection_limiter
    held: list[socket.socket] = []
    try:
        held = flood(int(server.url.rsplit(":", 1)[1]), 200, within_s=20)
        assert len(held) == 200
        deadline = time.monotonic() + 5
        while limiter.evicted + limiter.refused < 192 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert limiter.count <= 8
        with httpx.Client(base_url=server.url, timeout=5) as client:
            assert client.get("/api/state").status_code == 200
            assert client.get("/api/state").status_code == 200  # kept alive
            assert limiter.count <= 8
        deadline = time.monotonic() + 5
        while limiter.count and time.monotonic() < deadline:
            time.sleep(0.05)
        assert limiter.count == 0  # the idle ones timed out, the client closed its own
    finally:
        close_all(held)
        server.stop()


@pytest.fixture
def app(tmp_path: Path) -> Iterator[object]:
    from station.ui.app import create_app
    from station.ui.controller import Controller
    from station.ui.history import History
    from station.ui.hub import Hub
    from tests.ui.fake_runner import FakeRunner

    runner = FakeRunner(tmp_path / "runs", step_s=0.02)
    controller = Controller(runner, Hub())
    yield create_app(controller, History(tmp_path / "runs"))
    controller.hub.close()
    runner.close()


def _wait_state(client: httpx.Client, done: object, timeout_s: float) -> dict:
    deadline = time.monotonic() + timeout_s
    while True:
        state = client.get("/api/state").json()
        if done(state):  # type: ignore[operator]
            return state
        if time.monotonic() > deadline:
            raise AssertionError(f"state not reached in {timeout_s} s: {state}")
        time.sleep(0.2)


@pytest.mark.slow
def test_start_and_abort_work_under_2000_idle_connections(tmp_path: Path) -> None:
    folder = tmp_path / "config"
    make_station_config(folder)
    with descriptors(FLOOD + 1024):  # the flood's ends here; the server inherits the limit
        station = start_ui_process(folder, tmp_path / "ui.log")
        held: list[socket.socket] = []
        try:
            port = int(station.url.rsplit(":", 1)[1])
            held = flood(port, FLOOD)
            assert len(held) == FLOOD, f"only {len(held)} connections opened"
            deadline, server_fds = time.monotonic() + 10, 1 << 30
            while server_fds >= ConnectionLimits().total + 200 and time.monotonic() < deadline:
                time.sleep(0.1)  # what the last accepts took is given back once capped
                server_fds = len(os.listdir(f"/proc/{station.process.pid}/fd"))
            assert server_fds < ConnectionLimits().total + 200, server_fds
            client = station_client(station.url)
            lights = client.get("/api/state").json()["instruments"]
            assert lights and all(x["connected"] and not x["faulted"] for x in lights), lights
            r = client.post(
                "/api/start", json={"serials": {"1": PASS_SERIAL, "2": FAIL_SERIAL}}
            )
            assert r.status_code == 200, r.text
            _wait_state(client, lambda s: s["run"] is not None, 60)
            assert client.post("/api/abort", json={}).status_code == 200
            state = _wait_state(client, lambda s: s["run"] is None and s["last"], 120)
            assert state["last"], state
            records = [
                json.loads(p.read_text()) for p in (folder / "runs").glob("*/record.json")
            ]
            assert len(records) == 2 and {r["verdict"] for r in records} == {"ABORTED"}
            assert station.truth()["safe"]["all"] is True
            lights = client.get("/api/state").json()["instruments"]
            assert lights and all(x["connected"] and not x["faulted"] for x in lights), lights
            log = (tmp_path / "ui.log").read_text()
            assert "out of range in select" not in log and "Too many open files" not in log
        finally:
            close_all(held)
            stop_ui_process(station.process)
