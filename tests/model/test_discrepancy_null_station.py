"""Null through the station (issue 29): run folders of `station run --sim` with the parts'
thermal physics off (`part_physics: {thermal: {mode: ideal}}`) hold nothing the first-order
model lacks, so the workflow names nothing, reports nothing not separable and leaves the gap
within 1.5 x the noise floor.

Six population parts (each its own serial: its own noise and first-order terms) in one
six-socket run of a small procedure (tests/model/data/eol-discrepancy-null.yaml: 25/30 C x
two supplies, six rates, stop method, 50 Hz), the bench in lockstep (`station run --sim`'s
default: station time is physics time whatever the load). About 30 s for the station run and
1 s of workflow per folder on the 2-core machine.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from procedures.model.discrepancy import UNEXPLAINED_GAP_RATIO, run_discrepancy
from procedures.model.gyro_model import first_order_model
from procedures.model.run_folder import load_data
from procedures.runtime.record import read_record

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
PROCEDURE = Path(__file__).resolve().parent / "data" / "eol-discrepancy-null.yaml"
STATION = Path(sys.executable).parent / "station"  # the installed console script
SERIALS = [f"SIM-{2911 + i}" for i in range(6)]


@pytest.fixture(scope="module")
def run_folders(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    work = tmp_path_factory.mktemp("null-station")
    cfg = work / "sim.yaml"
    cfg.write_text(yaml.safe_dump({
        "part_physics": {"thermal": {"mode": "ideal"}},
        "fixture": {"sockets": len(SERIALS)},
        "parts": [{"socket": i + 1, "serial": s} for i, s in enumerate(SERIALS)],
    }))
    out = work / "runs"
    args = [str(STATION), "run", "--sim", "--sim-config", str(cfg),
            "--procedure", str(PROCEDURE), "--out", str(out)]
    for s in SERIALS:
        args += ["--dut", s]
    done = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert done.returncode in (0, 1), (done.stdout + done.stderr)[-2000:]  # PASS or FAIL
    folders = {s: sorted(out.glob(f"*_{s}"))[-1] for s in SERIALS}
    for folder in folders.values():
        assert read_record(folder).verdict in ("PASS", "FAIL"), folder
    return folders


@pytest.mark.parametrize("serial", SERIALS)
def test_an_ideal_part_through_the_station_names_nothing(run_folders: dict[str, Path],
                                                         serial: str) -> None:
    traj = load_data(run_folders[serial], dut=serial)
    assert traj.n > 50_000
    res = run_discrepancy(traj, first_order_model())
    assert res.effects_added == [], [it.evidence for it in res.iterations]
    assert res.not_separable == ()
    assert res.gap_final_dps <= UNEXPLAINED_GAP_RATIO * res.noise_floor_dps
    assert not res.unexplained_remains
