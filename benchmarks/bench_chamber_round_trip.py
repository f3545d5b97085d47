"""Command round trip of each chamber family against its twin (median and p99, wall ms).

Each twin runs alone in a child process over its own world (as the bench serves it), and this
process times `read_temperature()` (one request each: a Modbus read, or `TEMP?`) through the
family's driver over loopback.

    python3 benchmarks/bench_chamber_round_trip.py [--count 500] [--json out.json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing as mp
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers import espec_p300, watlow_f4t  # noqa: E402
from drivers.chamber import ModbusChamber  # noqa: E402
from drivers.clock import ScaledClock  # noqa: E402
from drivers.sim.config import SimConfig  # noqa: E402
from drivers.sim.espec_twin import EspecP300Twin  # noqa: E402
from drivers.sim.modbus_twins import ChamberTwin  # noqa: E402
from drivers.sim.watlow_f4t_twin import WatlowF4TTwin  # noqa: E402
from drivers.sim.world import World  # noqa: E402

FAMILIES = ("watlow-f4", "watlow-f4t", "espec-p300")


def _serve(family: str, endpoint_q: Any, stop: Any) -> None:
    async def main() -> None:
        world = World(SimConfig(), 1.0)
        if family == "watlow-f4":
            legacy = ChamberTwin(world)
            await legacy.start()
            endpoint, shutdown = legacy.endpoint, legacy.shutdown
        else:
            twin = WatlowF4TTwin(world) if family == "watlow-f4t" else EspecP300Twin(world)
            await twin.start()
            endpoint, shutdown = twin.endpoint(), twin.shutdown
        endpoint_q.put(endpoint)
        while not stop.is_set():
            await asyncio.sleep(0.05)
        await shutdown()

    asyncio.run(main())


def _driver(family: str, endpoint: str) -> Any:
    if family == "watlow-f4":
        host, _, port = endpoint.rpartition(":")
        return ModbusChamber.connect(host, int(port), ScaledClock(1.0))
    factory = watlow_f4t.factory if family == "watlow-f4t" else espec_p300.factory
    return factory({"address": endpoint})


def measure(family: str, count: int) -> dict[str, Any]:
    ctx = mp.get_context("spawn")
    endpoint_q, stop = ctx.Queue(), ctx.Event()
    proc = ctx.Process(target=_serve, args=(family, endpoint_q, stop), daemon=True)
    proc.start()
    try:
        driver = _driver(family, endpoint_q.get(timeout=30))
        try:
            for _ in range(20):  # warm up
                driver.read_temperature()
            times_ms = []
            for _ in range(count):
                t0 = time.perf_counter()
                driver.read_temperature()
                times_ms.append((time.perf_counter() - t0) * 1e3)
        finally:
            driver.close()
    finally:
        stop.set()
        proc.join(10)
    times_ms.sort()
    return {
        "family": family,
        "count": count,
        "median_ms": statistics.median(times_ms),
        "p99_ms": times_ms[min(len(times_ms) - 1, int(0.99 * len(times_ms)))],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=500)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    results = [measure(family, args.count) for family in FAMILIES]
    print(f"{'family':<12} {'n':>5} {'median ms':>10} {'p99 ms':>8}")
    for r in results:
        print(f"{r['family']:<12} {r['count']:>5} {r['median_ms']:>10.3f} {r['p99_ms']:>8.3f}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
