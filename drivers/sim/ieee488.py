"""IEEE 488.2 status reporting and common commands, and the commands SCPI-1999 requires of
every instrument (SYSTem:ERRor, SYSTem:VERSion, STATus:OPERation, STATus:QUEStionable,
STATus:PRESet), for the simulated bench's SCPI twins.

The status model (IEEE 488.2 ch. 11, SCPI-1999 vol. 1 ch. 9): every refused unit queues its
error and sets its class's bit in the standard event status register (ESR: -1xx command error
bit 5, -2xx execution error bit 4, -3xx and device-specific codes bit 3, -4xx query error bit
2); the status byte (STB) sums the error queue (bit 2), QUEStionable (bit 3), a reply waiting
(MAV, bit 4), ESR & ESE (bit 5) and OPERation (bit 7), and bit 6 when any of them is enabled
in SRE. A twin completes every command before it reads the next one, so `*OPC` sets the OPC
bit and `*OPC?` answers 1 at once, and `*WAI` returns at once. `*CLS` empties the queue and the
event registers; `*RST` resets the device's settings, never the status reporting.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from drivers.sim.scpi_syntax import (
    UNDEFINED_HEADER,
    Refused,
    Unit,
    integer,
    match,
    units,
)

OPC, RQC, QYE, DDE, EXE, CME, URQ, PON = (1 << b for b in range(8))  # ESR bits
EAV, QUES_SUMMARY, MAV, ESB, MSS, OPER_SUMMARY = 4, 8, 16, 32, 64, 128  # STB bits
SCPI_VERSION = "1999.0"


def event_bit(code: int) -> int:
    """The ESR bit an error sets (SCPI-1999 vol. 2, 21.8: the error's class)."""
    if -199 <= code <= -100:
        return CME
    if -299 <= code <= -200:
        return EXE
    if -499 <= code <= -400:
        return QYE
    return DDE  # -3xx device-specific, and the instrument's own positive codes


@dataclass
class Register:
    """A SCPI status register: condition, event (latched on a rising condition), enable."""

    condition: int = 0
    event: int = 0
    enable: int = 0

    def set_condition(self, value: int) -> None:
        self.event |= value & ~self.condition
        self.condition = value

    def summary(self) -> bool:
        return bool(self.event & self.enable)

    def read_event(self) -> int:
        event, self.event = self.event, 0
        return event


class StatusModel:
    """The error queue and the registers behind *ESR?, *STB? and STATus."""

    def __init__(self, queue_size: int = 20) -> None:
        self.queue_size = queue_size
        self.errors: deque[tuple[int, str]] = deque()
        self.esr = PON  # set at power-on (IEEE 488.2 11.5.1.1.2)
        self.ese = 0
        self.sre = 0
        self.questionable = Register()
        self.operation = Register()

    def push(self, code: int, text: str) -> None:
        """Queue an error; a full queue's last entry becomes -350 (SCPI-1999 vol. 2, 21.8)."""
        if len(self.errors) >= self.queue_size:
            self.errors[-1] = (-350, "Queue overflow")
        else:
            self.errors.append((code, text))
        self.esr |= event_bit(code)

    def next_error(self) -> tuple[int, str]:
        return self.errors.popleft() if self.errors else (0, "No error")

    def stb(self, reply_waiting: bool = False) -> int:
        value = 0
        if self.errors:
            value |= EAV
        if self.questionable.summary():
            value |= QUES_SUMMARY
        if reply_waiting:
            value |= MAV
        if self.esr & self.ese:
            value |= ESB
        if self.operation.summary():
            value |= OPER_SUMMARY
        if value & self.sre:
            value |= MSS
        return value

    def clear(self) -> None:
        """*CLS: the error queue and every event register empty."""
        self.errors.clear()
        self.esr = 0
        self.questionable.event = 0
        self.operation.event = 0


class ScpiInstrument:
    """A SCPI instrument's message handling: the common commands and SCPI-1999's required
    ones here; a twin adds its own command set in `command` and its settings in `reset`.

    Class settings are how the maker writes replies: `signed` NR1 (`+0` on Keysight, `0` on
    Rigol), `self_test` (what *TST? answers when the test passes)."""

    signed = True
    self_test = "+0"
    queue_size = 20

    def __init__(self) -> None:
        self.status = StatusModel(self.queue_size)
        self._replies: list[str] = []

    # ------------------------------------------------------------ for a twin to give

    @property
    def identity(self) -> str:
        raise NotImplementedError

    def reset(self) -> None:
        """*RST: the device's settings to their reset values."""

    def command(self, unit: Unit) -> str | None:
        """The instrument's own command set; `Refused` (UNDEFINED_HEADER) for anything else."""
        raise UNDEFINED_HEADER

    def conditions(self) -> tuple[int, int]:
        """(QUEStionable, OPERation) condition bits now."""
        return 0, 0

    # ------------------------------------------------------------ serving a message

    def handle(self, message: str) -> str | None:
        """One program message -> its response message (the queries' replies joined by
        `;`), or None when it held no query. A command error ends the message there
        (IEEE 488.2 6.1.6.1.1); an execution error only its own unit."""
        self._replies = []
        try:
            for unit in units(message):
                try:
                    reply = self._unit(unit)
                except Refused as refused:
                    self.status.push(refused.code, refused.text)
                    if event_bit(refused.code) == CME:
                        break
                    continue
                if reply is not None:
                    self._replies.append(reply)
        except Refused as refused:  # a header that does not parse
            self.status.push(refused.code, refused.text)
        replies, self._replies = self._replies, []
        return ";".join(replies) if replies else None

    def nr1(self, value: int) -> str:
        return f"{value:+d}" if self.signed else str(value)

    def error_reply(self, code: int, text: str) -> str:
        return f'{self.nr1(code)},"{text}"'

    def _unit(self, unit: Unit) -> str | None:
        if unit.common:
            return self._common(unit)
        handled, reply = self._required(unit)
        return reply if handled else self.command(unit)

    def _common(self, unit: Unit) -> str | None:
        name, s = unit.nodes[0], self.status
        if len(unit.nodes) != 1:
            raise UNDEFINED_HEADER
        if unit.query:
            unit.arity(0)
            queries = {
                "*IDN": lambda: self.identity,
                "*ESE": lambda: self.nr1(s.ese),
                "*ESR": self._read_esr,
                "*SRE": lambda: self.nr1(s.sre),
                "*STB": lambda: self.nr1(s.stb(bool(self._replies))),
                "*OPC": lambda: "1",
                "*TST": lambda: self.self_test,
            }
            if name not in queries:
                raise UNDEFINED_HEADER
            return queries[name]()
        if name in ("*ESE", "*SRE"):
            value = integer(unit.arity(1)[0], 0, 255)
            if name == "*ESE":
                s.ese = value
            else:
                s.sre = value & ~MSS  # bit 6 cannot be enabled (IEEE 488.2 11.3.2.3)
            return None
        actions = {"*CLS": s.clear, "*OPC": self._operation_complete, "*WAI": lambda: None,
                   "*RST": self.reset}  # fmt: skip
        if name not in actions:
            raise UNDEFINED_HEADER
        unit.arity(0)
        actions[name]()
        return None

    def _read_esr(self) -> str:
        value, self.status.esr = self.status.esr, 0
        return self.nr1(value)

    def _operation_complete(self) -> None:
        self.status.esr |= OPC

    def _required(self, unit: Unit) -> tuple[bool, str | None]:
        """SCPI-1999 4.2.1's required commands: (handled, reply)."""
        s = self.status
        if match(unit, "SYSTem:ERRor[:NEXT]", query=True) is not None:
            unit.arity(0)
            return True, self.error_reply(*s.next_error())
        if match(unit, "SYSTem:VERSion", query=True) is not None:
            unit.arity(0)
            return True, SCPI_VERSION
        if match(unit, "STATus:PRESet", query=False) is not None:
            unit.arity(0)
            s.questionable.enable = s.operation.enable = 0
            return True, None
        for word, register in (("QUEStionable", s.questionable), ("OPERation", s.operation)):
            handled, reply = self._register(unit, word, register)
            if handled:
                return True, reply
        return False, None

    def _register(self, unit: Unit, word: str, register: Register) -> tuple[bool, str | None]:
        ques, oper = self.conditions()
        self.status.questionable.set_condition(ques)
        self.status.operation.set_condition(oper)
        if match(unit, f"STATus:{word}[:EVENt]", query=True) is not None:
            unit.arity(0)
            return True, self.nr1(register.read_event())
        if match(unit, f"STATus:{word}:CONDition", query=True) is not None:
            unit.arity(0)
            return True, self.nr1(register.condition)
        if match(unit, f"STATus:{word}:ENABle") is not None:
            if unit.query:
                unit.arity(0)
                return True, self.nr1(register.enable)
            register.enable = integer(unit.arity(1)[0], 0, 65535)
            return True, None
        return False, None
