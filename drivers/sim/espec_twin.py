"""The ESPEC P-300 twin: the world's chamber served as a P-300's ASCII command set over TCP.

An asyncio line server: one CR LF (or LF) terminated command, one CR LF terminated reply, the
same commands `drivers.espec_p300` documents. Settings answer `OK:<command>`; refusals
`NA:<reason>` as the P-300 words them (`DATA OUT OF RANGE` for a setpoint outside the limits,
`CMD ERR` for an unknown command, `PARA ERR` for a bad parameter, `DATA NOT READY` for a
program that does not exist, `CONT NOT READY-1` for humidity on this temperature-only chamber).
Modes: `POWER,OFF` -> OFF (control off, only `POWER,ON` and queries are taken), STANDBY
(control off), CONSTANT (control on at the setpoint). The world's `chamber_stuck` fault with
`report_fault` is one active alarm: `MON?`'s alarm count 1 and `ALARM?` -> `1,<STUCK_ALARM_CODE>`.
"""

from __future__ import annotations

import logging
import math

from drivers.sim.line_twin import LineTwin
from drivers.sim.world import World

log = logging.getLogger(__name__)

STUCK_ALARM_CODE = 17  # the twin's number for "cannot reach the setpoint" (heater/refrigeration)
CONTROLLER = "P300"
MAX_LINE = 256


class EspecP300Twin(LineTwin):
    """ESPEC P-300 twin on loopback (the bench's twin contract)."""

    name = "ESPEC P-300 twin"
    max_line_bytes = MAX_LINE

    def __init__(self, world: World, host: str = "127.0.0.1", port: int = 0) -> None:
        super().__init__(world, host, port)
        self.powered = True

    # ------------------------------------------------------------ the command set

    def mode(self) -> str:
        if not self.powered:
            return "OFF"
        return "CONSTANT" if self.world.chamber.running else "STANDBY"

    def reply(self, line: str) -> str:
        return self.answer(line)

    def answer(self, command: str) -> str:
        """The reply to one command line (without its terminator)."""
        self.world.advance()
        head, _, arg = command.partition(",")
        head, arg = head.strip().upper(), arg.strip().upper()
        ch = self.world.chamber
        if head == "TEMP?":
            return (
                f"{ch.air_c:.1f},{ch.setpoint_c:.1f},"
                f"{ch.cfg.setpoint_high_c:.1f},{ch.cfg.setpoint_low_c:.1f}"
            )
        if head == "MON?":
            return f"{ch.air_c:.1f},,{self.mode()},{len(self._alarm_codes())}"
        if head == "MODE?":
            return self.mode()
        if head == "ALARM?":
            codes = self._alarm_codes()
            return ",".join(str(v) for v in [len(codes), *codes])
        if head == "ROM?":
            return f"{CONTROLLER} VER {ch.cfg.firmware}"
        if head == "TYPE?":
            return f"T,{CONTROLLER},{ch.cfg.setpoint_high_c:.0f}"
        if head == "HUMI?":
            return "NA:CONT NOT READY-1"
        setting = {"TEMP": self._temp, "MODE": self._mode, "POWER": self._power}.get(head)
        if setting is None:
            return "NA:CMD ERR"
        refusal = setting(arg)
        self.world.advance()
        return refusal or f"OK:{command}"

    def _alarm_codes(self) -> list[int]:
        ch = self.world.chamber
        return [STUCK_ALARM_CODE] if ch.stuck and ch.stuck_reports_fault else []

    def _temp(self, arg: str) -> str | None:
        if not arg.startswith("S"):
            return "NA:PARA ERR"  # limits (H, L) are set at the panel on this twin
        try:
            temp_c = float(arg[1:])
        except ValueError:
            return "NA:PARA ERR"
        cfg = self.world.chamber.cfg
        if not (math.isfinite(temp_c) and cfg.setpoint_low_c <= temp_c <= cfg.setpoint_high_c):
            return "NA:DATA OUT OF RANGE"
        self.world.chamber.setpoint_c = temp_c
        return None

    def _mode(self, arg: str) -> str | None:
        if not self.powered:
            return "NA:CHB NOT READY"
        if arg == "CONSTANT":
            self.world.chamber.set_running(True)
        elif arg in ("STANDBY", "OFF"):
            self.world.chamber.set_running(False)
            self.powered = arg != "OFF"
        elif arg.startswith("RUN"):
            return "NA:DATA NOT READY"  # the twin holds no programs
        else:
            return "NA:PARA ERR"
        return None

    def _power(self, arg: str) -> str | None:
        if arg not in ("ON", "OFF"):
            return "NA:PARA ERR"
        self.powered = arg == "ON"
        self.world.chamber.set_running(self.powered)
        return None
