"""The discrepancy workflow per axis on a three-axis part's full station run (the bench's
eol-three-axis procedure, lockstep): with the run's own fit taking out the cross-axis terms and
g-sensitivity, each axis is a single-axis gyro. The bench's three-axis part is first-order
(docs/three-axis.md), so from the first-order model nothing is named on any axis; a warm-up
drift hidden in axis y's output only is named on y, and on neither x nor z.
`station discrepancy` on the folder writes one section per axis."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from procedures.model.discrepancy import run_discrepancy
from procedures.model.gyro_model import first_order_model
from procedures.model.run_folder_xyz import AXES, load_axis
from station.sim_run import run_simulated

pytestmark = [pytest.mark.slow, pytest.mark.station_grid]

ROOT = Path(__file__).resolve().parents[2]
PROCEDURE = ROOT / "config/procedures/eol-three-axis.yaml"
# a warm-up drift on axis y: 0.05 deg/s decaying over 10 min (about 2.5 x the noise floor)
WARMUP_DPS = 0.05
WARMUP_TAU_S = 600.0


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("three-axis-run")
    result, _truth = run_simulated([{"socket": 1, "serial": "IMU-0301", "three_axis": {}}],
                                   procedure_path=PROCEDURE, out=out)
    assert str(result.verdicts[1]) in ("PASS", "FAIL", "Verdict.PASS", "Verdict.FAIL")
    return result.folders[1]


def _hide_on_y(folder: Path, dest: Path) -> Path:
    """A copy of the run folder with a warm-up drift added to axis y's samples only:
    A exp(-t / tau) from the first sample."""
    shutil.copytree(folder, dest)
    with h5py.File(dest / "raw.h5", "r+") as f:
        t = f["samples/time_s"][()]
        y = f["samples_xyz/rate_y_dps"][()]
        f["samples_xyz/rate_y_dps"][...] = y + WARMUP_DPS * np.exp(-(t - t.min()) / WARMUP_TAU_S)
    return dest


def _named(folder: Path, axis: str) -> list[str]:
    return run_discrepancy(load_axis(folder, axis), first_order_model()).effects_added


def test_nothing_is_named_on_a_first_order_part(run_folder: Path) -> None:
    assert {a: _named(run_folder, a) for a in AXES} == {"x": [], "y": [], "z": []}


def test_an_effect_hidden_on_one_axis_is_named_on_that_axis(
    run_folder: Path, tmp_path: Path
) -> None:
    hidden = _hide_on_y(run_folder, tmp_path / "hidden")
    named = {a: _named(hidden, a) for a in AXES}
    assert named["x"] == [] and named["z"] == [], named
    assert named["y"][:1] == ["warmup_drift"], named


def test_station_discrepancy_writes_one_section_per_axis(
    run_folder: Path, tmp_path: Path
) -> None:
    out = tmp_path / "disc"
    done = subprocess.run(
        [sys.executable, "-m", "station", "discrepancy", str(run_folder), "--model",
         "first_order", "--out", str(out)], capture_output=True, text=True, cwd=ROOT,
        timeout=600)
    assert done.returncode == 0, done.stderr
    payload = json.loads((out / "discrepancy.json").read_text())
    assert [a["axis"] for a in payload["axes"]] == ["x", "y", "z"]
    for a in AXES:
        assert (out / f"axis-{a}" / "model.yaml").is_file()
        assert (out / f"axis-{a}" / "discrepancy_report.pdf").is_file()
    assert "axis y:" in done.stdout
