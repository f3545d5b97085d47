"""LAN twins of the Keysight E36300 and Rigol DP800 supplies: a raw SCPI socket (one LF-ended
line per message, as their port 5025 / 5555 servers) over the world's supply.

The part's output (channel 1 unless configured) is the world's `SupplyModel`, the same one the
pty `SupplyTwin` serves, so the physics (CV/CC crossover, the `supply_short` fault) is shared;
the other outputs are unloaded `SupplyModel`s sharing its error queue. Each family only
rewrites its own syntax (channel lists, CHn arguments, compound messages) into the generic
commands `SupplyModel.handle` already serves. Fault hooks as the Modbus twins: `drop()` closes
every connection and refuses new ones until `restore()`; `delay_s` answers every message late.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable

import numpy as np

from drivers.sim.line_twin import LineTwin
from drivers.sim.supply import SupplyModel
from drivers.sim.world import World

log = logging.getLogger(__name__)
MAX_LINE_BYTES = 4096
CHANNELS = 3
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_ILLEGAL_PARAMETER = (-224, "Illegal parameter value")


class SupplyOutputs:
    """The outputs of a multi-output supply: the world's supply on `channel`, the rest idle."""

    def __init__(self, world: World, channel: int) -> None:
        if not 1 <= channel <= CHANNELS:
            raise ValueError(f"the part's supply channel must be 1..{CHANNELS}, not {channel}")
        self.main = world.supply
        self.channel = channel
        self._models: dict[int, SupplyModel] = {}
        for n in range(1, CHANNELS + 1):
            if n == channel:
                self._models[n] = self.main
            else:
                idle = SupplyModel(self.main.cfg, np.random.default_rng(n))
                idle.errors = self.main.errors  # one error queue per instrument
                self._models[n] = idle

    def model(self, channel: int) -> SupplyModel | None:
        """The output `channel`, or None (and -224 queued) if the supply has no such output."""
        found = self._models.get(channel)
        if found is None:
            self.main.errors.append(_ILLEGAL_PARAMETER)
        return found

    def reset(self) -> None:
        for model in self._models.values():
            model.reset()

    def errors_reply(self) -> str | None:
        return self.main.handle("SYST:ERR?")

    def undefined(self) -> None:
        self.main.errors.append((-113, "Undefined header"))


class ScpiLanTwin(LineTwin):
    """A raw SCPI socket server for one supply family; subclasses translate their syntax."""

    name = "SCPI supply"
    terminator = b"\n"
    max_line_bytes = MAX_LINE_BYTES
    overlong_closes = False  # an over-long message is discarded; the connection stays

    def __init__(
        self, world: World, host: str = "127.0.0.1", port: int = 0, channel: int = 1
    ) -> None:
        super().__init__(world, host, port)
        self.outputs = SupplyOutputs(world, channel)

    def endpoint(self) -> str:
        return f"TCPIP::{self.host}::{self.port}::SOCKET"

    def reply(self, line: str) -> str | None:
        """Empty lines are no message; the world advances to the message and past it."""
        if not line:
            return None
        self.world.advance()
        answer = self.handle(line)
        self.world.advance()
        return answer

    def handle(self, line: str) -> str | None:
        """One message line -> the reply line, or None for a setting."""
        raise NotImplementedError

    def _common(self, upper: str, identity: str) -> str | None | bool:
        """*IDN?, *RST and the error queue; False when `upper` is none of them."""
        if upper == "*IDN?":
            return identity
        if upper == "*RST":
            self.outputs.reset()
            return None
        if re.fullmatch(r":?SYST(EM)?:ERR(OR)?(:NEXT)?\?", upper):
            return self.outputs.errors_reply()
        return False


def _on_channel(
    outputs: SupplyOutputs, channel: int, command: str, fmt: Callable[[str], str] | None = None
) -> str | None:
    model = outputs.model(channel)
    if model is None:
        return None
    reply = model.handle(command)
    return fmt(reply) if reply is not None and fmt is not None else reply


# ---------------------------------------------------------------- Keysight E36300

_CHANNEL_LIST = re.compile(r"(?P<head>.*?)[\s,]*\(@(?P<ch>\d+)\)$")
_KEYSIGHT_HEADS = {
    "VOLT": "VOLT", "VOLTAGE": "VOLT", "SOUR:VOLT": "VOLT", "SOURCE:VOLTAGE": "VOLT",
    "CURR": "CURR", "CURRENT": "CURR", "SOUR:CURR": "CURR", "SOURCE:CURRENT": "CURR",
    "OUTP": "OUTP", "OUTPUT": "OUTP", "OUTP:STAT": "OUTP", "OUTPUT:STATE": "OUTP",
    "MEAS:VOLT": "MEAS:VOLT", "MEASURE:VOLTAGE": "MEAS:VOLT", "MEAS:VOLT:DC": "MEAS:VOLT",
    "MEAS:CURR": "MEAS:CURR", "MEASURE:CURRENT": "MEAS:CURR", "MEAS:CURR:DC": "MEAS:CURR",
}  # fmt: skip


def _keysight_number(reply: str) -> str:
    try:
        return f"{float(reply):+.8E}"
    except ValueError:
        return reply


class KeysightE36300Twin(ScpiLanTwin):
    """`VOLT 5,(@1)`, `OUTP 1,(@1)`, `MEAS:VOLT? (@1)`...; no channel list: output 1."""

    name = "Keysight E36300 twin"
    model_name = "E36312A"

    def handle(self, line: str) -> str | None:
        upper = " ".join(line.upper().split())
        cfg = self.outputs.main.cfg
        common = self._common(
            upper, f"Keysight Technologies,{self.model_name},{cfg.serial},{cfg.firmware}"
        )
        if common is not False:
            return common if isinstance(common, str) else None
        m = _CHANNEL_LIST.fullmatch(upper)
        command, channel = (m["head"], int(m["ch"])) if m else (upper, 1)
        head, _, arg = command.lstrip(":").partition(" ")
        query = head.endswith("?")
        generic = _KEYSIGHT_HEADS.get(head.rstrip("?"))
        if generic is None or (query == bool(arg.strip())):
            self.outputs.undefined()
            return None
        if query:
            fmt = None if generic == "OUTP" else _keysight_number
            return _on_channel(self.outputs, channel, generic + "?", fmt)
        return _on_channel(self.outputs, channel, f"{generic} {arg.strip()}")


# ---------------------------------------------------------------- Rigol DP800

_RIGOL_RULES: list[tuple[re.Pattern[str], str]] = [
    (re.compile(r"INST(?:RUMENT)?:NSEL(?:ECT)?\s+(?P<ch>\d+)"), "select"),
    (re.compile(r"INST(?:RUMENT)?(?::SEL(?:ECT)?)?\s+CH(?P<ch>\d+)"), "select"),
    (re.compile(rf"(?:SOUR(?:CE)?:)?(?P<what>VOLT|CURR)(?:AGE|ENT)?\s+(?P<value>{_NUMBER})"),
     "level"),
    (re.compile(r"(?:SOUR(?:CE)?:)?(?P<what>VOLT|CURR)(?:AGE|ENT)?\?"), "level?"),
    (re.compile(r"OUTP(?:UT)?(?::STAT(?:E)?)?\s+CH(?P<ch>\d+),(?P<on>ON|OFF|1|0)"), "output"),
    (re.compile(r"OUTP(?:UT)?(?::STAT(?:E)?)?\?\s+CH(?P<ch>\d+)"), "output?"),
    (re.compile(r"MEAS(?:URE)?(?::(?P<what>VOLT|CURR)(?:AGE|ENT)?)?(?::DC)?\?\s+CH(?P<ch>\d+)"),
     "measure?"),
    (re.compile(rf"APPL(?:Y)?\s+CH(?P<ch>\d+),(?P<v>{_NUMBER})(?:,(?P<i>{_NUMBER}))?"), "apply"),
    (re.compile(r"APPL(?:Y)?\?\s+CH(?P<ch>\d+),(?P<what>VOLT|CURR)(?:AGE|ENT)?"), "apply?"),
]  # fmt: skip


class RigolDp800Twin(ScpiLanTwin):
    """`:INST:NSEL 1;:VOLT 5`, `:OUTP CH1,ON`, `:OUTP? CH1` -> ON, `:MEAS:VOLT? CH1`...;
    compound messages (`;`) are run in order and their replies joined with `;`."""

    name = "Rigol DP800 twin"
    model_name = "DP832"

    def __init__(
        self, world: World, host: str = "127.0.0.1", port: int = 0, channel: int = 1
    ) -> None:
        super().__init__(world, host, port, channel)
        self.selected = 1

    def handle(self, line: str) -> str | None:
        replies = [self._one(part) for part in line.split(";") if part.strip()]
        answered = [r for r in replies if r is not None]
        return ";".join(answered) if answered else None

    def _one(self, part: str) -> str | None:
        upper = " ".join(part.upper().split()).replace(", ", ",")
        cfg = self.outputs.main.cfg
        common = self._common(upper, f"RIGOL TECHNOLOGIES,{self.model_name},{cfg.serial},00.01.16")
        if common is not False:
            if upper == "*RST":
                self.selected = 1
            return common if isinstance(common, str) else None
        for pattern, action in _RIGOL_RULES:
            m = pattern.fullmatch(upper.lstrip(":"))
            if m:
                return self._do(action, m.groupdict())
        self.outputs.undefined()
        return None

    def _do(self, action: str, g: dict[str, str | None]) -> str | None:
        ch_text = g.get("ch")
        ch = int(ch_text) if ch_text else self.selected
        what = g.get("what") or "VOLT"
        if action == "select":
            if self.outputs.model(ch) is not None:
                self.selected = ch
            return None
        if action == "level":
            return _on_channel(self.outputs, ch, f"{what} {g['value']}")
        if action in ("level?", "apply?"):
            return _on_channel(self.outputs, ch, f"{what}?", _rigol_level(what))
        if action == "output":
            on = "ON" if g["on"] in ("ON", "1") else "OFF"
            return _on_channel(self.outputs, ch, f"OUTP {on}")
        if action == "output?":
            return _on_channel(self.outputs, ch, "OUTP?", lambda r: "ON" if r == "1" else "OFF")
        if action == "measure?":
            return _on_channel(self.outputs, ch, f"MEAS:{what}?", _rigol_level(what))
        # apply: voltage, then the current limit if given
        _on_channel(self.outputs, ch, f"VOLT {g['v']}")
        if g.get("i"):
            _on_channel(self.outputs, ch, f"CURR {g['i']}")
        return None


def _rigol_level(what: str) -> Callable[[str], str]:
    digits = 3 if what == "VOLT" else 4

    def fmt(reply: str) -> str:
        try:
            return f"{float(reply):.{digits}f}"
        except ValueError:
            return reply

    return fmt


# the sim config's `instruments: supply:` names served on the LAN (`scpi` is the pty SupplyTwin)
LAN_SUPPLY_TWINS: dict[str, type[ScpiLanTwin]] = {
    "keysight-e36300": KeysightE36300Twin,
    "rigol-dp800": RigolDp800Twin,
}
