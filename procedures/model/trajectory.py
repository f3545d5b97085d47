"""The reference trajectory and measured output of one record, in one typed object.

Everything the gyro model needs to predict an output (true rate, table angle, die
temperature, supply, time since power-on) and the measured output itself, sample by
sample, plus the analysed windows (segments) of the run.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

REFERENCE_TEMPERATURE_C = 25.0
REFERENCE_SUPPLY_V = 5.0

# Segment kinds as the engine writes them (procedures/runtime/rawdata.py) plus `transition`, the
# time between analysed windows, which the discrepancy workflow also uses.
SEGMENT_KINDS = (
    "static",
    "plateau",
    "transition",
    "stop_move",
    "stop_static",
    "verify",
    "stabilise",
    "ramp_plateau",  # the ramp's (eol-ramp): a rate plateau while the die heats or cools
)


@dataclass(frozen=True)
class Segment:
    kind: str
    start_s: float
    end_s: float
    condition: str = ""


@dataclass(frozen=True)
class Trajectory:
    """Samples of one record; all arrays have the same length and increasing time."""

    time_s: FloatArray
    gyro_dps: FloatArray
    ref_rate_dps: FloatArray
    ref_angle_deg: FloatArray
    temp_c: FloatArray
    supply_v: FloatArray
    time_since_power_on_s: FloatArray
    segments: tuple[Segment, ...]
    source: str = ""
    serial: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)
    # one axis of a three-axis part (procedures/model/run_folder_xyz.py): the axis (x, y, z)
    # and the other axes' variables per sample, by their regressor name (rate_x, accel_x, ...:
    # the reference rate along that axis, deg/s, and the accelerometer's reading, m/s^2);
    # empty for a single-axis part
    axis: str = ""
    axis_variables: Mapping[str, FloatArray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = self.time_s.shape[0]
        for name, arr in self.axis_variables.items():
            if arr.shape != (n,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"trajectory variable {name} must be ({n},) finite values")
        for name in (
            "gyro_dps",
            "ref_rate_dps",
            "ref_angle_deg",
            "temp_c",
            "supply_v",
            "time_since_power_on_s",
        ):
            arr = getattr(self, name)
            if arr.shape != (n,):
                raise ValueError(f"trajectory column {name} has shape {arr.shape}, expected ({n},)")
            if not np.all(np.isfinite(arr)):
                raise ValueError(
                    f"trajectory column {name} holds NaN or infinite values; "
                    "remove those rows from the data"
                )
        if n < 10:
            raise ValueError(f"trajectory has {n} samples; the workflow needs a whole run")
        if np.any(np.diff(self.time_s) <= 0):
            raise ValueError("time_s must increase strictly from row to row; sort the data")

    @property
    def n(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def dtemp_c(self) -> FloatArray:
        return self.temp_c - REFERENCE_TEMPERATURE_C

    @property
    def dsupply_v(self) -> FloatArray:
        return self.supply_v - REFERENCE_SUPPLY_V
