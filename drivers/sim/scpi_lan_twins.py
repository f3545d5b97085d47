"""LAN twins of the Keysight E36300 and Rigol DP800 supplies: a raw SCPI socket (one LF-ended
message per line, as their port 5025 / 5555 servers) over the world's supply, and the same
instrument over VXI-11 (`drivers.sim.vxi11`).

The part's output (channel 1 unless configured) is the world's `SupplyModel`, the same one the
pty twin serves, so the physics (CV/CC crossover, the `supply_short` fault) is shared; the
other outputs are unloaded. The instrument itself (its commands, ranges, status model) is the
family's twin: `drivers.sim.keysight_twin`, `drivers.sim.rigol_twin`. Fault hooks as the
Modbus twins: `drop()` closes every connection and refuses new ones until `restore()`;
`delay_s` answers every message late.
"""

from __future__ import annotations

import logging

from drivers.sim.ieee488 import ScpiInstrument
from drivers.sim.keysight_twin import RANGES as KEYSIGHT_RANGES
from drivers.sim.keysight_twin import KeysightE36312A
from drivers.sim.line_twin import LineTwin
from drivers.sim.rigol_twin import RANGES as RIGOL_RANGES
from drivers.sim.rigol_twin import RigolDP832
from drivers.sim.supply import SupplyOutputs
from drivers.sim.vxi11 import Vxi11Server
from drivers.sim.world import World

log = logging.getLogger(__name__)
MAX_LINE_BYTES = 4096


class ScpiLanTwin(LineTwin):
    """A raw SCPI socket server for one supply family's instrument."""

    name = "SCPI supply"
    terminator = b"\n"
    max_line_bytes = MAX_LINE_BYTES
    overlong_closes = False  # an over-long message is discarded; the connection stays

    def __init__(
        self, world: World, host: str = "127.0.0.1", port: int = 0, channel: int = 1
    ) -> None:
        super().__init__(world, host, port)
        self.instrument = self.make_instrument(world, channel)
        self.vxi11 = Vxi11Server(self.reply, self.instrument.status.stb, host)

    def make_instrument(self, world: World, channel: int) -> ScpiInstrument:
        raise NotImplementedError

    def endpoint(self) -> str:
        return f"TCPIP::{self.host}::{self.port}::SOCKET"

    async def start(self) -> None:
        await super().start()
        if self.vxi11.port == 0:
            await self.vxi11.start()

    async def shutdown(self) -> None:
        await super().shutdown()
        await self.vxi11.shutdown()

    def vxi11_endpoint(self) -> str:
        """The same instrument as a VXI-11 resource (its port named: no portmapper)."""
        return self.vxi11.resource()

    def reply(self, line: str) -> str | None:
        """Empty lines are no message; the world advances to the message and past it."""
        if not line:
            return None
        self.world.advance()
        answer = self.handle(line)
        self.world.advance()
        return answer

    def handle(self, line: str) -> str | None:
        """One program message -> its response message, or None."""
        return self.instrument.handle(line)


class KeysightE36300Twin(ScpiLanTwin):
    """The Keysight E36312A on its SCPI socket (port 5025 on the instrument)."""

    name = "Keysight E36300 twin"

    def make_instrument(self, world: World, channel: int) -> ScpiInstrument:
        self.outputs = SupplyOutputs(world.supply, channel, KEYSIGHT_RANGES)
        cfg = world.supply.cfg
        return KeysightE36312A(self.outputs, cfg.serial, cfg.firmware)


class RigolDp800Twin(ScpiLanTwin):
    """The Rigol DP832 on its SCPI socket (port 5555 on the instrument)."""

    name = "Rigol DP800 twin"

    def make_instrument(self, world: World, channel: int) -> ScpiInstrument:
        self.outputs = SupplyOutputs(world.supply, channel, RIGOL_RANGES)
        return RigolDP832(self.outputs, world.supply.cfg.serial)


# the sim config's `instruments: supply:` names served on the LAN (`scpi` is the pty twin)
LAN_SUPPLY_TWINS: dict[str, type[ScpiLanTwin]] = {
    "keysight-e36300": KeysightE36300Twin,
    "rigol-dp800": RigolDp800Twin,
}
