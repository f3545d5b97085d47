"""The bench in lockstep: its world stands still until `advance`, which sends the frames due."""

from __future__ import annotations

import asyncio
import time

import pytest

from drivers.sim.bench import Bench
from drivers.sim.config import SimConfig
from drivers.sim.control import ControlRequestError
from drivers.sim.world import World


def config() -> SimConfig:
    return SimConfig.model_validate(
        {"parts": [{"socket": 1, "serial": "SIM-0001"}, {"socket": 2, "serial": "SIM-0002"}],
         "fixture": {"sockets": 2}}
    )


def test_a_lockstep_world_moves_only_when_asked_and_never_back() -> None:
    world = World(config(), lockstep=True)
    t0 = world.advance()
    time.sleep(0.05)
    assert world.advance() == t0 == 0.0
    assert world.advance_to(12.5) == 12.5
    assert world.advance_to(3.0) == 12.5
    part = world.sockets[1].part
    assert part is not None and part.die_temp_c() == pytest.approx(world.chamber.air_c, abs=1.0)


def test_a_scaled_world_refuses_advance_to() -> None:
    with pytest.raises(ValueError, match="lockstep"):
        World(config(), speed=10.0).advance_to(1.0)


def test_advance_sends_the_frames_due_and_names_the_last_sequence_number() -> None:
    async def scenario() -> tuple[dict[str, object], dict[str, object]]:
        bench = Bench(config(), lockstep=True)
        await bench.start()
        try:
            w = bench.world
            w.supply.output_on, w.supply.voltage_set_v, w.supply.current_limit_a = True, 5.0, 0.5
            w.advance_to(1.0)
            bench.fixtures[1].socket.handle_line("START", w.advance())  # socket 2 stays idle
            reply = await bench.dispatch({"cmd": "advance", "to_s": 3.0})
            again = await bench.dispatch({"cmd": "advance", "to_s": 3.0})
            return reply, again
        finally:
            await bench.stop()

    reply, again = asyncio.run(scenario())
    odr_hz = 200  # the fixture's default output rate
    assert reply["time_s"] == 3.0
    assert reply["seq"] == {"1": 2 * odr_hz - 1}  # frames 0..399 for (1 s, 3 s]
    assert again["seq"] == {}  # the world did not move: nothing more is due


def test_advance_is_refused_by_a_bench_on_its_own_clock() -> None:
    async def scenario() -> None:
        bench = Bench(config(), speed=10.0)
        with pytest.raises(ControlRequestError, match="lockstep"):
            await bench.dispatch({"cmd": "advance", "to_s": 1.0})

    asyncio.run(scenario())
