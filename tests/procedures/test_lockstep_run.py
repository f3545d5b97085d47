"""Lockstep on the simulated bench: station time is physics time, whatever the machine load."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from procedures.runtime.record import Verdict, read_record
from station.sim_run import run_simulated

LOCKSTEP_PROC = Path(__file__).resolve().parent / "data" / "lockstep.yaml"
HOG = (
    "import os, time\nos.nice(5)\nend = time.monotonic() + 600\n"
    "while time.monotonic() < end:\n    pass\n"
)


def run_once(out: Path) -> tuple[float, float, Verdict]:
    result, truth = run_simulated(
        [{"socket": 1, "serial": "SIM-8101"}], procedure_path=LOCKSTEP_PROC, out=out
    )
    record = read_record(result.folders[1])
    return float(record.timings["total"]), float(truth["time_s"]), record.verdict


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_the_same_run_takes_the_same_station_time_beside_a_cpu_hog(tmp_path: Path) -> None:
    quiet_total_s, quiet_world_s, quiet_verdict = run_once(tmp_path / "quiet")
    hogs = [subprocess.Popen([sys.executable, "-c", HOG])]
    try:
        busy_total_s, busy_world_s, busy_verdict = run_once(tmp_path / "busy")
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
    assert quiet_verdict == busy_verdict == Verdict.PASS
    assert busy_total_s == pytest.approx(quiet_total_s, rel=0.01)
    # pinned: timings.total is the run's station seconds, and in lockstep station time is the
    # bench's world time (the world moved only while the station waited)
    assert quiet_total_s == pytest.approx(quiet_world_s, rel=0.01)
    assert busy_total_s == pytest.approx(busy_world_s, rel=0.01)
    assert quiet_total_s > 300  # the thermal and measurement waits are in it
