"""The parts of a run: one socket's part (`PartRun`), its results per condition, its row buffer.

These are the data a step works on; `procedures.runtime.run_context` holds the helpers that wait,
log, record and publish around them.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from common.clock import ScaledClock
from drivers.protocols import Chamber, Inclinometer, PartLink, RateTable, Supply
from procedures.analysis.allan import NoiseModel
from procedures.analysis.rate_table import RateTableFit
from procedures.analysis.temp_supply_fit import FirstOrderCoefficients
from procedures.analysis.three_axis import ThreeAxisCalibration, Window
from procedures.runtime.rawdata import RawDataWriter
from procedures.runtime.record import ConditionRecord, RunRecord, StorageError, Verdict
from procedures.runtime.streams import PartStream
from procedures.thermal.thermal_control import PartThermal

log = logging.getLogger(__name__)


@dataclass
class Bench:
    """The instruments of one run (shared by every socket) and the station clock."""

    chamber: Chamber
    supply: Supply
    links: dict[int, PartLink]
    clock: ScaledClock
    table: RateTable | None = None
    inclinometer: Inclinometer | None = None  # a fixture's angle at a stop (manual_stop)


@dataclass(frozen=True)
class StopScale:
    """The stop method's scale at one condition (steps stop, manual_stop), k=1."""

    scale: float
    u_scale: float
    bias_dps: float
    reference_angle_deg: float
    u_reference_angle_deg: float


class ProgrammableFit(Protocol):
    """What the fit step leaves in `PartRun.fit` for the program step (procedures.steps.fit
    CombinedFit, procedures.steps.fit_order HigherOrderFit)."""

    @property
    def coefficients(self) -> FirstOrderCoefficients: ...

    @property
    def registers_beyond_first_order(self) -> dict[str, float]: ...


@dataclass(frozen=True)
class KeptRecord:
    """Where the run's end wrote record.json (None: nowhere; procedures.runtime.record
    .save_record_anywhere)."""

    path: Path | None


@dataclass
class ConditionResult:
    """What one part measured at one condition (engineering units, k=1 uncertainties)."""

    name: str
    temperature_c: float
    supply_v: float
    die_temperature_c: float | None = None
    supply_measured_v: float | None = None
    supply_current_a: float | None = None
    time_to_stability_s: float | None = None
    stable: bool | None = None
    bias_dps: float | None = None
    u_bias_dps: float | None = None
    table_fit: RateTableFit | None = None
    # die temperature over the measurement windows: the bias and the scale are each paired
    # with the temperature of their own windows (the die may still creep within a condition)
    temp_sums: dict[str, tuple[float, int]] = field(default_factory=dict)
    # per kind: the sum of each timed window's die slope (C/s) x its samples, and those samples
    slope_sums: dict[str, tuple[float, int]] = field(default_factory=dict)
    # the hysteresis state when the bias was measured (+1 reached by heating, -1 by cooling;
    # None: the product declares no hysteresis; procedures.analysis.hysteresis)
    hysteresis_state: float | None = None

    def note_temperature(self, kind: str, temp_c: Any, time_s: Any = None) -> None:
        """Add a window's die temperatures to `kind` ("bias" or "scale"); with the window's
        sample times, its slope too (the sensing element lags the sensor by the slope x its
        lag: `temperature_for`)."""
        arr = np.asarray(temp_c, dtype=np.float64)
        if arr.size:
            total, n = self.temp_sums.get(kind, (0.0, 0))
            self.temp_sums[kind] = (total + float(arr.sum()), n + int(arr.size))
            all_sum = sum(v[0] for v in self.temp_sums.values())
            all_n = sum(v[1] for v in self.temp_sums.values())
            self.die_temperature_c = all_sum / all_n
        t = None if time_s is None else np.asarray(time_s, dtype=np.float64)
        if t is not None and arr.size >= 3 and t.size == arr.size and np.ptp(t) > 0:
            slope = float(np.polyfit(t - t[0], arr, 1)[0])
            total, n = self.slope_sums.get(kind, (0.0, 0))
            self.slope_sums[kind] = (total + slope * arr.size, n + int(arr.size))

    def temperature_for(self, kind: str, lag_s: float = 0.0) -> float | None:
        """The die temperature of `kind`'s windows; with `lag_s`, carried to where a sensing
        element lagging the sensor by `lag_s` (first order) is: less the slope x lag."""
        if kind not in self.temp_sums:
            return self.die_temperature_c
        total, n = self.temp_sums[kind]
        return total / n - lag_s * self.slope_for(kind)

    def slope_for(self, kind: str) -> float:
        """The die's mean slope over `kind`'s timed windows, C/s (0 when none was timed)."""
        total, n = self.slope_sums.get(kind, (0.0, 0))
        return total / n if n else 0.0

    stop: StopScale | None = None


class RowBuffer:
    """Rows for raw.h5's small groups (table, chamber, supply, segments, events), written in
    batches (end of each step, and every 2 wall s): an HDF5 flush per row costs wall time,
    which the simulated bench's fast clock turns into minutes of station time."""

    def __init__(self, writer: RawDataWriter | None) -> None:
        self.writer = writer
        self._rows: dict[str, list[dict[str, Any]]] = {}
        self._last_flush_wall = time.monotonic()

    def flush_if_due(self, every_wall_s: float = 2.0) -> None:
        """Flush when rows have waited `every_wall_s` (a killed run loses at most that)."""
        if self._rows and time.monotonic() - self._last_flush_wall > every_wall_s:
            self.flush()

    def append(self, group: str, **columns: Any) -> None:
        if self.writer is not None:
            self._rows.setdefault(group, []).append(columns)

    def flush(self) -> None:
        if self.writer is None:
            return
        rows, self._rows = self._rows, {}
        self._last_flush_wall = time.monotonic()
        for group, items in rows.items():
            merged = {k: [row[k] for row in items] for k in items[0]}
            try:
                self.writer.append(group, **merged)
            except StorageError:  # the writer keeps it; the run's next check ends the run
                return
            except Exception:  # never lose a run over a log row
                log.exception("could not write %d rows to raw data group %s", len(items), group)


@dataclass
class PartRun:
    """One socket's part: its record, data file, stream and state."""

    socket: int
    serial: str
    folder: Path
    record: RunRecord
    writer: RawDataWriter | None = None
    stream: PartStream | None = None
    alive: bool = True
    verdict: Verdict | None = None
    reason: str = ""
    conditions: dict[str, ConditionResult] = field(default_factory=dict)
    fit: ProgrammableFit | None = None
    noise: NoiseModel | None = None  # from the bias step, floored; later windows use it
    stop_angle: tuple[float, float] | None = None  # the fixture's, deg, and its k=1 u
    power_on_station_s: float | None = None  # when the part was last powered on
    kept: KeptRecord | None = None  # set when the run's end wrote the record
    unasked_sockets: int = 0  # sockets the bench has but nobody scanned (step power)
    cube_face: str | None = None  # the face up on the cube fixture (step cube)
    three_axis_windows: list[Window] = field(default_factory=list)  # step cube
    three_axis_fit: ThreeAxisCalibration | None = None  # step fit_three_axis
    rows: RowBuffer = field(default_factory=lambda: RowBuffer(None))
    # set when the part failed a limit: what it failed (it is then never programmed)
    failed_limits: list[str] = field(default_factory=list)
    # what the `fastest` thermal strategy learned of it from its own sensor, condition to condition
    thermal: PartThermal = field(default_factory=PartThermal)

    def __post_init__(self) -> None:
        self.rows = RowBuffer(self.writer)

    @property
    def link(self) -> PartLink:
        assert self.stream is not None
        return self.stream.link


def condition_record(result: ConditionResult) -> ConditionRecord:
    fit = result.table_fit
    stop = result.stop
    return ConditionRecord.model_validate(
        dict(
            name=result.name,
            temperature_c=result.temperature_c,
            supply_v=result.supply_v,
            die_temperature_c=result.die_temperature_c,
            time_to_stability_s=result.time_to_stability_s,
            stable=result.stable,
            bias_dps=result.bias_dps,
            bias_uncertainty_dps=None if result.u_bias_dps is None else 2 * result.u_bias_dps,
            scale_table=None if fit is None else fit.scale,
            scale_table_uncertainty=None if fit is None else 2 * fit.u_scale,
            scale_stop=None if stop is None else stop.scale,
            scale_stop_uncertainty=None if stop is None else 2 * stop.u_scale,
            supply_current_a=result.supply_current_a,
            supply_measured_v=result.supply_measured_v,
        )
    )
