"""Supply command round trips per family against its twin (a measurement, not a test):
`python3 benchmarks/bench_supply_roundtrip.py [N]`.

Each family's driver talks through pyvisa + pyvisa-py to its twin on this machine (`scpi`: the
pty twin over ASRL; `keysight-e36300`, `rigol-dp800`: the LAN twins over TCPIP SOCKET), the twins
on an asyncio loop in a background thread as in the bench. Prints median and p99 wall ms of a
query (`measure_voltage`) and of a setting (`set_voltage`: the command and the error query).
"""

from __future__ import annotations

import asyncio
import statistics
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any, TypeVar

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers import keysight_e36300, rigol_dp800, supply  # noqa: E402
from drivers.sim.config import SimConfig  # noqa: E402
from drivers.sim.pty_twins import SupplyTwin  # noqa: E402
from drivers.sim.scpi_lan_twins import KeysightE36300Twin, RigolDp800Twin  # noqa: E402
from drivers.sim.world import World  # noqa: E402

T = TypeVar("T")


def _on_loop(loop: asyncio.AbstractEventLoop, fn: Callable[[], T]) -> T:
    done: Future[T] = Future()
    loop.call_soon_threadsafe(lambda: done.set_result(fn()))
    return done.result(10)


def _ms(samples: list[float]) -> str:
    ordered = sorted(samples)
    p99 = ordered[min(len(ordered) - 1, round(0.99 * (len(ordered) - 1)))]
    return f"median {statistics.median(ordered) * 1e3:6.2f} ms, p99 {p99 * 1e3:6.2f} ms"


def _time(call: Callable[[], Any], n: int) -> list[float]:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        call()
        out.append(time.perf_counter() - t0)
    return out


def main(n: int = 300) -> None:
    loop = asyncio.new_event_loop()
    threading.Thread(target=loop.run_forever, daemon=True).start()
    world = World(SimConfig.model_validate({"parts": [{"socket": 1, "serial": "SIM-B001"}]}), 1.0)
    pty = _on_loop(loop, lambda: SupplyTwin(world, loop))
    lan = {"keysight-e36300": KeysightE36300Twin(world), "rigol-dp800": RigolDp800Twin(world)}
    for twin in lan.values():
        asyncio.run_coroutine_threadsafe(twin.start(), loop).result(10)
    drivers = {
        "scpi": supply.factory({"address": pty.port.path}),
        "keysight-e36300": keysight_e36300.factory({"address": lan["keysight-e36300"].endpoint()}),
        "rigol-dp800": rigol_dp800.factory({"address": lan["rigol-dp800"].endpoint()}),
    }
    print(f"{n} round trips each (pyvisa {__import__('pyvisa').__version__}, pyvisa-py backend)")
    for family, psu in drivers.items():
        psu.set_voltage(5.0)
        query = _time(psu.measure_voltage, n)
        setting = _time(lambda p=psu: p.set_voltage(5.0), n)
        print(f"{family:16s} query   {_ms(query)}")
        print(f"{family:16s} setting {_ms(setting)}")
        psu.close()
    for twin in lan.values():
        asyncio.run_coroutine_threadsafe(twin.shutdown(), loop).result(10)
    _on_loop(loop, pty.close)
    loop.call_soon_threadsafe(loop.stop)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 300)
