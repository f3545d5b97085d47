"""The thermal chamber in the world: a ramp-limited setpoint and a first-order air response.

Stepped with exact exponentials over whatever world time has passed, so coarse steps are
fine (the time constants are a minute and more).
"""

from __future__ import annotations

import math
from typing import Any

from drivers.chamber_map import AT_SETPOINT_BAND_C, STRING_REGS, TENTHS, Reg, State
from drivers.sim.config import ChamberConfig
from drivers.sim.table import string_registers


class ChamberModel:
    def __init__(self, config: ChamberConfig) -> None:
        self.cfg = config
        self.setpoint_c = config.initial_setpoint_c
        self.ramp_c_per_min = 0.0  # 0 = as fast as the chamber can
        self.running = False
        self.air_c = config.ambient_c
        self.ramped_sp_c = config.ambient_c
        self.stuck = False
        self.stuck_reports_fault = False
        self._strings = {
            Reg.MODEL: config.model,
            Reg.SERIAL: config.serial,
            Reg.FIRMWARE: config.firmware,
        }

    def step(self, dt_s: float) -> None:
        if dt_s <= 0:
            return
        if self.stuck:
            return  # compressor/heater fault: the air stays where it is
        if not self.running:
            self.ramped_sp_c = self.air_c
            k = 1.0 - math.exp(-dt_s / self.cfg.idle_tau_s)
            self.air_c += (self.cfg.ambient_c - self.air_c) * k
            return
        rate = self.ramp_c_per_min if self.ramp_c_per_min > 0 else self.cfg.max_ramp_c_per_min
        rate = min(rate, self.cfg.max_ramp_c_per_min)
        max_step = rate / 60.0 * dt_s
        start_sp = self.ramped_sp_c
        delta = self.setpoint_c - start_sp
        self.ramped_sp_c = start_sp + max(-max_step, min(max_step, delta))
        # air follows the (linearly moving) ramped setpoint; use its mid-step value
        target = 0.5 * (start_sp + self.ramped_sp_c)
        k = 1.0 - math.exp(-dt_s / self.cfg.air_tau_s)
        self.air_c += (target - self.air_c) * k

    def state(self) -> State:
        if self.stuck and self.stuck_reports_fault:
            return State.FAULT
        if not self.running:
            return State.STOPPED
        if abs(self.air_c - self.setpoint_c) <= AT_SETPOINT_BAND_C:
            return State.AT_SETPOINT
        return State.RAMPING

    def registers(self) -> dict[int, int]:
        def tenths(c: float) -> int:
            return int(round(c * TENTHS)) & 0xFFFF

        regs: dict[int, int] = {
            Reg.PROCESS_VALUE: tenths(self.air_c),
            Reg.STATE: int(self.state()),
            Reg.SETPOINT: tenths(self.setpoint_c),
            Reg.SP_LIMIT_LOW: tenths(self.cfg.setpoint_low_c),
            Reg.SP_LIMIT_HIGH: tenths(self.cfg.setpoint_high_c),
            Reg.RUN: int(self.running),
            Reg.RAMP_RATE: int(round(self.ramp_c_per_min * TENTHS)),
        }
        for reg, count in STRING_REGS.items():
            for i, value in enumerate(string_registers(self._strings[reg], count)):
                regs[reg + i] = value
        return {int(k): v for k, v in regs.items()}

    def write(self, reg: int, value: int) -> None:
        """Apply one register write; ValueError when out of range (Modbus exception 3)."""
        signed = value - 0x10000 if value & 0x8000 else value
        if reg == Reg.SETPOINT:
            temp_c = signed / TENTHS
            if not self.cfg.setpoint_low_c <= temp_c <= self.cfg.setpoint_high_c:
                raise ValueError("setpoint outside the limits in registers 602/603")
            self.setpoint_c = temp_c
        elif reg == Reg.RUN:
            if value not in (0, 1):
                raise ValueError("RUN takes 0 or 1")
            if value and not self.running:
                self.ramped_sp_c = self.air_c
            self.running = bool(value)
        elif reg == Reg.RAMP_RATE:
            self.ramp_c_per_min = value / TENTHS
        else:
            raise PermissionError(f"register {reg} is read-only")

    def is_safe(self, safe_low_c: float = 10.0, safe_high_c: float = 40.0) -> bool:
        """Stopped, or running towards a setpoint people can touch."""
        return (not self.running) or safe_low_c <= self.setpoint_c <= safe_high_c

    def truth(self) -> dict[str, Any]:
        return {
            "setpoint_c": self.setpoint_c,
            "air_c": self.air_c,
            "ramped_setpoint_c": self.ramped_sp_c,
            "running": self.running,
            "ramp_c_per_min": self.ramp_c_per_min,
            "state": self.state().name.lower(),
            "stuck": self.stuck,
        }

    def set_running(self, on: bool) -> None:
        """Control on (the ramp starts from the air, as a RUN write does) or off: for twins
        whose protocol switches the chamber some other way than the RUN register."""
        if on and not self.running:
            self.ramped_sp_c = self.air_c
        self.running = on
