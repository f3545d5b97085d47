"""Twin of an ACUTROL-controlled rate table: the dialect of `drivers.acutrol_codes` on TCP.

It drives the world's `TableModel` (the same physics the Modbus `TableTwin` serves): each
command becomes the register write the servo controller would get (mode, demands and the
mode's acceleration limit in one write, so a motion is planned once), and every query reads
the model at the line's world time, so one line is one consistent snapshot. World faults
surface as the status word, `:fault?` and `ERR` replies (201 safety interlock open, 202 fault
latched, 203 e-stop). Fault hooks as the Modbus twins: `drop()`/`restore()` and `delay_s`.
Position-mode moves are trapezoids at the mode's acceleration limit and the simulated
table's `slew_rate_dps` (a `:limit:rate pos` lower than that is stored, not applied).
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from drivers.acutrol_codes import MANUFACTURER, Err, Fault, StatusBit
from drivers.rate_table_map import MAX_RATE_DPS, Control, Mode, Reg, Status
from drivers.rate_table_map import Fault as NativeFault
from drivers.sim.line_twin import LineTwin
from drivers.sim.table import CommandRefusedError
from drivers.sim.world import World

log = logging.getLogger(__name__)

_KEYWORDS = (
    "interlock", "close", "open", "reset", "mode", "rate", "position", "off", "demand", "limit",
    "acceleration", "absolute", "read", "status", "fault", "system", "time",
)
_FAULTS = {
    NativeFault.NONE: Fault.NONE,
    NativeFault.OVERSPEED: Fault.OVERSPEED,
    NativeFault.FOLLOWING_ERROR: Fault.FOLLOWING_ERROR,
    NativeFault.ENCODER_LOSS: Fault.TRANSDUCER,
    NativeFault.ESTOP: Fault.ESTOP,
}
_MODE_NAMES = {"off": "Off", "rate": "Rate", "position": "Position"}
_NATIVE_MODE = {"off": Mode.IDLE, "rate": Mode.RATE, "position": Mode.POSITION}


class CommandError(Exception):
    """One command refused: becomes the line's `ERR <code>,"<text>"` reply."""

    def __init__(self, code: Err, text: str) -> None:
        super().__init__(text)
        self.code = code
        self.text = text


def _keyword(word: str) -> str:
    """A header keyword in full from its long form or a prefix of 3+ letters (`int`, `dem`)."""
    w = word.lower()
    for k in _KEYWORDS:
        if w == k or (len(w) >= 3 and k.startswith(w)):
            return k
    raise CommandError(Err.UNDEFINED_HEADER, f"Undefined header {word!r}")


class AcutrolTwin(LineTwin):
    """The ACUTROL command interface of the simulated table on `host:port` (0: any free)."""

    name = "ACUTROL twin"
    max_line_bytes = 65536

    def __init__(self, world: World, host: str = "127.0.0.1", port: int = 0) -> None:
        super().__init__(world, host, port)
        self.before_write: Callable[[float], None] | None = None
        cfg = world.table.cfg
        self.mode = "off"
        self.rate_demand_dps = 0.0
        self.position_demand_deg = 0.0
        self.accel_dps2 = {"rate": cfg.accel_limit_dps2, "position": cfg.accel_limit_dps2}
        self.rate_limit_dps = {"rate": MAX_RATE_DPS, "position": cfg.slew_rate_dps}

    # ------------------------------------------------------------ one line

    def reply(self, line: str) -> str:
        return self.handle_line(line)

    def handle_line(self, line: str) -> str:
        """The reply to one request line, all of it at one world time."""
        t = self.world.advance()
        results: list[str] = []
        prefix: list[str] = []
        hooked = False
        try:
            for part in (p.strip() for p in line.split(";")):
                if not part:
                    continue
                header, _, args_text = part.partition(" ")
                args = [a.strip() for a in args_text.split(",")] if args_text.strip() else []
                if header.startswith("*"):
                    results.append(self._common(header.upper()))
                    continue
                query = header.endswith("?")
                words = [w for w in header.rstrip("?").split(":") if w]
                path = [_keyword(w) for w in words]
                if not header.startswith(":"):
                    path = prefix + path
                prefix = path[:-1]
                if query:
                    results.append(self._query(t, tuple(path), args))
                else:
                    if not hooked and self.before_write is not None:
                        self.before_write(t)  # samples due before the command see the old motion
                        hooked = True
                    self._command(t, tuple(path), args)
        except CommandError as exc:
            log.info("ACUTROL twin refused %r: %s", line, exc.text)
            return f'ERR {int(exc.code)},"{exc.text}"'
        return ";".join(results) if results else "OK"

    # ------------------------------------------------------------ parameters

    def _axis(self, args: list[str], at: int = 0) -> None:
        if len(args) <= at:
            raise CommandError(Err.MISSING_PARAMETER, "Missing parameter: axis number")
        if args[at] != "1":
            raise CommandError(Err.OUT_OF_RANGE, f"Data out of range: no axis {args[at]}")

    @staticmethod
    def _number(args: list[str], at: int, what: str) -> float:
        if len(args) <= at:
            raise CommandError(Err.MISSING_PARAMETER, f"Missing parameter: {what}")
        try:
            value = float(args[at])
        except ValueError:
            raise CommandError(Err.DATA_TYPE, f"Data type error: {what} {args[at]!r}") from None
        if value != value or value in (float("inf"), float("-inf")):
            raise CommandError(Err.DATA_TYPE, f"Data type error: {what} {args[at]!r}")
        return value

    @staticmethod
    def _mode_arg(args: list[str]) -> str:
        if not args:
            raise CommandError(Err.MISSING_PARAMETER, "Missing parameter: rate or pos")
        try:
            return {"rate": "rate", "pos": "position", "position": "position"}[args[0].lower()]
        except KeyError:
            raise CommandError(Err.DATA_TYPE, f"Data type error: mode {args[0]!r}") from None

    # ------------------------------------------------------------ queries

    def _common(self, header: str) -> str:
        if header == "*IDN?":
            cfg = self.world.table.cfg
            return f"{MANUFACTURER},{cfg.model},{cfg.serial},{cfg.firmware}"
        if header == "*STB?":
            return str(self._status_word(self.world.advance()))
        raise CommandError(Err.UNDEFINED_HEADER, f"Undefined header {header!r}")

    def _status_word(self, t: float) -> int:
        table = self.world.table
        native = Status(table.status_bits(t))
        word = StatusBit(0)
        for ours, theirs in (
            (StatusBit.READY, Status.READY), (StatusBit.CLOSED, Status.ENABLED),
            (StatusBit.FAULT, Status.FAULT), (StatusBit.IN_POSITION, Status.IN_POSITION),
            (StatusBit.AT_RATE, Status.AT_RATE), (StatusBit.MOVING, Status.MOVING),
            (StatusBit.SAFETY_OPEN, Status.INTERLOCK_OPEN),
        ):
            if theirs in native:
                word |= ours
        if table.estop_pressed:
            word |= StatusBit.ESTOP
        return int(word)

    def _query(self, t: float, path: tuple[str, ...], args: list[str]) -> str:
        table = self.world.table
        if path == ("system", "time"):
            return f"{t:.6f}"
        if path[:1] == ("limit",) and path[1:] in (("acceleration",), ("rate",)):
            mode = self._mode_arg(args)
            self._axis(args, 1)
            values = self.accel_dps2 if path[1] == "acceleration" else self.rate_limit_dps
            return f"{values[mode]:.6f}"
        self._axis(args)
        if path == ("read", "position"):
            return f"{table.counts_since_zero(t) * 360.0 / table.cpr:.7f}"
        if path == ("read", "rate"):
            return f"{float(table.rate_dps(t)[0]):.6f}"
        if path == ("read", "acceleration"):
            dt = 1e-3
            rates = table.rate_dps([t - dt, t + dt])
            return f"{float(rates[1] - rates[0]) / (2 * dt):.6f}"
        if path == ("status",):
            return str(self._status_word(t))
        if path == ("fault",):
            return str(int(_FAULTS[table.fault]))
        if path == ("interlock",):
            if table.fault != NativeFault.NONE:
                return "Fault"
            return "Closed" if table.enabled else "Open"
        if path == ("mode",):
            return _MODE_NAMES[self.mode]
        if path == ("limit", "absolute"):
            cfg = table.cfg
            return (
                f"{MAX_RATE_DPS:.3f},{cfg.max_accel_dps2:.3f},0.000,-1000000.000,1000000.000,"
                f"{1.1 * MAX_RATE_DPS:.3f}"
            )
        raise CommandError(Err.UNDEFINED_HEADER, f"Undefined header {':'.join(path)}?")

    # ------------------------------------------------------------ commands

    def _command(self, t: float, path: tuple[str, ...], args: list[str]) -> None:
        if path[:1] == ("limit",) and path[1:] in (("acceleration",), ("rate",)):
            self._set_limit(t, path[1], self._mode_arg(args), args)
            return
        if path != ("interlock", "reset") or args:  # a reset without an axis resets all
            self._axis(args)
        if path[:1] == ("interlock",) and len(path) == 2:
            self._interlock(t, path[1])
        elif path[:1] == ("mode",) and len(path) == 2 and path[1] in _NATIVE_MODE:
            self._set_mode(t, path[1])
        elif path in (("demand", "rate"), ("demand", "position")):
            self._demand(t, path[1], self._number(args, 1, path[1]))
        else:
            raise CommandError(Err.UNDEFINED_HEADER, f"Undefined header {':'.join(path)}")

    def _interlock(self, t: float, action: str) -> None:
        table = self.world.table
        regs = table.registers(t)
        if action == "close":
            if table.interlock_open:
                raise CommandError(Err.SAFETY_OPEN, "Safety interlock open: close the door")
            if table.estop_pressed:
                raise CommandError(Err.ESTOP, "Emergency stop pressed: release it")
            if table.fault != NativeFault.NONE:
                raise CommandError(Err.FAULT_LATCHED, "Fault latched: reset the interlock")
            # closing holds the axis where it is: it never resumes a demand from before
            self.rate_demand_dps = 0.0
            self.position_demand_deg = table.counts_since_zero(t) * 360.0 / table.cpr
            self._push(t)
            table.write(t, Reg.CONTROL, [int(Control.ENABLE)], table.registers(t))
        elif action == "open":
            table.write(t, Reg.CONTROL, [0], regs)
        elif action == "reset":
            if table.estop_pressed:
                raise CommandError(Err.ESTOP, "Emergency stop pressed: release it")
            keep = regs[Reg.CONTROL] & int(Control.ENABLE)
            table.write(t, Reg.CONTROL, [keep | int(Control.FAULT_RESET)], regs)
        else:
            raise CommandError(Err.UNDEFINED_HEADER, f"Undefined header interlock:{action}")

    def _set_mode(self, t: float, mode: str) -> None:
        if mode != self.mode:
            table = self.world.table
            self.rate_demand_dps = 0.0
            self.position_demand_deg = table.counts_since_zero(t) * 360.0 / table.cpr
            self.mode = mode
        self._push(t)

    def _demand(self, t: float, kind: str, value: float) -> None:
        if kind != self.mode:
            raise CommandError(
                Err.SETTINGS_CONFLICT, f"Settings conflict: the axis is not in {kind} mode"
            )
        if kind == "rate":
            if abs(value) > self.rate_limit_dps["rate"]:
                raise CommandError(
                    Err.OUT_OF_RANGE,
                    f"Data out of range: rate {value:g} beyond the limit "
                    f"{self.rate_limit_dps['rate']:g}",
                )
            self.rate_demand_dps = value
        else:
            self.position_demand_deg = value
        self._push(t)

    def _set_limit(self, t: float, which: str, mode: str, args: list[str]) -> None:
        self._axis(args, 1)
        value = self._number(args, 2, f"{which} limit")
        cfg = self.world.table.cfg
        top = cfg.max_accel_dps2 if which == "acceleration" else MAX_RATE_DPS
        if not 0 < value <= top:
            raise CommandError(
                Err.OUT_OF_RANGE, f"Data out of range: {which} limit {value:g} not in (0, {top:g}]"
            )
        (self.accel_dps2 if which == "acceleration" else self.rate_limit_dps)[mode] = value
        if mode == self.mode:
            self._push(t)

    def _push(self, t: float) -> None:
        """Write mode, demands and the mode's acceleration limit to the controller at once."""
        table = self.world.table
        regs = table.registers(t)
        block = list(regs[Reg.MODE : Reg.MOVE_TIME + 2])

        def put(reg: Reg, value: float) -> None:
            v = int(round(value * 1000.0)) & 0xFFFFFFFF
            block[reg - Reg.MODE : reg - Reg.MODE + 2] = [v >> 16, v & 0xFFFF]

        block[0] = int(_NATIVE_MODE[self.mode])
        put(Reg.POS_CMD, self.position_demand_deg)
        put(Reg.RATE_CMD, self.rate_demand_dps)
        accel = self.accel_dps2["rate" if self.mode == "rate" else "position"]
        put(Reg.ACCEL_LIMIT, accel)
        put(Reg.MOVE_TIME, 0.0)
        try:
            table.write(t, Reg.MODE, block, regs)
        except CommandRefusedError as exc:
            raise CommandError(Err.OUT_OF_RANGE, f"Data out of range: {exc}") from None

