"""The lockstep clock's bench is an instrument of the run: a bench whose process is stopped
(SIGSTOP, a debugger) or gone is named as such, an instrument fault the engine ends the run
on with the safe-state pass, never "internal error ... report this" (issue 39, finding 16)."""

from __future__ import annotations

import json
import socket
import threading
from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from drivers.errors import ConnectionLost, InstrumentTimeout
from station.bench_clock import station_clock


@dataclass
class Bench:
    control: str
    speed: float = 1.0
    lockstep: bool = True


def _serve(server: socket.socket, answer_advance: bool) -> None:
    conn, _ = server.accept()
    with conn, conn.makefile("rwb") as f:
        for line in f:
            cmd = json.loads(line)["cmd"]
            if cmd == "advance" and not answer_advance:
                if answer_advance is None:  # the bench's process ends
                    return
                continue  # frozen: reads, never answers
            f.write(json.dumps({"ok": True, "result": {"time_s": 0.0}}).encode() + b"\n")
            f.flush()


@pytest.fixture(params=["frozen", "gone"])
def bench(request: pytest.FixtureRequest) -> Iterator[tuple[str, Bench]]:
    server = socket.create_server(("127.0.0.1", 0))
    mode = {"frozen": False, "gone": None}[request.param]
    threading.Thread(target=_serve, args=(server, mode), daemon=True).start()
    host, port = server.getsockname()[:2]
    yield request.param, Bench(f"{host}:{port}")
    server.close()


def test_a_bench_that_stops_answering_is_an_instrument_fault(
        bench: tuple[str, Bench]) -> None:
    mode, endpoints = bench
    closers: list = []
    clock = station_clock(endpoints, closers, reply_s=0.5)
    expected = InstrumentTimeout if mode == "frozen" else ConnectionLost
    with pytest.raises(expected) as caught:
        clock.sleep_s(1.0)
    assert caught.value.instrument == "simulated bench"
    assert ("stopped or frozen" if mode == "frozen" else "has gone") in str(caught.value)
    for close in closers:
        close()
