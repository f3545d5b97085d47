"""What the station expects of each instrument, as small typing Protocols.

Each capability is a Protocol of one to four methods (bluesky's protocols.py idea): what the
engine needs to identify, probe, move, read, power and close an instrument. The role
protocols (RateTable, Chamber, Supply, PartLink) are compositions of them, so code that
sequences a whole role keeps one name, while code that needs one capability (the UI's
instrument lights: `Probeable`; the pre-flight: `RateLimited`, `SetpointLimited`,
`OutputLimited`) asks only for that, at run time with `isinstance`. A driver is any object
that implements its role's composition; the optional capabilities are checked where present.
All angles in degrees, rates in deg/s, temperatures in C, supply in V and A, station time in s.
Every method may raise a subclass of `drivers.errors.InstrumentError`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntFlag
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from common.clock import Clock


@dataclass(frozen=True)
class InstrumentIdentity:
    """Who the instrument says it is (for traceability on the certificate)."""

    manufacturer: str
    model: str
    serial: str
    firmware: str = ""


# ---------------------------------------------------------------- shared capabilities


@runtime_checkable
class Identifiable(Protocol):
    def identify(self) -> InstrumentIdentity: ...


@runtime_checkable
class Probeable(Protocol):
    def probe(self) -> str:
        """A cheap health check for the instrument lights: '' when the instrument answers and
        reports no fault, else what it reports (a fault, an open interlock). Raises an
        `InstrumentError` when it cannot be reached at all."""
        ...


@runtime_checkable
class Closable(Protocol):
    def close(self) -> None: ...


@runtime_checkable
class ClockUser(Protocol):
    def attach_clock(self, clock: Clock) -> None:
        """Use the station clock for waits and timeouts (ScaledClock(1.0) until called)."""
        ...


# ---------------------------------------------------------------- rate table


@dataclass(frozen=True)
class TableStatus:
    """One consistent snapshot of the table's status and feedback registers."""

    ready: bool
    enabled: bool
    fault: bool
    in_position: bool
    at_rate: bool
    moving: bool
    interlock_open: bool
    fault_code: int
    encoder_counts: int  # raw, wrapping U32
    position_deg: float
    rate_dps: float
    controller_time_s: float  # controller clock at the snapshot, unwrapped by the driver
    # encoder counts made continuous by the driver (no wrap) since it connected; added so the
    # rate-table fit can difference counts across a U32 wrap
    encoder_counts_unwrapped: int = 0
    # one step of the controller clock (its time stamps are rounded to it): the reference
    # rate's uncertainty takes it from here; 1 ms where a driver cannot tell
    controller_time_resolution_s: float = 1e-3


@runtime_checkable
class Energizable(Protocol):
    """The table's drive: enable, disable, clear a fault, zero the encoder."""

    def enable(self) -> None: ...

    def disable(self) -> None: ...

    def reset_fault(self) -> None: ...

    def zero_encoder(self) -> None: ...


@runtime_checkable
class RateSettable(Protocol):
    def set_rate(self, rate_dps: float, accel_dps2: float | None = None) -> None:
        """Rate mode at `rate_dps`, ramping at `accel_dps2` (default: the configured limit)."""
        ...

    def wait_at_rate(self, timeout_s: float) -> TableStatus: ...


@runtime_checkable
class Movable(Protocol):
    def move_to(
        self,
        angle_deg: float,
        *,
        accel_dps2: float | None = None,
        move_time_s: float | None = None,
    ) -> None:
        """Position mode to `angle_deg`; either an acceleration limit or a move time."""
        ...

    def wait_in_position(self, timeout_s: float) -> TableStatus: ...


@runtime_checkable
class TableReadable(Protocol):
    def read_status(self) -> TableStatus: ...

    def counts_per_rev(self) -> int:
        """Encoder counts per revolution (the fixture latches this encoder into samples)."""
        ...


@runtime_checkable
class RateLimited(Protocol):
    """Optional: the table's own limits, for the pre-flight."""

    def max_rate_dps(self) -> float:
        """The largest |rate| the table accepts, deg/s."""
        ...

    def max_accel_dps2(self) -> float:
        """The largest acceleration the table accepts, deg/s^2."""
        ...


@runtime_checkable
class RateTable(
    Identifiable, Energizable, RateSettable, Movable, TableReadable, Closable, Protocol
):
    def safe_state(self) -> None:
        """Bring the table to rest and disable it. Must not raise if it is already safe."""
        ...


# ---------------------------------------------------------------- thermal chamber


@runtime_checkable
class TemperatureReadable(Protocol):
    def read_temperature(self) -> float:
        """The chamber's process value (air temperature), C."""
        ...


@runtime_checkable
class SetpointLimited(Protocol):
    def setpoint_limits(self) -> tuple[float, float]:
        """(lowest, highest) setpoint the controller accepts, C (read from the controller)."""
        ...


@runtime_checkable
class TemperatureSettable(Protocol):
    def set_setpoint(self, temp_c: float) -> None: ...

    def read_setpoint(self) -> float: ...

    def set_ramp_rate(self, c_per_min: float) -> None: ...

    def wait_setpoint(self, band_c: float, timeout_s: float) -> float:
        """Wait until the process value is within `band_c` of the setpoint."""
        ...


@runtime_checkable
class Runnable(Protocol):
    def run(self) -> None: ...

    def stop(self) -> None: ...

    def is_running(self) -> bool: ...


@runtime_checkable
class Chamber(
    Identifiable,
    TemperatureReadable,
    SetpointLimited,
    TemperatureSettable,
    Runnable,
    Closable,
    Protocol,
):
    def safe_state(self, safe_temp_c: float = 25.0) -> None: ...


# ---------------------------------------------------------------- DC supply


@runtime_checkable
class VoltageSource(Protocol):
    def reset(self) -> None: ...

    def set_voltage(self, supply_v: float) -> None: ...

    def set_current_limit(self, current_a: float) -> None: ...

    def output(self, on: bool) -> None: ...

    def output_is_on(self) -> bool: ...


@runtime_checkable
class SupplyMeasurable(Protocol):
    def measure_voltage(self) -> float: ...

    def measure_current(self) -> float: ...

    def check_errors(self) -> None:
        """Drain the SCPI error queue; raise ScpiError on the first error found."""
        ...

    def check_current_limit(self) -> tuple[float, float]:
        """Measure (volts, amps); raise SupplyCurrentLimit if the output is current-limiting
        (a shorted part). Call it after switching the output on and after voltage changes."""
        ...


@runtime_checkable
class OutputLimited(Protocol):
    """Optional: the supply's output limits, for the pre-flight."""

    def output_limits(self) -> tuple[float | None, float | None]:
        """(highest voltage V, highest current limit A) the supply can set; None: unknown."""
        ...


@dataclass(frozen=True)
class OutputRange:
    """What one supply output can be set to, and who says so (for the pre-flight's line)."""

    output: str  # "output 2 of the Keysight E36312A"
    low_v: float  # the lowest voltage it can be set to (a negative output: below 0)
    high_v: float
    max_a: float  # the highest current limit
    source: str  # "its rating", "VOLT? MAX and CURR? MAX", "station.yaml"

    def describe(self) -> str:
        parts = []
        if self.high_v != float("inf"):
            parts.append(f"{self.low_v:g} to {self.high_v:g} V")
        if self.max_a != float("inf"):
            parts.append(f"up to {self.max_a:g} A")
        return ", ".join(parts) + (f": {self.source}" if self.source else "")


@runtime_checkable
class OutputRanged(Protocol):
    """Optional: the range of the output the parts hang on, for the pre-flight."""

    def output_range(self) -> OutputRange | None:
        """The output's range; None when neither the model nor the instrument tells it."""
        ...


@runtime_checkable
class Supply(Identifiable, VoltageSource, SupplyMeasurable, Closable, Protocol):
    def safe_state(self) -> None: ...


# ---------------------------------------------------------------- inclinometer


@runtime_checkable
class Inclinometer(Protocol):
    """The optional inclinometer role: one sensor on each fixture socket, read at each stop of
    a hand-turned fixture (the manual_stop step's reference angle)."""

    def read_angle(self, socket: int) -> tuple[float, float]:
        """(angle, its standard uncertainty), deg, of the sensor on `socket`'s fixture."""
        ...


# ---------------------------------------------------------------- part link (fixture)


@dataclass(frozen=True)
class CalibrationRegisters:
    """The part's calibration registers, in engineering units.

    The part's compensated output is
        (raw - (bias + bias_tc*(T-T0) + bias_vc*(V-V0)))
            / (scale*(1 + scale_tc*(T-T0) + scale_vc*(V-V0)))
    with raw the uncompensated output in deg/s, T the die temperature and V the supply.
    The erased state (bias 0, scale 1, coefficients 0) passes the raw output through.
    Parts with higher-order temperature registers add bias_tc2*dT^2 + bias_tc3*dT^3 to the
    bias and scale*(scale_tc2*dT^2 + scale_tc3*dT^3) to the scale (dT = T - T0); 0 on parts
    calibrated to first order (and on fixtures without them).
    """

    bias_dps: float = 0.0
    scale: float = 1.0
    bias_tc_dps_per_c: float = 0.0
    scale_tc_per_c: float = 0.0
    bias_vc_dps_per_v: float = 0.0
    scale_vc_per_v: float = 0.0
    t0_c: float = 25.0
    v0_v: float = 5.0
    bias_tc2_dps_per_c2: float = 0.0
    bias_tc3_dps_per_c3: float = 0.0
    scale_tc2_per_c2: float = 0.0
    scale_tc3_per_c3: float = 0.0


class SampleStatus(IntFlag):
    """Status bits of each sample (`SampleBlock.status`), as every part link reports them
    (the fixture's frames carry them on the wire: drivers/fixture_protocol.py)."""

    OVER_RANGE = 1 << 0  # |output| beyond the rated range (250 deg/s): out of specification
    SATURATED = 1 << 1  # the rate code hit a rail: the sample is clipped
    COMPENSATED = 1 << 2  # the part applied its calibration registers to this sample
    TEMP_INVALID = 1 << 3  # the on-chip temperature sensor reading is not valid
    SUPPLY_LOW = 1 << 4  # the part's supply is below its operating minimum
    ENCODER_LATCHED = 1 << 5  # the encoder field holds the table's count at this sample


ENCODER_MODULO = 1 << 32  # SampleBlock.encoder_counts wrap here (a u32 counter)


@dataclass(frozen=True)
class SampleBlock:
    """Samples decoded from the stream since the last read, in arrival order.

    `time_s` is the fixture's timestamp (its own clock, unwrapped), never the station's.
    Lost and corrupted counts are for this block; a gap in `seq` is a lost frame.
    `encoder_counts` is the table's encoder count the fixture latched at each sample (raw,
    wrapping u32), meaningful only where `status` has ENCODER_LATCHED: the serial link always
    fills it, with zeros and the bit clear from a fixture whose encoder input is not connected
    (or whose older firmware has no encoder field). None only from links and test fakes that
    do not provide the field at all.
    """

    seq: NDArray[np.int64]
    time_s: NDArray[np.float64]
    rate_code: NDArray[np.int64]
    temp_code: NDArray[np.int64]
    status: NDArray[np.int64]
    frames_lost: int = 0
    frames_corrupted: int = 0
    bytes_discarded: int = 0
    encoder_counts: NDArray[np.int64] | None = None
    # three-axis frames only (None from single-axis ones): gyro and accelerometer codes per
    # axis, (n, 3) columns x, y, z; `rate_code` is then the x column (rate_code_xyz[:, 0])
    rate_code_xyz: NDArray[np.int64] | None = None
    accel_code_xyz: NDArray[np.int64] | None = None

    def __len__(self) -> int:
        return int(self.seq.size)


@dataclass(frozen=True)
class LinkStats:
    """Running totals of a part link since streaming started."""

    frames_ok: int = 0
    frames_lost: int = 0
    frames_corrupted: int = 0
    bytes_discarded: int = 0
    extra: dict[str, int] = field(default_factory=dict)


@runtime_checkable
class PartPresence(Protocol):
    def part_present(self) -> bool: ...

    def read_part_serial(self) -> str:
        """The part's own serial-number register, to check against the scanned label."""
        ...


@runtime_checkable
class Streaming(Protocol):
    def set_output_rate(self, rate_hz: int) -> None: ...

    def start_stream(self) -> None: ...

    def stop_stream(self) -> None: ...

    def read_samples(self, max_wait_s: float = 0.0) -> SampleBlock:
        """Everything decoded since the last call; waits up to `max_wait_s` wall s for data."""
        ...

    def stats(self) -> LinkStats: ...


@runtime_checkable
class CalibrationStore(Protocol):
    def read_calibration(self) -> CalibrationRegisters: ...

    def write_calibration(self, registers: CalibrationRegisters) -> None: ...

    def set_compensation(self, enabled: bool) -> None:
        """Let the part apply its calibration registers to its output (or not: raw output)."""
        ...


@runtime_checkable
class StopAngleSource(Protocol):
    def stop_angle(self) -> tuple[float, float]:
        """The fixture's measured angle between its mechanical stops and its standard
        uncertainty, deg (measured once with an inclinometer, stored in the fixture)."""
        ...


@runtime_checkable
class PartLink(
    Identifiable,  # the fixture microcontroller's identity (not the part's)
    PartPresence,
    Streaming,
    CalibrationStore,
    StopAngleSource,
    Closable,
    Protocol,
):
    """One fixture socket's link to its part."""


# ---------------------------------------------------------------- safe-state readback


@dataclass(frozen=True)
class SafeReadback:
    """What an instrument itself reports about its safe state, read back after commanding it.

    `safe` is the instrument's own answer (table at rest and disabled, supply output off,
    chamber setpoint at its safe temperature); `detail` says what was read, in words an
    operator can act on.
    """

    safe: bool
    detail: str


@runtime_checkable
class ReadsBackSafe(Protocol):
    """A table or supply that can read back whether it is in its safe state."""

    def check_safe(self) -> SafeReadback: ...


@runtime_checkable
class ChamberReadsBackSafe(Protocol):
    """A chamber that can read back whether it holds its safe temperature."""

    def check_safe(self, safe_temp_c: float) -> SafeReadback: ...


@runtime_checkable
class StreamReadsBackSafe(Protocol):
    """A part link that can read back from its fixture whether the sample stream is stopped
    (the fixture's own state: a stream a crashed station started is still started)."""

    def check_stream_stopped(self) -> SafeReadback: ...


@runtime_checkable
class Reconnectable(Protocol):
    """A driver that can drop its connection and open a new one, optionally with a longer
    reply timeout (wall seconds) for a slow link."""

    def reconnect(self, timeout_s: float | None = None) -> None: ...


@runtime_checkable
class Watched(Protocol):
    """An instrument the run's watchdog polls: raises an `InstrumentError` subclass when the
    instrument reports a fault (e-stop, interlock, chamber FAULT, a stalled heartbeat)."""

    def watchdog_check(self) -> None: ...


# ---------------------------------------------------------------- three-axis parts

Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]
_ZERO3: Vec3 = (0.0, 0.0, 0.0)
_IDENTITY3: Mat3 = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
_ZERO33: Mat3 = (_ZERO3, _ZERO3, _ZERO3)


def _vec3(value: object, name: str) -> Vec3:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,):
        raise ValueError(f"{name} must be 3 numbers (x, y, z), got shape {a.shape}")
    return (float(a[0]), float(a[1]), float(a[2]))


def _mat3(value: object, name: str) -> Mat3:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3, 3):
        raise ValueError(f"{name} must be 3 x 3 numbers (rows x, y, z), got shape {a.shape}")
    return (_vec3(a[0], name), _vec3(a[1], name), _vec3(a[2], name))


@dataclass(frozen=True)
class CalibrationRegisters3:
    """A three-axis part's calibration registers, in engineering units (part frame x, y, z).

    With raw the uncompensated output (deg/s, 3-vector), a the accelerometer's specific force
    (m/s^2, 3-vector), T the die temperature and V the supply, dT = T - t0_c, dV = V - v0_v,
    the part's compensated output is

        w_hat = D^-1 M (raw - b - G a)
        b = bias_dps + bias_tc_dps_per_c dT + bias_vc_dps_per_v dV        (per axis)
        D = diag(1 + scale_tc_per_c dT + scale_vc_per_v dV)               (per axis)

    M = `matrix` (scale and misalignment, rows are output axes), G = `g_sensitivity_dps_per_mps2`
    (deg/s per m/s^2, rows output axes, columns the accelerometer axes). Erased: zeros, M the
    identity (the raw output passes through). Fields are tuples (hashable, comparable); the
    constructor accepts any array-like of the right shape.
    """

    bias_dps: Vec3 = _ZERO3
    matrix: Mat3 = _IDENTITY3
    g_sensitivity_dps_per_mps2: Mat3 = _ZERO33
    bias_tc_dps_per_c: Vec3 = _ZERO3
    bias_vc_dps_per_v: Vec3 = _ZERO3
    scale_tc_per_c: Vec3 = _ZERO3
    scale_vc_per_v: Vec3 = _ZERO3
    t0_c: float = 25.0
    v0_v: float = 5.0

    VECTOR_FIELDS: ClassVar[tuple[str, ...]] = (
        "bias_dps", "bias_tc_dps_per_c", "bias_vc_dps_per_v", "scale_tc_per_c", "scale_vc_per_v"
    )
    MATRIX_FIELDS: ClassVar[tuple[str, ...]] = ("matrix", "g_sensitivity_dps_per_mps2")

    def __post_init__(self) -> None:
        for name in self.VECTOR_FIELDS:
            object.__setattr__(self, name, _vec3(getattr(self, name), name))
        for name in self.MATRIX_FIELDS:
            object.__setattr__(self, name, _mat3(getattr(self, name), name))
        object.__setattr__(self, "t0_c", float(self.t0_c))
        object.__setattr__(self, "v0_v", float(self.v0_v))

    def compensate(
        self,
        raw_dps: NDArray[np.float64],
        accel_mps2: NDArray[np.float64],
        temp_c: NDArray[np.float64] | float,
        supply_v: NDArray[np.float64] | float,
    ) -> NDArray[np.float64]:
        """w_hat (n, 3) deg/s from raw (n, 3) deg/s, accel (n, 3) m/s^2, temp and supply
        (scalars or (n,)): the formula above, as the part applies it."""
        raw = np.atleast_2d(np.asarray(raw_dps, dtype=np.float64))
        acc = np.atleast_2d(np.asarray(accel_mps2, dtype=np.float64))
        d_t = (np.asarray(temp_c, dtype=np.float64) - self.t0_c).reshape(-1, 1)
        d_v = (np.asarray(supply_v, dtype=np.float64) - self.v0_v).reshape(-1, 1)
        bias = (np.asarray(self.bias_dps) + np.asarray(self.bias_tc_dps_per_c) * d_t
                + np.asarray(self.bias_vc_dps_per_v) * d_v)
        scale = 1.0 + np.asarray(self.scale_tc_per_c) * d_t + np.asarray(self.scale_vc_per_v) * d_v
        corrected = raw - bias - acc @ np.asarray(self.g_sensitivity_dps_per_mps2).T
        return np.asarray((corrected @ np.asarray(self.matrix).T) / scale, dtype=np.float64)


@runtime_checkable
class CalibrationStore3(Protocol):
    """Optional capability of a part link whose part may have three axes."""

    def axes(self) -> int:
        """1 or 3: the part's rate axes (from the fixture's identity)."""
        ...

    def read_calibration3(self) -> CalibrationRegisters3: ...

    def write_calibration3(self, registers: CalibrationRegisters3) -> None:
        """Write the three-axis registers, read them back and compare (raises on mismatch)."""
        ...
