"""The discrepancy workflow per axis on a three-axis part's full station run (the bench's
eol-three-axis procedure, lockstep): with the run's own fit taking out the cross-axis terms and
g-sensitivity, each axis is a single-axis gyro. The bench's three-axis part is first-order
(docs/three-axis.md), so from the first-order model nothing is named on any axis; a warm-up
drift hidden in axis y's output only is named on y, and on neither x nor z.
`station discrepancy` on the folder writes one section per axis.

Effects that couple the axes (procedures/model/cross_axis.py): a cross-coupling drifting
with temperature and a g-squared cross term, each on one pair of axes only, are named on
the axis they act on with the axes they couple, and on no other axis; once hidden in a copy
of the first-order part's raw data (cheap), once through the bench's own physics
(drivers/sim/cross_axis.py) in one station run of two parts."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from drivers.orientation import up_vector
from procedures.model.discrepancy import DiscrepancyResult, run_discrepancy
from procedures.model.gyro_model import first_order_model
from procedures.model.output import result_to_json
from procedures.model.run_folder_xyz import AXES, load_axis
from procedures.runtime.record import read_record
from station.sim_run import run_simulated

pytestmark = [pytest.mark.slow, pytest.mark.station_grid]

ROOT = Path(__file__).resolve().parents[2]
PROCEDURE = ROOT / "config/procedures/eol-three-axis.yaml"
# a warm-up drift on axis y: 0.05 deg/s decaying over 10 min (about 2.5 x the noise floor)
WARMUP_DPS = 0.05
WARMUP_TAU_S = 600.0
# the cross-axis effects: 20 ppm/C of the rate along one axis into another (0.04 deg/s at
# 100 deg/s and 20 C), and 3e-4 deg/s per (m/s^2)^2 (0.03 deg/s at 1 g)
CROSS_C_PER_C = 2e-5
CROSS_Q = 3e-4


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


def _matrix(target: str, source: str, value: float) -> list[list[float]]:
    m = [[0.0] * 3 for _ in range(3)]
    m[AXES.index(target)][AXES.index(source)] = value
    return m


@pytest.fixture(scope="module")
def crossed_folders(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One station run of two parts: a cross-coupling drifting with temperature y <- x on
    the first part (the null folder's serial), a g-squared cross term z <- y on the second."""
    out = tmp_path_factory.mktemp("three-axis-crossed")
    parts = [
        {"socket": 1, "serial": "IMU-0301",
         "three_axis": {"cross_temp_coeff_per_c": _matrix("y", "x", CROSS_C_PER_C)}},
        {"socket": 2, "serial": "IMU-0302",
         "three_axis": {"g2_cross_dps_per_mps2_sq": _matrix("z", "y", CROSS_Q)}},
    ]
    result, _truth = run_simulated(parts, procedure_path=PROCEDURE, out=out)
    return {"w_dT": result.folders[1], "a2": result.folders[2]}


def _hide_cross(folder: Path, dest: Path, kind: str, target: str, source: str) -> Path:
    """A copy of the run folder with a cross-axis effect added to axis `target`'s samples:
    C dT w_source (w from the fit's windows: the table rate along the face up) or
    Q a_source^2 (the accelerometer's reading)."""
    shutil.copytree(folder, dest)
    k = AXES.index(source)
    windows = [w for w in read_record(folder).analysis.three_axis_windows or []
               if w.start_s is not None and w.end_s is not None and w.table_rate_dps]
    with h5py.File(dest / "raw.h5", "r+") as f:
        t = f["samples/time_s"][()]
        if kind == "w_dT":
            w = np.zeros(t.size)
            for win in windows:
                inside = (t >= win.start_s) & (t <= win.end_s)
                w[inside] = float(win.table_rate_dps) * up_vector(win.face)[k]
            add = CROSS_C_PER_C * (f["samples/temp_c"][()] - 25.0) * w
        else:
            add = CROSS_Q * f[f"samples_xyz/accel_{source}_mps2"][()] ** 2
        f[f"samples_xyz/rate_{target}_dps"][...] += add
    return dest


def _results(folder: Path) -> dict[str, DiscrepancyResult]:
    return {a: run_discrepancy(load_axis(folder, a), first_order_model()) for a in AXES}


def _check_named_on_one_axis(res: dict[str, DiscrepancyResult], kind: str, target: str,
                             source: str, truth: float, rtol: float) -> None:
    named = {a: r.effects_added for a, r in res.items()}
    effect = f"lib_{target}from{source}_{kind}"
    assert named == {a: [effect] if a == target else [] for a in AXES}, named
    it = result_to_json(res[target])["iterations"][0]
    assert it["couples"] == f"{target} <- {source}"
    assert it["formula"].startswith(f"couples {target} <- {source}: ")
    assert f"{'rate' if kind == 'w_dT' else 'accel'}_{source}" in it["regressors"]
    assert it["parameters"]["coeff"] == pytest.approx(truth, rel=rtol)


@pytest.mark.parametrize(("kind", "target", "source", "truth"),
                         [("w_dT", "x", "z", CROSS_C_PER_C), ("a2", "y", "z", CROSS_Q)])
def test_a_cross_axis_effect_hidden_on_one_pair_is_named_there_only(
    run_folder: Path, tmp_path: Path, kind: str, target: str, source: str, truth: float
) -> None:
    hidden = _hide_cross(run_folder, tmp_path / "hidden", kind, target, source)
    _check_named_on_one_axis(_results(hidden), kind, target, source, truth, rtol=0.25)


@pytest.mark.parametrize(("kind", "target", "source", "truth"),
                         [("w_dT", "y", "x", CROSS_C_PER_C), ("a2", "z", "y", CROSS_Q)])
def test_the_bench_s_cross_axis_physics_is_named_on_its_pair_only(
    crossed_folders: dict[str, Path], kind: str, target: str, source: str, truth: float
) -> None:
    """The part's own physics: the run's fit took up the effect's average (a constant
    cross-coupling, a linear g-sensitivity), the term's own columns what it left."""
    _check_named_on_one_axis(_results(crossed_folders[kind]), kind, target, source, truth,
                             rtol=0.35)
