"""How fast can the simulated bench run with no frame lost?

For each output data rate (200 Hz, 1 kHz) and socket count (1, 8) this starts the bench at
increasing world speed factors, streams every socket for a few wall seconds through real ptys
(decoded with FrameParser by one reader thread in this process, like the station would), and
reports the highest speed with zero frames lost and the FIFO never more than half full, plus
the CPU time the bench process and the reader spent.

    python3 benchmarks/bench_stream.py [--wall-s 4] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.sim.launcher import launch_bench  # noqa: E402
from drivers.sim.stream_probe import StreamProbe, power_parts  # noqa: E402

SPEEDS = (25, 50, 100, 200, 400, 800, 1600)
PART_ALLOWANCE_A = 0.05  # the supply current a socket is given (the station's own allowance)
TICK = os.sysconf("SC_CLK_TCK")


def _proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK  # utime + stime


def _self_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run_once(odr_hz: int, sockets: int, speed: float, wall_s: float) -> dict[str, Any]:
    parts = [{"socket": i, "serial": f"BENCH-{i:04d}"} for i in range(1, sockets + 1)]
    with launch_bench(config={"parts": parts, "fixture": {"sockets": sockets}}, speed=speed) as b:
        # a part draws 20-30 mA: the limit grows with the load (a fixed 0.5 A held 32 parts
        # in constant current, below their power-on voltage: "ERR 11 part not powered")
        power_parts(b.endpoints.supply, current_limit_a=max(0.5, PART_ALLOWANCE_A * sockets))
        with StreamProbe([b.endpoints.duts[i] for i in range(1, sockets + 1)]) as probe:
            bench_cpu0, self_cpu0, t0 = (
                _proc_cpu_s(b.endpoints.pid),
                _self_cpu_s(),
                time.monotonic(),
            )
            probe.stream(odr_hz, wall_s=wall_s)
            wall = time.monotonic() - t0
            bench_cpu = _proc_cpu_s(b.endpoints.pid) - bench_cpu0
            reader_cpu = _self_cpu_s() - self_cpu0
            truth = b.control.truth()
        counts = probe.counts
    socks = [truth["sockets"][str(i)] for i in range(1, sockets + 1)]
    sent = sum(s["frames_sent"] for s in socks)
    received = sum(c.frames_ok for c in counts)
    # gaps in the sequence the reader saw (a frame the bench dropped is one of them too, so
    # the bench's own count is reported beside it, not added to it)
    lost = sum(c.frames_lost for c in counts)
    dropped = sum(s["frames_dropped"] for s in socks)
    peak = max(s["fifo_peak_bytes"] / s["fifo_bytes"] for s in socks)
    ok = lost == 0 and dropped == 0 and received == sent and peak < 0.5
    return {
        "odr_hz": odr_hz,
        "sockets": sockets,
        "speed": speed,
        "ok": ok,
        "frames_sent": sent,
        "frames_received": received,
        "frames_lost": lost,
        "frames_dropped_by_bench": dropped,
        "fifo_peak_fraction": round(peak, 4),
        "wall_s": round(wall, 3),
        "frames_per_wall_s": round(received / wall),
        "bench_cpu_s": round(bench_cpu, 3),
        "reader_cpu_s": round(reader_cpu, 3),
        "bench_cpu_per_wall_s": round(bench_cpu / wall, 3),
        "bench_cpu_us_per_frame": round(1e6 * bench_cpu / max(received, 1), 2),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--wall-s", type=float, default=4.0, help="streaming time per trial")
    ap.add_argument("--json", type=Path, help="also write every trial as JSON")
    ap.add_argument("--odr", type=int, nargs="+", default=[200, 1000], help="output data rates")
    ap.add_argument("--sockets", type=int, nargs="+", default=[1, 8], help="socket counts")
    ap.add_argument(
        "--speeds",
        type=float,
        nargs="+",
        default=list(SPEEDS),
        help="speed factors to try, ascending (stops at the first failure)",
    )
    args = ap.parse_args()
    trials: list[dict[str, Any]] = []
    summary = []
    for odr in args.odr:
        for sockets in args.sockets:
            best = None
            for speed in args.speeds:
                try:
                    r = run_once(odr, sockets, speed, args.wall_s)
                except (TimeoutError, RuntimeError, OSError) as exc:
                    r = {
                        "odr_hz": odr,
                        "sockets": sockets,
                        "speed": speed,
                        "ok": False,
                        "error": str(exc),
                    }
                trials.append(r)
                print(json.dumps(r), flush=True)
                if not r["ok"]:
                    break
                best = r
            summary.append((odr, sockets, best))
    print(
        "\nhighest speed with zero frames lost (FIFO < 50 %), "
        f"{args.wall_s:g} s wall per trial, {os.cpu_count()} cores:"
    )
    print(
        f"{'ODR':>6} {'sockets':>7} {'speed':>6} {'frames/s':>9} {'bench CPU/wall':>14} "
        f"{'reader CPU/wall':>15} {'bench us/frame':>14}"
    )
    for odr, sockets, best in summary:
        if best is None:
            print(f"{odr:>6} {sockets:>7}   none at {args.speeds[0]:g}x")
            continue
        print(
            f"{odr:>6} {sockets:>7} {best['speed']:>6} {best['frames_per_wall_s']:>9} "
            f"{best['bench_cpu_per_wall_s']:>14} "
            f"{round(float(best['reader_cpu_s']) / float(best['wall_s']), 3):>15} "
            f"{best['bench_cpu_us_per_frame']:>14}"
        )
    if args.json:
        args.json.write_text(json.dumps(trials, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
