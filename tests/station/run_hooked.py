"""`station run` with two test hooks, as its own process (tests/station/test_start_safe.py).

    python tests/station/run_hooked.py MARKS_FILE [--freeze-at STEP:SECONDS] [--truth-at STEP]
        -- station run ARGS...

The real station CLI runs unchanged; the hooks only watch it:

--freeze-at STEP[#N]:SECONDS  when the lockstep clock passes SECONDS station s into STEP (its
    Nth beginning, one per condition; the first by default) (for the
    program step, which takes no station time: right after its first calibration write), write
    {"frozen": STEP, ...} to MARKS_FILE and block the run there for good. In lockstep the bench's
    world moves only when the station asks, so the bench stays exactly as it was mid-step (the
    table turning, the supply on, the streams on) until the test kills this process with -9.
--until FILE  with --freeze-at: block only until FILE exists, then go on (a run held mid-step
    while the test tries a second station on the same bench).
--truth-at STEP  when STEP begins (its progress event, published before the step's setup
    touches anything), write the bench's truth {"truth": {...}} to MARKS_FILE: what the bench
    really was when the step began.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any


def _mark(path: Path, **entry: Any) -> None:
    with path.open("a", encoding="utf-8") as f:
        f.write(json.dumps(entry) + "\n")


def install(
    marks: Path, freeze_at: str | None, truth_at: str | None, until: Path | None = None
) -> None:
    from drivers import part_link
    from station import uut

    step_name, _, seconds = (freeze_at or "").partition(":")
    step_name, _, nth = step_name.partition("#")  # STEP#N: the Nth time STEP begins
    begun: dict[str, int] = {}
    state: dict[str, Any] = {"step": ""}

    def freeze(why: str) -> None:
        if state.get("frozen"):
            return
        state["frozen"] = True
        _mark(marks, frozen=step_name, why=why)
        if until is None:
            threading.Event().wait()  # the run thread stops here; kill -9 ends the process
        while not until.exists():
            time.sleep(0.02)

    original_run_engine = uut.UutRunner._run_engine

    def run_engine(self: Any, opened: Any, parts: Any, warnings: Any = None) -> Any:
        clock = opened.bench.clock
        armed: dict[str, float] = {}

        def on_progress(ev: Any) -> None:
            if ev.kind != "step" or ev.step == state["step"]:
                return
            state["step"] = ev.step
            begun[ev.step] = begun.get(ev.step, 0) + 1
            if truth_at and ev.step == truth_at and "truth" not in state:
                from drivers.sim.control_client import ControlClient

                with ControlClient(self.endpoints.control) as control:
                    state["truth"] = control.truth()
                _mark(marks, truth=state["truth"], step=ev.step)
            if (step_name and ev.step == step_name and seconds and "at" not in armed
                    and begun[ev.step] == int(nth or 1)):
                armed["at"] = clock.now_s() + float(seconds)

        def waiter(t_s: float, reply: Any) -> None:
            # only within the step: a step that ended sooner is never frozen in the next one
            if "at" in armed and t_s >= armed["at"] and state["step"] == step_name:
                freeze(f"{t_s - armed['at'] + float(seconds):.1f} station s into {step_name}")

        self.progress.subscribe(on_progress)
        if step_name and seconds:
            clock.add_waiter(waiter)
        return original_run_engine(self, opened, parts, warnings)

    uut.UutRunner._run_engine = run_engine  # type: ignore[method-assign]

    if step_name and not seconds:  # a step without station time: after its first CAL write
        original_cal_write = part_link.SerialPartLink._cal_write

        def cal_write(self: Any, values: dict[str, float]) -> None:
            original_cal_write(self, values)
            if state["step"] == step_name:
                freeze("after the first calibration write")

        part_link.SerialPartLink._cal_write = cal_write  # type: ignore[method-assign]


def main() -> int:
    argv = sys.argv[1:]
    split = argv.index("--")
    p = argparse.ArgumentParser()
    p.add_argument("marks", type=Path)
    p.add_argument("--freeze-at")
    p.add_argument("--truth-at")
    p.add_argument("--until", type=Path)
    args = p.parse_args(argv[:split])
    install(args.marks, args.freeze_at, args.truth_at, args.until)
    from station.cli.main import main as station_main

    return int(station_main(argv[split + 1 :]))


if __name__ == "__main__":
    sys.exit(main())
