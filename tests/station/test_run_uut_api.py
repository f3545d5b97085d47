"""The UutRunner API the browser UI uses: start in the background, state, progress, abort."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from drivers.sim.launcher import launch_bench
from procedures.runtime.progress import ProgressEvent
from procedures.runtime.record import Verdict, read_record
from station.endpoints import Endpoints
from station.errors import UserError
from station.station_file import load_settings
from station.uut import UutRunner

ROOT = Path(__file__).resolve().parents[2]
SHORT = ROOT / "tests/procedures/data/short.yaml"


def test_start_state_abort_wait(tmp_path: Path) -> None:
    with launch_bench(
        config={
            "parts": [{"socket": 1, "serial": "SIM-0601"}, {"socket": 2, "serial": "SIM-0602"}]
        },
        speed=100,
        sockets=2,
    ) as bench:
        e = bench.endpoints
        runner = UutRunner(
            load_settings(),
            procedure_path=SHORT,
            out=tmp_path / "runs",
            endpoints=Endpoints.of_bench(e),
            certificate=False,
        )
        with pytest.raises(UserError, match="does not match the product"):
            runner.start({1: "SIM-06011"})
        in_bias = threading.Event()
        events: list[ProgressEvent] = []

        def watch(ev: ProgressEvent) -> None:
            events.append(ev)
            if ev.kind == "step" and ev.step == "bias":
                in_bias.set()

        runner.progress.subscribe(watch)
        runner.start({1: "SIM-0601", 2: "SIM-0602"})
        assert in_bias.wait(60)
        state = runner.state()
        assert state["state"] == "running" and state["step"] == "bias"
        assert state["sockets"] == {1: "RUNNING", 2: "RUNNING"}
        assert runner.context is not None and len(runner.context.parts.alive()) == 2
        with pytest.raises(UserError, match="already in progress"):
            runner.start({1: "SIM-0601"})
        t_abort = time.monotonic()
        runner.abort("operator pressed abort in the UI")
        result = runner.wait(60)
        assert time.monotonic() - t_abort < 10
        assert result is not None and result.verdicts == {1: Verdict.ABORTED, 2: Verdict.ABORTED}
        assert result.exit_code == 2
        safe = bench.control.truth()["safe"]
        assert safe["all"], safe
        rec = read_record(result.folders[2])
        assert "operator pressed abort in the UI" in rec.reason
        assert runner.state()["state"] == "finished" and runner.context is None
        assert events[-1].kind == "finished"
        fractions = [ev.fraction for ev in events]
        assert fractions == sorted(fractions) and 0 < fractions[-1] < 0.5
