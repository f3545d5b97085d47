"""The rows of the results database the lot reports read, and what they read them through.

The station's results database (station/results_db.py) makes these rows; the reports only
read them, through `LotRows`, so that reports never import the station (dependencies run
one way: station -> reports -> procedures -> drivers).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol


class LotRows(Protocol):
    """What a lot report reads from a results database (station.results_db.ResultsDB): its
    name, and the runs, measurements and three-axis elements matching keyword filters
    (since, until, product, verdict, serial, lot, work_order)."""

    @property
    def path(self) -> Path | str: ...

    @property
    def runs(self) -> Callable[..., list[RunRow]]: ...

    @property
    def measurement_values(self) -> Callable[..., list[MeasurementRow]]: ...

    @property
    def calibration_elements(self) -> Callable[..., list[CalibrationElement]]: ...


@dataclass(frozen=True)
class RunRow:
    run_id: str
    serial: str
    product: str
    verdict: str
    reason: str
    failed_measurements: tuple[str, ...]
    simulated: bool
    started_utc: str
    finished_utc: str | None
    station_id: str
    operator: str
    software_version: str
    procedure_name: str
    procedure_sha256: str
    folder: str
    calibration: dict[str, float | None]  # coefficient key -> value (None when not written)
    work_order: str = ""
    lot: str = ""
    attempt: int = 1  # 1 for a serial's first test, 2 for its first retest, ...
    first_run_id: str = ""  # the run_id of the serial's first test
    axes: int = 1  # 3: a three-axis part (its calibration: ResultsDB.calibration_elements)
    socket: int = 0  # the fixture socket the part sat in; 0 when not recorded (schema < 5)


@dataclass(frozen=True)
class MeasurementRow:
    run_id: str
    serial: str
    started_utc: str
    verdict: str
    name: str
    condition: str | None
    value: float | None
    units: str
    low: float | None
    high: float | None
    outcome: str


@dataclass(frozen=True)
class CalibrationElement:
    """One element of a three-axis calibration (schema 4's calibration_elements)."""

    run_id: str
    serial: str
    quantity: str  # bias_dps, matrix, g_sensitivity_dps_per_mps2, ...
    axis: str  # x, y, z: the output axis (a matrix's row)
    column_axis: str | None  # a matrix's column; None for a vector
    value: float | None
    uncertainty_k2: float | None
