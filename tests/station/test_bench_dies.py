"""A bench that dies mid-run: the run ends ERROR with the instrument and its reason.

The simulated bench's process is killed during a step (every instrument's link goes at once:
Modbus sockets reset, fixture and supply pseudo-terminals hang up). Whatever instrument the
engine touches first, the verdict's reason is that instrument's typed error with advice,
never "internal error ... report this" and never a bare OS error text alone.
"""

from __future__ import annotations

import os
import signal
import threading
from pathlib import Path
from typing import Any

import pytest

from drivers.sim.launcher import launch_bench
from procedures.runtime.record import Verdict, read_record
from station.endpoints import Endpoints
from station.station_file import load_settings
from station.uut import UutRunner

pytestmark = [pytest.mark.slow, pytest.mark.station_grid]
ROOT = Path(__file__).resolve().parents[2]
SHORT = ROOT / "tests/procedures/data/short.yaml"
INSTRUMENTS = ("rate table", "thermal chamber", "DC supply", "supply", "fixture")


@pytest.mark.parametrize("step", ["thermal", "rate_table", "stop_method", "verify"])
def test_bench_killed_mid_step_is_an_instrument_error(
    tmp_path: Path, step: str
) -> None:
    with launch_bench(config={"parts": [{"socket": 1, "serial": "SIM-0001"}]}, speed=50) as bench:
        runner = UutRunner(
            load_settings(),
            procedure_path=SHORT,
            out=tmp_path,
            endpoints=Endpoints.of_bench(bench.endpoints),
            certificate=False,
        )
        killed = threading.Event()

        def on_progress(ev: Any) -> None:
            if ev.kind == "step" and ev.step == step and not killed.is_set():
                killed.set()
                threading.Timer(0.2, os.kill, (bench.process.pid, signal.SIGKILL)).start()

        runner.progress.subscribe(on_progress)
        result = runner.run({1: "SIM-0001"})
    assert killed.is_set()
    reason = result.reasons[1]
    assert result.verdicts[1] is Verdict.ERROR, reason
    assert "internal error" not in reason and "report this" not in reason, reason
    assert any(name in reason for name in INSTRUMENTS), reason
    assert "check" in reason, reason  # says what to do
    record = read_record(result.folders[1])
    assert record.reason == reason and not (result.folders[1] / ".running").exists()
