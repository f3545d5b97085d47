"""Fixture boards on the simulated bench: 32 sockets are four boards of eight, each its own
twin with one pty per socket, every socket streaming on the same advance."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path
from typing import Any

from drivers import fixture_protocol as fp
from drivers.sim.bench import Bench
from drivers.sim.config import SimConfig, load_sim_config
from drivers.sim.fixture_board import board_sockets
from drivers.sim.world import World

ROOT_CONFIG = Path(__file__).resolve().parents[2] / "config"


def test_sockets_are_cut_into_boards_of_the_configured_size() -> None:
    assert board_sockets(list(range(1, 33)), 8) == [
        list(range(1, 9)), list(range(9, 17)), list(range(17, 25)), list(range(25, 33))
    ]
    assert board_sockets([3, 1, 2], 2) == [[1, 2], [3]]


def test_the_32_socket_sim_config_is_four_boards_of_eight_parts() -> None:
    config = load_sim_config(ROOT_CONFIG / "sim" / "thirty_two_sockets.yaml")
    assert config.socket_count == 32
    assert config.fixture.sockets_per_board == 8
    assert sorted(p.socket for p in config.parts) == list(range(1, 33))


def _read_all(fd: int) -> bytes:
    os.set_blocking(fd, False)
    out = b""
    while True:
        try:
            chunk = os.read(fd, 1 << 16)
        except BlockingIOError:
            return out
        if not chunk:
            return out
        out += chunk


def test_a_32_socket_bench_serves_four_boards_and_every_socket_streams() -> None:
    parts = [{"socket": s, "serial": f"SIM-B{s:03d}"} for s in range(1, 33)]
    config = SimConfig.model_validate({"parts": parts, "fixture": {"sockets": 32}})

    async def scenario() -> tuple[dict[str, Any], dict[str, Any], dict[int, bytes]]:
        bench = Bench(config, lockstep=True)
        await bench.start()
        slaves = {}
        try:
            state = bench.endpoints()
            for s, path in state["duts"].items():
                slaves[int(s)] = os.open(path, os.O_RDWR | os.O_NOCTTY)
            w = bench.world
            w.supply.output_on, w.supply.voltage_set_v, w.supply.current_limit_a = True, 5.0, 2.0
            w.advance_to(1.0)
            for sock in w.sockets.values():
                sock.handle_line("START", w.advance())
            reply = await bench.dispatch({"cmd": "advance", "to_s": 2.0})
            await asyncio.sleep(0.05)  # the event loop writes what the ptys did not take
            data = {s: _read_all(fd) for s, fd in slaves.items()}
            return state, reply, data
        finally:
            for fd in slaves.values():
                os.close(fd)
            await bench.stop()

    state, reply, data = asyncio.run(scenario())
    assert state["sockets"] == 32 and len(state["duts"]) == 32
    assert state["boards"] == {str(b + 1): list(range(8 * b + 1, 8 * b + 9)) for b in range(4)}
    assert len(set(state["duts"].values())) == 32  # a port of its own for every socket
    assert reply["seq"] == {str(s): 199 for s in range(1, 33)}  # 200 Hz for (1 s, 2 s]
    for s in range(1, 33):
        frames = fp.FrameParser().feed(data[s])
        assert list(frames.seq) == list(range(200)), f"socket {s}"


def test_produce_all_gives_every_socket_its_own_frames_as_produce_would() -> None:
    parts = [{"socket": s, "serial": f"SIM-P{s:03d}"} for s in range(1, 5)]
    cfg = {"parts": parts, "fixture": {"sockets": 4}}
    one = World(SimConfig.model_validate(cfg), lockstep=True)
    both = World(SimConfig.model_validate(cfg), lockstep=True)
    for w in (one, both):
        w.supply.output_on, w.supply.voltage_set_v, w.supply.current_limit_a = True, 5.0, 1.0
        t = w.advance_to(0.5)
        for s, sock in w.sockets.items():
            sock.handle_line("START", t + 0.0013 * s)  # each socket its own sample times
    t = one.advance_to(3.0)
    singly = {s: sock.produce(t) for s, sock in one.sockets.items()}
    together = both.produce_all(both.advance_to(3.0))
    assert together == singly
    assert all(len(v) > 0 for v in together.values())
