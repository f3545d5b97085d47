"""The rate table's controller in the world: commands, motion, encoder, status, faults.

Register semantics follow drivers/rate_table_map.py. A motion is planned from the state at
the time a write request arrives, so a multi-register write (e.g. POS_CMD..MOVE_TIME in one
request) plans once. Everything read back is evaluated at the request time.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.rate_table_map import (
    AT_RATE_TOLERANCE_DPS,
    FAULT_TEXT,
    IN_POSITION_TOLERANCE_DEG,
    MAX_RATE_DPS,
    STRING_REGS,
    Control,
    Fault,
    Mode,
    Reg,
    Status,
)
from drivers.sim import motion
from drivers.sim.config import TableConfig

REGISTER_COUNT = 64
_I32 = {Reg.POS_CMD, Reg.RATE_CMD, Reg.ACCEL_LIMIT, Reg.MOVE_TIME}


class CommandRefusedError(ValueError):
    """A write the controller refuses (Modbus exception 3, illegal data value)."""


def _i32_from(hi: int, lo: int) -> int:
    v = (hi << 16) | lo
    return v - (1 << 32) if v & 0x80000000 else v


def _regs32(value: int) -> tuple[int, int]:
    v = value & 0xFFFFFFFF
    return v >> 16, v & 0xFFFF


def string_registers(text: str, count: int) -> list[int]:
    raw = text.encode("ascii", "replace")[: 2 * count].ljust(2 * count, b"\0")
    return [(raw[2 * i] << 8) | raw[2 * i + 1] for i in range(count)]


class TableModel:
    """The servo table's controller state; every method takes the world time `t_s`."""

    def __init__(self, config: TableConfig) -> None:
        self.cfg = config
        self.cpr = config.counts_per_rev
        self.enabled = False
        self.halt = False
        self.mode = Mode.IDLE
        self.pos_cmd_mdeg = 0
        self.rate_cmd_mdps = 0
        self.accel_mdps2 = int(round(config.accel_limit_dps2 * 1000))
        self.move_time_ms = 0
        self.fault = Fault.NONE
        self.estop_pressed = False
        self.interlock_open = False
        self.follow_error_pending = False
        self.zero_counts = 0  # absolute encoder count taken as zero
        self.profile = motion.hold(0.0, 0.0)
        self._plan_key: tuple[Any, ...] | None = None
        self._settle_s = 0.0  # world time after which AT_RATE / IN_POSITION may be set
        self._strings = {
            Reg.MODEL: config.model,
            Reg.SERIAL: config.serial,
            Reg.FIRMWARE: config.firmware,
        }

    # ------------------------------------------------------------ kinematics

    def _ripple_amp(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.cfg.ripple_dps * np.minimum(1.0, np.abs(v) / 10.0)

    def angle_deg(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """True table angle (deg, continuous), ripple included."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        p, v = self.profile.position_velocity(t)
        w = 2 * math.pi * self.cfg.ripple_hz
        return p + self._ripple_amp(v) / w * np.sin(w * t)

    def rate_dps(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """True table rate (deg/s), ripple included."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        v = self.profile.velocity_dps(t)
        w = 2 * math.pi * self.cfg.ripple_hz
        return v + self._ripple_amp(v) * np.cos(w * t)

    def _abs_counts(self, angle_deg: float) -> int:
        return math.floor(angle_deg * self.cpr / 360.0 + 1e-9)

    def absolute_counts(self, angle_deg: NDArray[np.float64]) -> NDArray[np.int64]:
        """The encoder's count from its index at each angle (what its quadrature output
        gives a counter; the registers report it minus the zero taken by ZERO_ENCODER)."""
        return np.floor(np.asarray(angle_deg) * self.cpr / 360.0 + 1e-9).astype(np.int64)

    def counts_since_zero(self, t_s: float) -> int:
        """The encoder's count since ZERO_ENCODER at `t_s`, not wrapped (what the registers'
        U32 ENCODER_COUNTS wraps); for twins that report position rather than counts."""
        return self._abs_counts(float(self.angle_deg(t_s)[0])) - self.zero_counts

    def _zero_angle_deg(self) -> float:
        return self.zero_counts * 360.0 / self.cpr

    # ------------------------------------------------------------ status

    def ready(self) -> bool:
        return self.fault == Fault.NONE and not self.interlock_open and not self.estop_pressed

    def status_bits(self, t_s: float) -> int:
        p, v = self.profile.at(t_s)
        bits = Status(0)
        if self.ready():
            bits |= Status.READY
        if self.enabled:
            bits |= Status.ENABLED
        if self.fault != Fault.NONE:
            bits |= Status.FAULT
        if self.interlock_open:
            bits |= Status.INTERLOCK_OPEN
        settled = t_s >= self._settle_s
        if self.enabled and settled and self.mode == Mode.POSITION:
            err = abs(float(self.angle_deg(t_s)[0]) - self._target_angle())
            if err < IN_POSITION_TOLERANCE_DEG:
                bits |= Status.IN_POSITION
        rate_err = abs(v - self.rate_cmd_mdps / 1000.0)
        if self.enabled and settled and self.mode == Mode.RATE and rate_err < AT_RATE_TOLERANCE_DPS:
            bits |= Status.AT_RATE
        if abs(v) > 1e-6 or t_s < self.profile.motion_end_s:
            bits |= Status.MOVING
        return int(bits)

    def _target_angle(self) -> float:
        return self.pos_cmd_mdeg / 1000.0 + self._zero_angle_deg()

    def registers(self, t_s: float) -> list[int]:
        """Every register 0..63 at world time `t_s` (one consistent snapshot)."""
        regs = [0] * REGISTER_COUNT
        control = Control(0)
        if self.enabled:
            control |= Control.ENABLE
        if self.halt:
            control |= Control.HALT
        regs[Reg.CONTROL] = int(control)
        regs[Reg.MODE] = int(self.mode)
        for reg, value in (
            (Reg.POS_CMD, self.pos_cmd_mdeg),
            (Reg.RATE_CMD, self.rate_cmd_mdps),
            (Reg.ACCEL_LIMIT, self.accel_mdps2),
            (Reg.MOVE_TIME, self.move_time_ms),
        ):
            regs[reg], regs[reg + 1] = _regs32(value)
        regs[Reg.STATUS] = self.status_bits(t_s)
        regs[Reg.FAULT_CODE] = int(self.fault)
        angle = float(self.angle_deg(t_s)[0])
        rate = float(self.rate_dps(t_s)[0])
        counts = self._abs_counts(angle) - self.zero_counts
        regs[Reg.ENCODER_COUNTS], regs[Reg.ENCODER_COUNTS + 1] = _regs32(counts)
        pos_mdeg = int(round(counts * 360_000.0 / self.cpr))
        regs[Reg.POS_FB], regs[Reg.POS_FB + 1] = _regs32(pos_mdeg)
        regs[Reg.RATE_FB], regs[Reg.RATE_FB + 1] = _regs32(int(round(rate * 1000.0)))
        regs[Reg.SNAPSHOT_TIME], regs[Reg.SNAPSHOT_TIME + 1] = _regs32(int(t_s * 1e6))
        regs[Reg.HEARTBEAT] = int(t_s * 100.0) & 0xFFFF
        for reg, count in STRING_REGS.items():
            regs[reg : reg + count] = string_registers(self._strings[reg], count)
        return regs

    # ------------------------------------------------------------ commands

    def write(self, t_s: float, first: int, values: list[int], current: list[int]) -> None:
        """Apply one write request (registers `first`.. = `values`); `current` holds 0..63.

        Raises CommandRefusedError for a value the controller does not accept.
        """
        regs = list(current[:REGISTER_COUNT])
        regs[first : first + len(values)] = values
        written = set(range(first, first + len(values)))
        new: dict[Reg, int] = {}
        for reg in _I32:
            if written & {reg, reg + 1}:
                new[reg] = _i32_from(regs[reg], regs[reg + 1])
        if Reg.MODE in written and regs[Reg.MODE] not in (0, 1, 2):
            raise CommandRefusedError(f"MODE {regs[Reg.MODE]} is not 0, 1 or 2")
        if Reg.RATE_CMD in new and abs(new[Reg.RATE_CMD]) > MAX_RATE_DPS * 1000:
            raise CommandRefusedError("RATE_CMD beyond the table's rate limit")
        if (
            Reg.ACCEL_LIMIT in new
            and not 0 < new[Reg.ACCEL_LIMIT] <= self.cfg.max_accel_dps2 * 1000
        ):
            raise CommandRefusedError("ACCEL_LIMIT outside 0 < a <= the table's maximum")
        if Reg.MOVE_TIME in new and new[Reg.MOVE_TIME] < 0:
            raise CommandRefusedError("MOVE_TIME must not be negative")
        self.pos_cmd_mdeg = new.get(Reg.POS_CMD, self.pos_cmd_mdeg)
        self.rate_cmd_mdps = new.get(Reg.RATE_CMD, self.rate_cmd_mdps)
        self.accel_mdps2 = new.get(Reg.ACCEL_LIMIT, self.accel_mdps2)
        self.move_time_ms = new.get(Reg.MOVE_TIME, self.move_time_ms)
        if Reg.MODE in written:
            self.mode = Mode(regs[Reg.MODE])
        if Reg.CONTROL in written:
            self._control(t_s, Control(regs[Reg.CONTROL] & 0x0F))
        self._plan(t_s)

    def _control(self, t_s: float, bits: Control) -> None:
        if Control.FAULT_RESET in bits and not self.estop_pressed:
            self.fault = Fault.NONE
        if Control.ZERO_ENCODER in bits:
            self.zero_counts = self._abs_counts(float(self.angle_deg(t_s)[0]))
            if self.mode == Mode.POSITION:
                self.pos_cmd_mdeg = 0
            self._plan_key = None
        self.halt = Control.HALT in bits
        if Control.ENABLE in bits and not self.enabled and self.ready():
            self.enabled = True
            self._plan_key = None
        elif Control.ENABLE not in bits and self.enabled:
            self.disable(t_s)

    def _accel(self) -> float:
        return self.accel_mdps2 / 1000.0

    def _plan(self, t_s: float) -> None:
        if not self.enabled:
            return
        if self.halt:
            key: tuple[Any, ...] = ("halt",)
        elif self.mode == Mode.RATE:
            key = ("rate", self.rate_cmd_mdps, self.accel_mdps2)
        elif self.mode == Mode.POSITION:
            key = ("pos", self.pos_cmd_mdeg, self.accel_mdps2, self.move_time_ms)
        else:
            key = ("idle",)
        if key == self._plan_key:
            return
        self._plan_key = key
        p, v = self.profile.at(t_s)
        a = self._accel()
        if key[0] in ("halt", "idle"):
            self.profile = motion.stop_profile(t_s, p, v, a)
        elif key[0] == "rate":
            self.profile = motion.rate_profile(t_s, p, v, self.rate_cmd_mdps / 1000.0, a)
        elif self.move_time_ms > 0:
            self.profile = motion.smooth_move(
                t_s, p, v, self._target_angle(), self.move_time_ms / 1000.0, a, self.cfg.bounce
            )
        else:
            self.profile = motion.trapezoid_move(
                t_s, p, v, self._target_angle(), a, self.cfg.slew_rate_dps, self.cfg.bounce
            )
        settle = self.profile.motion_end_s + self.cfg.at_rate_settle_s
        if self.profile.bounce is not None:
            settle = max(settle, self.profile.bounce.settled_at_s(IN_POSITION_TOLERANCE_DEG / 2))
        self._settle_s = settle

    def disable(self, t_s: float, accel_dps2: float | None = None) -> None:
        """Disable the drive and bring the axis to rest (controlled stop)."""
        p, v = self.profile.at(t_s)
        self.enabled = False
        self._plan_key = None
        self.profile = motion.stop_profile(t_s, p, v, accel_dps2 or self._accel())

    # ------------------------------------------------------------ faults

    def inject_fault(self, t_s: float, fault: Fault) -> None:
        """Trip the controller: hard stop at the table's maximum deceleration."""
        self.fault = fault
        if fault == Fault.ESTOP:
            self.estop_pressed = True
        self.disable(t_s, self.cfg.max_accel_dps2)

    def set_interlock(self, t_s: float, open_: bool) -> None:
        self.interlock_open = open_
        if open_ and self.enabled:
            self.disable(t_s, self.cfg.max_accel_dps2)

    def clear_faults(self) -> None:
        """Release the e-stop and close the interlock (the fault code still needs a reset)."""
        self.estop_pressed = False
        self.interlock_open = False

    def is_safe(self, t_s: float) -> bool:
        _, v = self.profile.at(t_s)
        return not self.enabled and abs(v) < 1e-6 and t_s >= self.profile.motion_end_s

    def truth(self, t_s: float) -> dict[str, Any]:
        return {
            "angle_deg": float(self.angle_deg(t_s)[0]),
            "position_deg": float(self.angle_deg(t_s)[0]) - self._zero_angle_deg(),
            "rate_dps": float(self.rate_dps(t_s)[0]),
            "enabled": self.enabled,
            "mode": self.mode.name.lower(),
            "halt": self.halt,
            "fault_code": int(self.fault),
            "fault": FAULT_TEXT[self.fault],
            "estop_pressed": self.estop_pressed,
            "interlock_open": self.interlock_open,
            "motion_end_s": self.profile.motion_end_s,
            "status": self.status_bits(t_s),
        }
