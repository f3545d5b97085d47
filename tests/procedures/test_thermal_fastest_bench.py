"""On the simulated bench (lockstep clock): the `fastest` thermal strategy brings the part's
die to stability at the new temperature sooner than `setpoint`, with the unchanged criterion
judged on the part's own sensor, and the run still passes."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from procedures.runtime.record import Verdict, read_record
from station.sim_run import run_simulated

PROC = Path(__file__).resolve().parent / "data" / "thermal_fastest.yaml"


def run(proc: Path, out: Path) -> dict[str, dict[str, float]]:
    result, truth = run_simulated([{"socket": 1, "serial": "SIM-8301"}], procedure_path=proc,
                                  out=out)
    record = read_record(result.folders[1])
    assert record.verdict == Verdict.PASS
    assert truth["chamber"]["setpoint_c"] == 25.0  # the run's safe temperature at the end
    return {c: s.model_dump() for c, s in record.analysis.stability.items()}


@pytest.mark.station_grid
@pytest.mark.timeout(600)
def test_fastest_settles_sooner_than_setpoint_on_the_bench(tmp_path: Path) -> None:
    data = yaml.safe_load(PROC.read_text())
    data["chamber"]["strategy"] = "setpoint"
    data["product"] = str((PROC.parent / data["product"]).resolve())
    straight_proc = tmp_path / "setpoint.yaml"
    straight_proc.write_text(yaml.safe_dump(data))

    fast = run(PROC, tmp_path / "fast")["T35_V5.25"]
    straight = run(straight_proc, tmp_path / "straight")["T35_V5.25"]
    assert "strategy" not in straight  # setpoint records are as they were
    assert fast["strategy"] == "fastest" and fast["overshoot_c"] > 0.0
    assert fast["time_to_stability_s"] < 0.8 * straight["time_to_stability_s"]
    assert 200.0 < fast["die_tau_s"] < 400.0  # learned from the part's own sensor (bench: 300)
