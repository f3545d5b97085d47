"""Property-based test of the bench's control channel (hypothesis): any line a client sends
gets one JSON reply, `{"ok": true, "result": ...}` or `{"ok": false, "error": "..."}` with a
message that is not an internal error, promptly; the bench keeps answering. Requests go
through the control server's own decoding and the bench's dispatch, on a real bench (twins,
ptys) running on its own event loop in this process."""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import Iterator
from typing import Any

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from drivers.sim.bench import FAULT_KINDS, Bench
from drivers.sim.config import parse_sim_config

json_values = st.recursive(
    st.one_of(
        st.none(), st.booleans(), st.integers(-(10**20), 10**20),
        st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20),
    ),
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.text(max_size=8), inner, max_size=3)),
    max_leaves=8,
)
COMMANDS = ["ping", "truth", "endpoints", "load", "unload", "fault", "clear_faults", "nope"]
KEYS = ["socket", "part", "kind", "target", "delay_s", "code", "byte_error_rate",
        "frame_drop_rate", "report_fault"]
requests = st.fixed_dictionaries(
    {"cmd": st.one_of(st.sampled_from(COMMANDS), json_values)},
    optional={k: st.one_of(json_values, st.sampled_from([*FAULT_KINDS, "table", "estop", 1]))
              for k in KEYS},
)
lines = st.one_of(
    requests.map(lambda r: json.dumps(r).encode()),  # NaN/Infinity: Python's JSON extension
    st.binary(max_size=200),
    json_values.map(lambda v: json.dumps(v).encode()),
)


class _LoopThread:
    """A bench on an asyncio loop in a daemon thread; `ask` runs a coroutine there."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def ask(self, coro: Any, timeout_s: float = 5.0) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout_s)

    def stop(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)


@pytest.fixture(scope="module")
def live_bench() -> Iterator[tuple[_LoopThread, Bench]]:
    runner = _LoopThread()
    config = parse_sim_config({"parts": [{"socket": 1, "serial": "SIM-P001"}],
                               "fixture": {"sockets": 2}})

    async def make() -> Bench:
        bench = Bench(config, speed=100.0)
        await bench.start()
        return bench

    bench = runner.ask(make(), 20.0)
    yield runner, bench
    runner.ask(bench.stop(), 20.0)
    runner.stop()


@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(line=lines)
@example(line=b"\x80")  # not UTF-8: it once killed the client's connection with no reply
@example(line=b"[" * 200_000)  # nested past the JSON parser's recursion
@example(line=b'{"cmd": "unload", "socket": Infinity}')  # int(inf): OverflowError
@example(line=b'{"cmd": "fault", "kind": ["modbus_drop"]}')  # unhashable kind
@example(line=b'{"cmd": "fault", "kind": "modbus_delay", "delay_s": NaN}')
@example(line=b'{"cmd": "load", "part": [1, 2]}')
def test_any_control_line_gets_one_clear_reply(
    live_bench: tuple[_LoopThread, Bench], line: bytes
) -> None:
    runner, bench = live_bench
    reply = runner.ask(bench.control._answer(line + b"\n"))
    json.dumps(reply)  # the server sends it as JSON
    assert set(reply) in ({"ok", "result"}, {"ok", "error"}), reply
    if not reply["ok"]:
        assert isinstance(reply["error"], str) and reply["error"]
        assert not reply["error"].startswith("internal error"), (line, reply)
    runner.ask(bench._clear_faults())
    assert runner.ask(bench.control._answer(b'{"cmd": "ping"}\n'))["ok"]
