"""Instrument families against their twins: command round trip per family, and with
`--procedure` the full procedure's station time per family set (a measurement, not a test).

Round trip: for each family set below the simulated bench is started as its own process (as
`station bench` serves it, `instruments:` in its sim config choosing the twins) and this
process opens each role's registered driver `<role>.<family>` on the twin's address, then
times N reads through it: the table's status (`read_status`), the chamber's air temperature
(`read_temperature`: a Modbus read, or `TEMP?`) and the supply's output (`measure_voltage`:
`MEAS:VOLT?` in the family's own form); for supplies also a setting (`set_voltage`: the
command and its error-queue read). Prints median and p99 wall ms.

Procedure: each family set runs the full procedure on one simulated part (the same serial,
so the same simulated physics); the station time is read from the part's record
(`timings.total`) and the spread between the sets is printed in % (the issue asks for 2 %).

    python3 benchmarks/bench_instruments.py [-n 300] [--json out.json]
    python3 benchmarks/bench_instruments.py --procedure [--speed 100]
        [--procedure-file config/procedures/eol-rate-table.yaml]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common.clock import ScaledClock  # noqa: E402
from drivers import registry  # noqa: E402
from drivers.sim.launcher import BenchEndpoints, launch_bench  # noqa: E402
from procedures.runtime.record import read_record  # noqa: E402

# family sets as the sim config's `instruments:` names them (the default set first)
FAMILY_SETS: dict[str, dict[str, str]] = {
    "default": {"rate_table": "modbus-servo", "chamber": "watlow-f4", "supply": "scpi"},
    "acutrol+f4t+keysight": {
        "rate_table": "acutrol", "chamber": "watlow-f4t", "supply": "keysight-e36300",
    },
    "servo+espec+rigol": {
        "rate_table": "modbus-servo", "chamber": "espec-p300", "supply": "rigol-dp800",
    },
}  # fmt: skip

# role -> (operation name, the timed call on the driver)
READS: dict[str, tuple[str, Callable[[Any], Any]]] = {
    "rate_table": ("status", lambda d: d.read_status()),
    "chamber": ("temperature", lambda d: d.read_temperature()),
    "supply": ("MEAS:VOLT?", lambda d: d.measure_voltage()),
}
SUPPLY_SETTING: tuple[str, Callable[[Any], Any]] = (
    "VOLT + error queue",
    lambda d: d.set_voltage(5.0),
)
WARM_UP = 10
PART = {"socket": 1, "serial": "SIM-0301"}


def _percentiles_ms(samples_s: list[float]) -> tuple[float, float]:
    ordered = sorted(samples_s)
    p99 = ordered[min(len(ordered) - 1, round(0.99 * (len(ordered) - 1)))]
    return statistics.median(ordered) * 1e3, p99 * 1e3


def _time(call: Callable[[Any], Any], driver: Any, n: int) -> list[float]:
    for _ in range(WARM_UP):
        call(driver)
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        call(driver)
        out.append(time.perf_counter() - t0)
    return out


def _open(role: str, family: str, endpoints: BenchEndpoints) -> Any:
    _, factory = registry.resolve(role, family)
    address = str(getattr(endpoints, role))
    return registry.open_driver(factory, {"address": address}, ScaledClock(endpoints.speed))


def round_trips(n: int) -> list[dict[str, Any]]:
    """Median and p99 of each family's read (and each supply's setting) against its twin."""
    rows: list[dict[str, Any]] = []
    done: set[tuple[str, str]] = set()
    for families in FAMILY_SETS.values():
        todo = {r: f for r, f in families.items() if (r, f) not in done}
        if not todo:
            continue
        # speed 1: the twins' physics idles, the timing is the protocol's and the drivers'
        with launch_bench(config={"parts": [PART], "instruments": families}, speed=1.0) as bench:
            for role, family in todo.items():
                done.add((role, family))
                driver = _open(role, family, bench.endpoints)
                try:
                    ops = [READS[role]] + ([SUPPLY_SETTING] if role == "supply" else [])
                    for op, call in ops:
                        median_ms, p99_ms = _percentiles_ms(_time(call, driver, n))
                        rows.append({
                            "role": role, "family": family, "operation": op, "count": n,
                            "median_ms": median_ms, "p99_ms": p99_ms,
                        })  # fmt: skip
                        print(f"  ... {role}.{family} {op} done", flush=True)
                finally:
                    driver.close()
    return rows


def print_round_trips(rows: list[dict[str, Any]]) -> None:
    head = f"{'driver':<26} {'operation':<20} {'n':>5} {'median ms':>10} {'p99 ms':>8}"
    print(f"\ncommand round trip against each twin (wall ms, loopback)\n{head}\n{'-' * len(head)}")
    for r in rows:
        name = f"{r['role']}.{r['family']}"
        print(
            f"{name:<26} {r['operation']:<20} {r['count']:>5} {r['median_ms']:>10.3f} "
            f"{r['p99_ms']:>8.3f}"
        )


def procedure_times(procedure: Path, speed: float) -> list[dict[str, Any]]:
    """The full procedure on one part with each family set: station time from the record."""
    from station.endpoints import Endpoints
    from station.station_file import load_settings
    from station.uut import UutRunner

    out = Path(tempfile.mkdtemp(prefix="bench-instruments-"))
    rows = []
    for name, families in FAMILY_SETS.items():
        config = {"parts": [PART], "instruments": families}
        w0 = time.monotonic()
        with launch_bench(config=config, speed=speed, sockets=1) as bench:
            runner = UutRunner(
                load_settings(), procedure_path=procedure, out=out / name,
                endpoints=Endpoints.of_bench(bench.endpoints), certificate=False,
                operator="benchmark",
            )  # fmt: skip
            result = runner.run({1: str(PART["serial"])})
        wall_s = time.monotonic() - w0
        folder = result.folders.get(1)
        rec = read_record(folder) if folder is not None else None
        station_s = float(rec.timings.get("total", float("nan"))) if rec else float("nan")
        verdict = str(rec.verdict) if rec else f"no record ({result.reasons.get(1, '')})"
        rows.append({
            "set": name, "families": families, "station_s": station_s, "wall_s": wall_s,
            "verdict": verdict, "folder": str(folder or ""),
        })  # fmt: skip
        print(f"  ... {name} done in {wall_s:.0f} s wall", flush=True)
    return rows


def print_procedure_times(rows: list[dict[str, Any]], procedure: Path, speed: float) -> None:
    print(f"\nfull procedure {procedure.name} on one part, bench speed {speed:g}x")
    head = f"{'family set':<22} {'station min':>11} {'wall s':>7}  verdict"
    print(f"{head}\n{'-' * len(head)}")
    for r in rows:
        print(f"{r['set']:<22} {r['station_s'] / 60:11.2f} {r['wall_s']:7.1f}  {r['verdict']}")
    times = [r["station_s"] for r in rows]
    if all(t == t and t > 0 for t in times):  # no NaN, all ran
        spread = (max(times) - min(times)) / min(times) * 100.0
        base = times[0]
        per_set = ", ".join(f"{r['set']} {(r['station_s'] - base) / base * 100:+.2f} %"
                            for r in rows[1:])  # fmt: skip
        print(f"spread between sets (max - min) / min: {spread:.2f} % ({per_set} against default)")
    else:
        print("spread between sets: not computed (a set did not complete)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", "--count", type=int, default=300, help="round trips per operation")
    ap.add_argument(
        "--procedure",
        action="store_true",
        help="also run the full procedure with each family set (minutes)",
    )
    ap.add_argument(
        "--procedure-file", type=Path, default=ROOT / "config/procedures/eol-rate-table.yaml"
    )
    ap.add_argument("--speed", type=float, default=100.0, help="bench speed for --procedure")
    ap.add_argument("--json", type=Path, help="write the figures to this file too")
    args = ap.parse_args()  # fmt: skip
    if args.count < 1:
        ap.error("--count must be at least 1")
    figures: dict[str, Any] = {"round_trip": round_trips(args.count)}
    print_round_trips(figures["round_trip"])
    if args.procedure:
        figures["procedure"] = procedure_times(args.procedure_file, args.speed)
        print_procedure_times(figures["procedure"], args.procedure_file, args.speed)
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
