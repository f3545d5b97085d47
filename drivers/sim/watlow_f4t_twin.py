"""The Watlow F4T twin: the world's chamber served as an F4T's loop 1 over Modbus TCP.

Same pymodbus `SimDevice` server as `modbus_twins.ChamberTwin` (the `action` callback fills the
registers from the world at the request time and applies writes), over the F4T map of
`drivers.watlow_f4t_map`: float32 pairs low word first, Watlow's codes for modes and alarms.

- Setpoint (2782) writes must cover the whole pair in one request (else exception 2); a value
  outside the range 2774/2776 or not finite is refused with exception 3.
- Control mode (2730) AUTO runs the chamber, OFF stops it (MANUAL is refused: exception 3).
- Range limits, process value, working setpoint, units and alarm states are read-only.
- Profile requests (16566) are accepted and change nothing: the twin runs no profiles.
- The world's `chamber_stuck` fault with `report_fault` shows as alarm 1 in state LOW or HIGH
  (the air on that side of the setpoint).
- `fahrenheit=True` serves temperatures in F with the units register saying so.
"""

from __future__ import annotations

import logging
import math

from pymodbus.constants import ExcCodes
from pymodbus.simulator import DataType, SimData

from drivers.sim.modbus_twins import ModbusTwin
from drivers.sim.world import World
from drivers.watlow_f4t_map import (
    PART_NUMBER_REGS,
    Code,
    Reg,
    alarm_reg,
    c_to_f,
    f_to_c,
    float_to_regs,
    regs_to_float,
)

log = logging.getLogger(__name__)

PART_NUMBER = "F4T1R2AA2AAAAAA"  # one loop, no profiles (ESPEC reads digits 7 and 12)
ALARMS = 6
WRITABLE = frozenset({Reg.CONTROL_MODE, Reg.SETPOINT, Reg.SETPOINT + 1, Reg.PROFILE_ACTION})
_FLOATS = (Reg.RANGE_LOW, Reg.RANGE_HIGH, Reg.SETPOINT, Reg.WORKING_SETPOINT, Reg.PROCESS_VALUE)


def _block(address: int, count: int) -> SimData:
    return SimData(address=address, count=count, values=0, datatype=DataType.REGISTERS)


class _F4TServer(ModbusTwin):
    def __init__(self, world: World, host: str, port: int, fahrenheit: bool) -> None:
        blocks = [
            _block(Reg.PART_NUMBER, PART_NUMBER_REGS),
            *(_block(alarm_reg(n), 1) for n in range(1, ALARMS + 1)),
            _block(Reg.CONTROL_MODE, 1),
            _block(Reg.RANGE_LOW, 4),
            _block(Reg.SETPOINT, 2),
            _block(Reg.WORKING_SETPOINT, 2),
            _block(Reg.ACTUAL_MODE, 1),
            _block(Reg.PROCESS_VALUE, 2),
            _block(Reg.UNITS, 1),
            _block(Reg.PROFILE_ACTION, 1),
            _block(Reg.PROFILE_STATE, 1),
        ]
        super().__init__("Watlow F4T chamber", blocks, host, port)
        self.world = world
        self.fahrenheit = fahrenheit

    def _temp(self, temp_c: float) -> float:
        return c_to_f(temp_c) if self.fahrenheit else temp_c

    def registers(self) -> dict[int, int]:
        ch = self.world.chamber
        cfg = ch.cfg
        values = {
            Reg.RANGE_LOW: cfg.setpoint_low_c,
            Reg.RANGE_HIGH: cfg.setpoint_high_c,
            Reg.SETPOINT: ch.setpoint_c,
            Reg.WORKING_SETPOINT: ch.ramped_sp_c if ch.running else ch.setpoint_c,
            Reg.PROCESS_VALUE: ch.air_c,
        }
        regs: dict[int, int] = {}
        for reg in _FLOATS:
            low, high = float_to_regs(self._temp(values[reg]))
            regs[reg], regs[reg + 1] = low, high
        mode = Code.AUTO if ch.running else Code.OFF
        regs[Reg.CONTROL_MODE] = regs[Reg.ACTUAL_MODE] = mode
        regs[Reg.UNITS] = Code.FAHRENHEIT if self.fahrenheit else Code.CELSIUS
        regs[Reg.PROFILE_ACTION] = Code.NONE
        regs[Reg.PROFILE_STATE] = Code.NONE
        for i, char in enumerate(PART_NUMBER[:PART_NUMBER_REGS]):
            regs[Reg.PART_NUMBER + i] = ord(char)
        for n in range(1, ALARMS + 1):
            regs[alarm_reg(n)] = Code.NONE
        if ch.stuck and ch.stuck_reports_fault:
            regs[alarm_reg(1)] = Code.LOW if ch.air_c < ch.setpoint_c else Code.HIGH
        return {int(k): int(v) for k, v in regs.items()}

    def _write(self, address: int, values: list[int]) -> ExcCodes | None:
        span = set(range(address, address + len(values)))
        if not span <= WRITABLE:
            return ExcCodes.ILLEGAL_ADDRESS
        if (Reg.SETPOINT in span) != (Reg.SETPOINT + 1 in span):
            log.info("F4T twin refused a write covering one word of the setpoint pair")
            return ExcCodes.ILLEGAL_ADDRESS
        ch = self.world.chamber
        for offset, value in enumerate(values):
            reg = address + offset
            if reg == Reg.CONTROL_MODE:
                if value not in (Code.AUTO, Code.OFF):
                    return ExcCodes.ILLEGAL_VALUE
                ch.set_running(value == Code.AUTO)
            elif reg == Reg.SETPOINT:
                raw = regs_to_float(values[offset : offset + 2])
                temp_c = f_to_c(raw) if self.fahrenheit else raw
                low, high = ch.cfg.setpoint_low_c, ch.cfg.setpoint_high_c
                if not (math.isfinite(temp_c) and low - 1e-3 <= temp_c <= high + 1e-3):
                    log.info("F4T twin refused setpoint %r C (range %g..%g)", temp_c, low, high)
                    return ExcCodes.ILLEGAL_VALUE
                ch.setpoint_c = min(max(temp_c, low), high)
        return None

    async def handle(
        self,
        fc: int,
        start: int,
        address: int,
        count: int,
        registers: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        self.world.advance()
        if values is not None:
            refused = self._write(address, [int(v) for v in values])
            if refused is not None:
                return refused
            self.world.advance()
        for reg, value in self.registers().items():
            registers[reg - start] = value
        return None


class WatlowF4TTwin:
    """Watlow F4T twin on loopback (the brief's twin contract).

    Args:
        world: the simulated bench's world (its chamber is the one served).
        host, port: where to listen (port 0: any free port).
        fahrenheit: serve temperatures in F.
    """

    def __init__(
        self, world: World, host: str = "127.0.0.1", port: int = 0, *, fahrenheit: bool = False
    ) -> None:
        self.world = world
        self._server = _F4TServer(world, host, port, fahrenheit)

    @property
    def delay_s(self) -> float:
        return self._server.delay_s

    @delay_s.setter
    def delay_s(self, value: float) -> None:
        self._server.delay_s = value

    @property
    def dropped(self) -> bool:
        return self._server.dropped

    @property
    def requests(self) -> int:
        return self._server.requests

    async def start(self) -> None:
        await self._server.start()

    def endpoint(self) -> str:
        return self._server.endpoint

    async def drop(self) -> None:
        await self._server.drop()

    async def restore(self) -> None:
        await self._server.restore()

    async def shutdown(self) -> None:
        await self._server.shutdown()
