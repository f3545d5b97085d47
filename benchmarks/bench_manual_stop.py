"""The hand-turned stop bench: station time per part, and the stop-method scale against the
bench's truth over a few parts.

Each part gets a fresh simulated bench (config/sim/manual.yaml: no rate table, an
inclinometer per fixture, the simulated operator's hand) and a full run of the procedure
through the station (config/station-manual.yaml). Per part it prints the station time, the
time spent in manual_stop (prompt to rest, the operator's part included), the scale error
against the part's true scale, its k = 2 uncertainty and the normalised error; then the
mean station time and the share of parts whose truth lies within k = 2.

    python3 benchmarks/bench_manual_stop.py [--parts 5] [--speed 100] [--procedure FILE]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.sim.launcher import launch_bench  # noqa: E402
from procedures.runtime.progress import ProgressEvent  # noqa: E402
from procedures.runtime.record import read_record  # noqa: E402
from station.endpoints import Endpoints  # noqa: E402
from station.station_file import load_settings  # noqa: E402
from station.uut import UutRunner  # noqa: E402


def run_part(index: int, procedure: Path, speed: float, out: Path) -> dict[str, Any]:
    serial = f"SIM-{7100 + index:04d}"
    config = yaml.safe_load((ROOT / "config/sim/manual.yaml").read_text())
    config["seed"] = index
    # no temperature or supply dependence of the scale: the truth is the part's `scale`
    config["parts"] = [{"socket": 1, "serial": serial, "scale_temp_coeff_per_c": 0.0,
                        "scale_supply_coeff_per_v": 0.0}]
    steps: dict[str, float] = {}

    def on_event(ev: ProgressEvent) -> None:
        if ev.kind == "step":
            steps.setdefault(ev.step, ev.station_time_s)
        elif ev.step == "manual_stop":
            steps["manual_stop_end"] = ev.station_time_s

    with launch_bench(config=config, speed=speed) as bench:
        runner = UutRunner(
            load_settings(ROOT / "config/station-manual.yaml"), procedure_path=procedure,
            out=out, endpoints=Endpoints.of_bench(bench.endpoints), certificate=False,
        )
        runner.progress.subscribe(on_event)
        result = runner.run({1: serial})
        truth = bench.control.truth()["sockets"]["1"]["parameters"]["scale"]
    record = read_record(result.folders[1])
    stops = record.analysis.stop_method
    stop = next(iter(stops.values()), None)
    row: dict[str, Any] = {"serial": serial, "verdict": str(result.verdicts[1]),
                           "station_s": result.station_time_s, "truth": truth,
                           "reason": result.reasons[1]}
    if "manual_stop" in steps and "manual_stop_end" in steps:
        row["manual_s"] = steps["manual_stop_end"] - steps["manual_stop"]
    if stop is not None and stop.scale is not None and stop.u_scale is not None:
        row.update(scale=stop.scale, u_k2=2 * stop.u_scale)
        row["z"] = (stop.scale - truth) / stop.u_scale
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", type=int, default=5)
    ap.add_argument("--speed", type=float, default=100.0)
    ap.add_argument("--procedure", default=str(ROOT / "config/procedures/eol-manual-stop.yaml"))
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-manual-") as tmp:
        for i in range(args.parts):
            row = run_part(i, Path(args.procedure), args.speed, Path(tmp))
            rows.append(row)
            err = row.get("scale", float("nan")) - row["truth"]
            print(
                f"{row['serial']} {row['verdict']:<6} station {row['station_s'] / 60:5.2f} min"
                f"  manual_stop {row.get('manual_s', float('nan')):6.1f} s"
                f"  scale error {err * 1e6:+8.0f} ppm  U(k=2) {row.get('u_k2', 0) * 1e6:6.0f} ppm"
                f"  z {row.get('z', float('nan')):+5.2f}",
                flush=True,
            )
            if row["verdict"] != "PASS":
                print(f"  {row['reason']}", flush=True)
    done = [r for r in rows if "z" in r]
    print(f"station time per part: {statistics.fmean(r['station_s'] for r in rows) / 60:.2f} min")
    if done:
        inside = sum(abs(r["z"]) <= 2 for r in done)
        print(f"truth within k = 2: {inside} of {len(done)} parts; "
              f"RMS z {statistics.fmean(r['z'] ** 2 for r in done) ** 0.5:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
