"""One UUT cycle on a freshly started simulated bench (benchmarks, tests and the twin runs
of `station discrepancy --simulate`)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from procedures.loading.config import load_procedure
from procedures.runtime.progress import ProgressEvent
from station.endpoints import Endpoints
from station.settings import LoadedSettings
from station.uut import UutResult, UutRunner

log = logging.getLogger(__name__)


def run_simulated(
    parts: list[dict[str, Any]],
    *,
    procedure_path: Path | None = None,
    out: Path,
    speed: float | None = None,
    settings: LoadedSettings | None = None,
    certificate: bool = False,
    on_progress: Callable[[ProgressEvent], None] | None = None,
    sim_config: dict[str, Any] | None = None,
    part_effects: dict[int, tuple[str, ...]] | None = None,
) -> tuple[UutResult, dict[str, Any]]:
    """One UUT cycle on a freshly started simulated bench holding `parts` (sim config
    entries); returns the result and the bench's truth at the end (for benchmarks and tests).
    Without `speed` the bench runs in lockstep (station time is physics time); `sim_config`
    adds sim config keys besides the parts (e.g. `part_physics: {thermal: {mode: ideal}}`);
    `part_effects` declares, per socket, the effects the part there carries (a model's twin):
    its record and certificate name them."""
    from drivers.sim.launcher import launch_bench
    from station.station_file import load_settings

    sockets = max(int(p["socket"]) for p in parts)
    settings = settings or load_settings()
    # the procedure's step modules import while the bench process starts (seconds of each)
    warm = threading.Thread(
        target=_warm_up, args=(procedure_path or settings.procedure,), daemon=True
    )
    warm.start()
    with launch_bench(
        config={**(sim_config or {}), "parts": parts},
        speed=speed,
        sockets=sockets,
        lockstep=speed is None,
    ) as bench:
        warm.join()
        runner = UutRunner(
            settings,
            procedure_path=procedure_path,
            out=out,
            endpoints=replace(Endpoints.of_bench(bench.endpoints),
                              part_effects=dict(part_effects or {})),
            certificate=certificate,
            operator="benchmark",
        )
        if on_progress is not None:
            runner.progress.subscribe(on_progress)
        result = runner.run({int(p["socket"]): str(p["serial"]) for p in parts})
        truth = bench.control.truth()
    return result, truth


def _warm_up(procedure_path: Path) -> None:
    """Load the procedure once, for its imports (UutRunner loads it again and reports any
    error in it)."""
    try:
        load_procedure(Path(procedure_path))
    except Exception:  # noqa: BLE001 - reported by the runner's own load
        log.debug("warm-up load of %s failed", procedure_path, exc_info=True)
