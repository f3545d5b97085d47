"""Schema 4: three-axis parts in the results database and the lot report. A database at
schema 3 upgrades with every row kept (single-axis runs read axes = 1 and have no
elements); a three-axis record's calibration is indexed element by element, kept through a
crash mark, and the lot report gets lines per axis (a single-axis lot gets none)."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
import sqlalchemy as sa

from procedures.runtime.record import RunRecord
from reports.lot_report import build_lot
from reports.lot_three_axis import element_lines
from station.db.connect import HEAD_REVISION, MIGRATIONS, dispose_all
from station.results_db import ResultsDB
from tests.linedb.linekit import as_three_axis
from tests.reports.synth_run import Part, make_record

QUANTITIES = ("bias_dps", "matrix", "g_sensitivity_dps_per_mps2", "bias_temp_coeff_dps_per_c",
              "bias_supply_coeff_dps_per_v", "scale_temp_coeff_per_c",
              "scale_supply_coeff_per_v")


@pytest.fixture(autouse=True)
def _dispose() -> None:
    yield
    dispose_all()


def _three_axis(serial: str, shift: float) -> RunRecord:
    record = make_record(Part(serial=serial, product="IMU-3 three-axis gyroscope"))
    return as_three_axis(record, shift, QUANTITIES)


def _schema3_file(path: Path) -> None:
    from alembic import command
    from alembic.config import Config

    engine = sa.create_engine(f"sqlite:///{path}")
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    with engine.begin() as con:
        cfg.attributes["connection"] = con
        command.upgrade(cfg, "0003")
    engine.dispose()


def test_schema3_database_upgrades_with_its_runs_kept(tmp_path: Path) -> None:
    path = tmp_path / "results.sqlite"
    _schema3_file(path)
    assert HEAD_REVISION == "0007"
    con = sqlite3.connect(path)
    assert "calibration_elements" not in {
        r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    con.close()
    # a schema-3 station writes a run (the schema-3 columns only), then is upgraded
    from station.db.store import run_row

    old = make_record(Part(serial="OLD-0001"))
    row = {k: v for k, v in run_row(tmp_path / old.run_id, old).items()
           if k not in ("axes", "socket")}
    engine = sa.create_engine(f"sqlite:///{path}")
    with engine.begin() as c:
        c.execute(sa.text(f"INSERT INTO runs ({', '.join(row)}) VALUES "
                          f"({', '.join(':' + k for k in row)})"), row)
    engine.dispose()
    db = ResultsDB(path)
    (run,) = db.runs()
    assert (run.run_id, run.axes, run.calibration["bias_dps"]) == (
        old.run_id, 1, old.calibration.bias_dps.value)
    assert db.calibration_elements() == []


def test_three_axis_run_indexed_element_by_element(tmp_path: Path) -> None:
    db = ResultsDB(tmp_path / "results.sqlite")
    single = make_record(Part(serial="SGL-0001"))
    three = _three_axis("IMU-0001", 0.0)
    db.add_run(tmp_path / single.run_id, single)
    db.add_run(tmp_path / three.run_id, three)
    by_id = {r.run_id: r for r in db.runs()}
    assert by_id[single.run_id].axes == 1 and by_id[three.run_id].axes == 3
    elements = db.calibration_elements()
    assert len(elements) == 5 * 3 + 2 * 9 and {e.run_id for e in elements} == {three.run_id}
    m_yz = [e for e in elements if (e.quantity, e.axis, e.column_axis) == ("matrix", "y", "z")]
    assert m_yz[0].value == pytest.approx(1 + 0.005)  # row y, column z of arange * 1e-3 + 1
    db.mark_error(three.run_id, "station stopped")
    assert len(db.calibration_elements()) == len(elements)  # kept through the mark


def test_lot_report_has_lines_per_axis_for_three_axis_parts_only(tmp_path: Path) -> None:
    db = ResultsDB(tmp_path / "results.sqlite")
    records = [_three_axis(f"IMU-{i:04d}", 0.01 * i) for i in range(3)]
    for r in records:
        db.add_run(tmp_path / r.run_id, r)
    lines = {name: (n, mean, sigma) for name, _u, n, mean, sigma, _uk in
             element_lines(db.calibration_elements(), db.runs())}
    assert set(lines) >= {"b_x", "b_y", "b_z", "M_xx", "M_zy", "G_yz", "sT_z", "bV_x"}
    n, mean, sigma = lines["b_y"]
    assert (n, mean, sigma) == (3, pytest.approx(0.001 + 0.01), pytest.approx(0.01))
    story, _summary, _furniture = build_lot(db, include_simulated=True)  # simulated parts
    texts = [getattr(f, "text", "") for f in story]
    assert "Three-axis calibration written, per axis" in texts
    single_db = ResultsDB(tmp_path / "single.sqlite")
    one = make_record(Part(serial="SGL-0002"))
    single_db.add_run(tmp_path / one.run_id, one)
    story, _s, _f = build_lot(single_db, include_simulated=True)
    assert "Three-axis calibration written, per axis" not in [getattr(f, "text", "")
                                                             for f in story]
