"""Issue 26's discrepancy findings, each on data made here (a generated record, fake run
folders): the lag cache that lost columns when it filled up (finding 2), and the run folder
picked under a results folder when the newest run holds nothing to analyse (finding 14)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from fake_run_folder import write_run_folder
from helpers_model import TINY, as_trajectory
from synth_gyro import Part, generate

from procedures.model import fit
from procedures.model.discrepancy import run_discrepancy
from procedures.model.gyro_model import base_model
from procedures.model.run_folder import find_run_folder, unusable_reason
from procedures.runtime.rawdata import EXTRA_GROUPS, RawDataWriter
from procedures.runtime.record import Dut, FileRef, RunRecord, Verdict, write_record


def test_a_full_lag_cache_keeps_the_columns_of_the_solve_in_hand(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Finding 2: `KeyError: ('bias', (), 0.0100003...)` in `_lagged_block_columns` on a
    part with a sensor lag and several effects. The lag cache was cleared when full *after*
    the solve had found some of its columns in it, then read them back. With the cache's
    bound at 2 entries every lagged solve past the first fills it."""
    monkeypatch.setattr(fit, "LAG_CACHE_ENTRIES", 2)
    part = Part().with_effect("sensor_lag", tau_s=0.01).with_effect("k2_quadratic")
    traj = as_trajectory(generate(part, 3, TINY))
    result = run_discrepancy(traj, base_model(), use_library=False)
    assert "sensor_lag" in result.effects_added


def _error_run(folder: Path, serial: str) -> Path:
    """A run folder as a run that ended in ERROR before it measured anything leaves it: a
    record with verdict ERROR, a raw data file with no samples and no windows."""
    folder.mkdir(parents=True)
    with RawDataWriter(folder / "raw.h5", {"serial": serial, "run_id": "r2"}):
        pass
    ref = FileRef(path="x", sha256="0" * 64)
    write_record(folder, RunRecord(run_id="r2", verdict=Verdict.ERROR,
                                   started_utc="2026-01-05T00:00:00Z", dut=Dut(serial=serial),
                                   product=ref, procedure=ref))
    return folder


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """SIM-0001 measured twice, then a third run that ended in ERROR with no samples."""
    root = tmp_path_factory.mktemp("res") / "results"
    first = write_run_folder(root / "20260102T000000Z_SIM-0001", generate(Part(), 5, TINY),
                             serial="SIM-0001")
    shutil.copytree(first, root / "20260103T090000Z_SIM-0001")
    _error_run(root / "20260104T080000Z_SIM-0001", "SIM-0001")
    return root


def test_the_newest_usable_run_folder_is_picked_and_the_skipped_one_named(
    results: Path,
) -> None:
    """Finding 14: `station discrepancy runs --dut X` took the newest folder even when it
    was an ERROR run with no samples (then failed on it); now the newest usable one is
    used and the note says which was skipped and why."""
    assert unusable_reason(results / "20260104T080000Z_SIM-0001") == "verdict ERROR, 0 samples"
    assert unusable_reason(results / "20260103T090000Z_SIM-0001") is None
    choice = find_run_folder(results, "SIM-0001")
    assert choice.folder.name == "20260103T090000Z_SIM-0001"
    assert choice.note == (
        "3 run folders for SIM-0001; the newest usable one, 20260103T090000Z_SIM-0001, was "
        "used; skipped, newer but with nothing to analyse: 20260104T080000Z_SIM-0001 "
        "(verdict ERROR, 0 samples)")


def test_cli_uses_the_newest_usable_run_and_says_so(results: Path, tmp_path: Path) -> None:
    from station.cli import main as cli

    out = tmp_path / "out"
    code = cli.main(["discrepancy", str(results), "--dut", "SIM-0001", "--out", str(out)])
    assert code == 0
    data = json.loads((out / "discrepancy.json").read_text())
    assert data["run_folder"].endswith("20260103T090000Z_SIM-0001")
    assert "skipped, newer but with nothing to analyse: 20260104T080000Z_SIM-0001" in (
        data["notes"][0])


def test_no_usable_run_folder_is_one_line_naming_each(tmp_path: Path) -> None:
    root = tmp_path / "results"
    _error_run(root / "20260104T080000Z_SIM-0009", "SIM-0009")
    with pytest.raises(ValueError, match=r"no run folder of SIM-0009 holds data to analyse: "
                       r"20260104T080000Z_SIM-0009 \(verdict ERROR, 0 samples\); run the "
                       r"part again"):
        find_run_folder(root, "SIM-0009")


def test_a_three_axis_run_that_ended_before_its_fit_is_refused_not_read_as_one_axis(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Found by the journey (tests/journeys/test_discrepancy.py): a three-axis run that
    ended in ERROR before its fit has no three-axis block in its record, so it was analysed
    as a single-axis part (its x axis against the table with the cube turning: a 24 deg/s
    gap and a scale term named). Its raw data's per-axis samples now mark it three-axis: it
    is refused with one line, and under a results folder it is skipped."""
    import h5py

    from station.cli import main as cli

    folder = write_run_folder(tmp_path / "results" / "20260102T000000Z_IMU-0001",
                              generate(Part(), 5, TINY), serial="IMU-0001")
    with h5py.File(folder / "raw.h5", "a") as f:  # the per-axis samples, x = /samples
        n = f["samples/time_s"].shape[0]
        g = f.create_group("samples_xyz")
        for name, (dtype, _units) in EXTRA_GROUPS["samples_xyz"].items():
            g.create_dataset(name, data=f["samples/rate_dps"][()] if name == "rate_x_dps"
                             else np.zeros(n, dtype=dtype))
    assert cli.main(["discrepancy", str(folder), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "a three-axis run without its fit (verdict PASS" in err[0]
    assert not (tmp_path / "out").exists()
    assert unusable_reason(folder) == "verdict PASS, a three-axis run that ended before its fit"
