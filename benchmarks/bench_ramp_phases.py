"""The ramp's phases in station time, and the time left the progress showed at each.

    python3 benchmarks/bench_ramp_phases.py [--procedure P] [--sim-config C | --serials S,...]

Runs the procedure on the simulated bench in lockstep and prints, for each phase change of
every step ("step" progress events), the station time, the fraction and the time left the
operator saw, then the run's end: the figures behind procedures/steps/ramp.py's
COOL_PER_HEAT and AFTER_COOLING_S.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import Any

import yaml

from procedures.runtime.progress import ProgressEvent
from station.sim_run import run_simulated

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--procedure", type=Path, default=ROOT / "config/procedures/eol-ramp.yaml")
    ap.add_argument("--sim-config", type=Path, help="a config/sim file: its parts and keys")
    ap.add_argument("--serials", default="SIM-7001,SIM-7002")
    args = ap.parse_args()
    extra: dict[str, Any] = {}
    if args.sim_config:
        extra = yaml.safe_load(args.sim_config.read_text())
        parts = extra.pop("parts")
    else:
        parts = [{"socket": i + 1, "serial": s} for i, s in enumerate(args.serials.split(","))]
    events: list[ProgressEvent] = []
    with tempfile.TemporaryDirectory() as tmp:
        result, _ = run_simulated(parts, procedure_path=args.procedure, out=Path(tmp),
                                  on_progress=events.append, sim_config=extra or None)
    end_s = events[-1].station_time_s
    print(f"{'station s':>9}  {'step':18} {'phase':12} {'done':>5}  {'left shown':>10}  actual")
    for e in events:
        if e.kind != "step":
            continue
        left = "-" if e.remaining_s is None else f"{e.remaining_s / 60:6.1f} min"
        print(f"{e.station_time_s:9.0f}  {e.step:18} {e.phase:12} {e.fraction:5.2f}  "
              f"{left:>10}  {(end_s - e.station_time_s) / 60:5.1f} min")
    verdicts = sorted((k, str(v)) for k, v in result.verdicts.items())
    print(f"end at {end_s:.0f} s; verdicts {verdicts}")


if __name__ == "__main__":
    main()
