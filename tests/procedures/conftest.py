"""Runs on the real simulated bench (its own process), in-process station side."""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers.sim.control_client import ControlClient
from drivers.sim.launcher import launch_bench
from procedures.runtime.progress import ProgressEvent
from station.endpoints import Endpoints
from station.station_file import load_settings
from station.uut import UutResult, UutRunner

DATA = Path(__file__).resolve().parent / "data"
SHORT = DATA / "short.yaml"


@dataclass
class SimRun:
    result: UutResult
    final_truth: dict[str, Any]
    history: list[dict[str, Any]] = field(default_factory=list)  # polled truth
    events: list[ProgressEvent] = field(default_factory=list)
    injected_at: dict[str, Any] | None = None


def run_on_bench(
    out: Path,
    parts: list[dict[str, Any]],
    *,
    procedure: Path = SHORT,
    speed: float | None = None,
    inject: tuple[str, Callable[[ControlClient], None]] | None = None,
    poll_truth: bool = False,
    sim_extra: dict[str, Any] | None = None,
    certificate: bool = False,
    runner_hook: Callable[[UutRunner], None] | None = None,
) -> SimRun:
    """Start a bench with `parts`, run `procedure` on them, return results and truth.

    `inject=(step_name, action)`: `action(control)` runs when the step first starts.
    Without `speed` the bench runs in lockstep (station time is physics time).
    """
    config = {"parts": parts, **(sim_extra or {})}
    sockets = max(p["socket"] for p in parts)
    with launch_bench(
        config=config, speed=speed, sockets=sockets, lockstep=speed is None
    ) as bench:
        e = bench.endpoints
        runner = UutRunner(
            load_settings(),
            procedure_path=procedure,
            out=out,
            endpoints=Endpoints.of_bench(bench.endpoints),
            certificate=certificate,
            operator="pytest",
        )
        run = SimRun(result=UutResult(), final_truth={})
        fired = threading.Event()

        def on_event(ev: ProgressEvent) -> None:
            run.events.append(ev)
            if inject and ev.kind == "step" and ev.step == inject[0] and not fired.is_set():
                fired.set()
                run.injected_at = {"station_time_s": ev.station_time_s, "condition": ev.condition}
                inject[1](bench.control)

        runner.progress.subscribe(on_event)
        if runner_hook:
            runner_hook(runner)
        stop = threading.Event()
        poller = None
        if poll_truth:

            def poll() -> None:
                with ControlClient(e.control) as client:
                    while not stop.is_set():
                        run.history.append(client.truth())
                        stop.wait(0.01)

            poller = threading.Thread(target=poll, daemon=True)
            poller.start()
        try:
            run.result = runner.run({p["socket"]: p["serial"] for p in parts})
        finally:
            stop.set()
            if poller is not None:
                poller.join(5)
        run.final_truth = bench.control.truth()
    return run


def truth_series(
    history: list[dict[str, Any]], socket: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(world time, die temperature, chamber air) from polled truth."""
    t = np.array([h["time_s"] for h in history])
    die = np.array([h["sockets"][str(socket)].get("die_temp_c", np.nan) for h in history])
    air = np.array([h["chamber"].get("air_c", h["chamber"].get("temp_c", np.nan)) for h in history])
    return t, die, air


@pytest.fixture
def out_dir(tmp_path: Path) -> Path:
    return tmp_path / "runs"
