"""The signal grid (see signal_grid.py for what a cell does and how it is judged): SIGTERM,
SIGINT, SIGHUP, SIGQUIT and a double SIGTERM, sent to a real `station run --sim` and a real
`station ui --sim` during a thermal ramp, a rate plateau, a stop-method move, programming
and the certificate rendering, and in the ramp calibration's own phases (the ramp record, the
static dwell, a stop move at a ramp end; a full disk during the ramp record); the bench's
truth read after the station exited.

The whole grid carries the `station_grid` marker (`pytest -m station_grid`, CI's long-grid
step); one cell per command runs in the default test run.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.station.signal_grid import REPRESENTATIVE, DiskUnavailable, grid_cells, run_cell


def _check(command: str, phase: str, sig: str, tmp_path: Path) -> None:
    try:
        cell = run_cell(command, phase, sig, tmp_path)
    except DiskUnavailable as exc:
        pytest.skip(str(exc))
    assert cell.correct, f"{cell.problems}\n{cell.output[-3000:]}"
    assert all(cell.truth_safe.values()) and set(cell.truth_safe) == {
        "rate_table", "supply", "chamber"}
    assert cell.sealed and cell.indexed and not cell.lock_left


@pytest.mark.slow
@pytest.mark.parametrize(("command", "phase", "sig"), REPRESENTATIVE)
def test_representative_cell(command: str, phase: str, sig: str, tmp_path: Path) -> None:
    _check(command, phase, sig, tmp_path)


@pytest.mark.station_grid
@pytest.mark.parametrize(("command", "phase", "sig"), grid_cells())
def test_grid_cell(command: str, phase: str, sig: str, tmp_path: Path) -> None:
    _check(command, phase, sig, tmp_path)
