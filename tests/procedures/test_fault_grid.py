"""The fault x step grid on the simulated bench (see fault_grid.py for what a correct cell is).

The whole grid carries the `fault_grid` marker (`pytest -m fault_grid`); a representative
subset, one cell per mechanism, runs in the default test run.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from .fault_grid import REPRESENTATIVE, grid_cells, run_cell


def _check(fault_id: str, step: str, tmp_path: Path) -> None:
    cell = run_cell(fault_id, step, tmp_path / "runs")
    assert cell.correct, cell.problems
    if not cell.all_safe:  # the station must say so: in the record and on page one
        assert any(not ok for ok in cell.station_safe.values())
        assert "SAFE STATE FAILED" in cell.reason


@pytest.mark.slow
@pytest.mark.parametrize(("fault_id", "step"), REPRESENTATIVE)
def test_representative_cell(fault_id: str, step: str, tmp_path: Path) -> None:
    _check(fault_id, step, tmp_path)


@pytest.mark.fault_grid
@pytest.mark.parametrize(("fault_id", "step"), grid_cells())
def test_grid_cell(fault_id: str, step: str, tmp_path: Path) -> None:
    _check(fault_id, step, tmp_path)
