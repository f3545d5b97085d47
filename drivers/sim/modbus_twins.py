"""Modbus TCP twins of the rate table and the chamber, served with pymodbus 3.16.

The registers are `pymodbus.simulator.SimDevice` blocks; the `action` callback runs on every
request and fills them from the world at the request time (so the table's 22..29 snapshot is
exact and consistent), applies writes to the world, and refuses writes to read-only
registers (exception 2) or bad values (exception 3). Fault hooks: drop (stop listening and
close every connection) and delay (answer late).
"""

from __future__ import annotations

import asyncio
import functools
import logging
from collections.abc import Awaitable, Callable

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from drivers import chamber_map as cm
from drivers import rate_table_map as rm
from drivers.servo_profile import ServoProfile, load_profile
from drivers.sim.profile_image import ProfileImage
from drivers.sim.table import REGISTER_COUNT, CommandRefusedError
from drivers.sim.world import World

log = logging.getLogger(__name__)

Action = Callable[
    [int, int, int, int, list[int], list[int] | list[bool] | None], Awaitable[ExcCodes | None]
]


class ModbusTwin:
    """One instrument's Modbus TCP server on loopback, with drop/delay fault hooks."""

    def __init__(self, name: str, blocks: list[SimData], host: str, port: int) -> None:
        self.name = name
        self.host = host
        self.port = port
        self.delay_s = 0.0
        self.dropped = False
        self.requests = 0
        self._blocks = blocks
        self._server: ModbusTcpServer | None = None

    async def start(self) -> None:
        device = SimDevice(id=rm.DEVICE_ID, simdata=self._blocks, action=self._action)
        # pymodbus 3.16 routes a request for an unknown device id to device 0 and raises
        # KeyError (logged with a traceback and hex dumps) when there is none: device 0
        # answers every such request cleanly with "gateway target failed to respond" (0x0B)
        fallback = SimDevice(id=0, simdata=self._blocks, action=self._unknown_device)
        self._server = ModbusTcpServer([device, fallback], address=(self.host, self.port))
        await self._server.serve_forever(background=True)
        sockets = getattr(self._server.transport, "sockets", None)
        if sockets:
            self.port = sockets[0].getsockname()[1]
        # listen again on the same port after a drop fault (pymodbus bound port 0 at init)
        self._server.call_create = functools.partial(
            asyncio.get_running_loop().create_server,
            self._server.handle_new_connection,
            self.host,
            self.port,
            reuse_address=True,
            start_serving=True,
        )

    async def _unknown_device(
        self,
        fc: int,
        start: int,
        address: int,
        count: int,
        registers: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        log.info("%s: request for an unknown device id refused (exception 0x0B)", self.name)
        return ExcCodes.GATEWAY_NO_RESPONSE

    @property
    def endpoint(self) -> str:
        return f"{self.host}:{self.port}"

    async def _action(
        self,
        fc: int,
        start: int,
        address: int,
        count: int,
        registers: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        self.requests += 1
        if self.delay_s > 0:
            await asyncio.sleep(self.delay_s)
        return await self.handle(fc, start, address, count, registers, values)

    async def handle(
        self,
        fc: int,
        start: int,
        address: int,
        count: int,
        registers: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        raise NotImplementedError

    async def drop(self) -> None:
        """Stop listening and close every open connection (a pulled cable, a crashed unit)."""
        if self._server is not None and not self.dropped:
            self.dropped = True
            self._server.close()

    async def restore(self) -> None:
        if self._server is not None and self.dropped:
            self.dropped = False
            if not await self._server.listen():
                log.error("%s: could not listen again on %s", self.name, self.endpoint)

    async def shutdown(self) -> None:
        if self._server is not None:
            await self._server.shutdown()
            self._server = None


PAIR_STARTS = frozenset(
    int(r) for r in (rm.Reg.POS_CMD, rm.Reg.RATE_CMD, rm.Reg.ACCEL_LIMIT, rm.Reg.MOVE_TIME)
)  # the writable 32-bit registers: each is written whole, both words in one request


def splits_pair(address: int, count: int) -> bool:
    """True when registers [address, address + count) hold only one word of a writable
    32-bit pair: a torn value that the controller must refuse."""
    covered = set(range(address, address + count))
    return any((p in covered) != (p + 1 in covered) for p in PAIR_STARTS)


class TableTwin(ModbusTwin):
    """The rate table's Modbus TCP server. With no `profile` it serves the controller's own
    map (`drivers.rate_table_map`, registers 0..63); given a servo profile (an object, a
    built-in profile's name or a file path), it serves that profile's layout over the same
    table model (`drivers.sim.profile_image`)."""

    def __init__(
        self, world: World, host: str = "127.0.0.1", port: int = 0,
        profile: ServoProfile | str | None = None,
    ) -> None:
        self.world = world
        self.image: ProfileImage | None = None
        if profile is not None:
            loaded = load_profile(profile) if isinstance(profile, str) else profile
            self.image = ProfileImage(loaded, world.table)
            first, count = self.image.first, self.image.count
        else:
            first, count = 0, REGISTER_COUNT
        blocks = [SimData(address=first, count=count, values=0, datatype=DataType.REGISTERS)]
        super().__init__("rate table", blocks, host, port)

    async def handle(
        self,
        fc: int,
        start: int,
        address: int,
        count: int,
        registers: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        if self.image is not None:
            return self._handle_profile(address, registers, values)
        table = self.world.table
        t = self.world.advance()
        if values is not None:
            hook = getattr(self, "before_write", None)
            if hook is not None:  # samples due before this command must see the old motion
                hook(t)
            if any(a not in rm.WRITABLE for a in range(address, address + count)):
                return ExcCodes.ILLEGAL_ADDRESS
            if splits_pair(address, count):
                log.info(
                    "rate table refused a write to %d..%d: it covers one register of a 32-bit "
                    "pair (write both in one request)",
                    address,
                    address + count - 1,
                )
                return ExcCodes.ILLEGAL_ADDRESS
            try:
                table.write(t, address, [int(v) for v in values], table.registers(t))
            except CommandRefusedError as exc:
                log.info("rate table refused a write: %s", exc)
                return ExcCodes.ILLEGAL_VALUE
        registers[0:REGISTER_COUNT] = table.registers(t)
        return None

    def _handle_profile(
        self, address: int, registers: list[int], values: list[int] | list[bool] | None
    ) -> ExcCodes | None:
        image = self.image
        assert image is not None
        t = self.world.advance()
        if values is not None:
            hook = getattr(self, "before_write", None)
            if hook is not None:
                hook(t)
            refused = image.write(t, address, [int(v) for v in values])
            if refused is not None:
                log.info("rate table refused a write at %d: %s", address, refused.name)
                return refused
        registers[0 : image.count] = image.image(t)
        return None


class ChamberTwin(ModbusTwin):
    def __init__(self, world: World, host: str = "127.0.0.1", port: int = 0) -> None:
        def block(address: int, count: int) -> SimData:
            return SimData(address=address, count=count, values=0, datatype=DataType.REGISTERS)

        blocks = [
            block(cm.Reg.MODEL, 20),
            block(cm.Reg.PROCESS_VALUE, 1),
            block(cm.Reg.STATE, 1),
            block(cm.Reg.SETPOINT, 1),
            block(cm.Reg.SP_LIMIT_LOW, 2),
            block(cm.Reg.RUN, 2),
        ]
        super().__init__("chamber", blocks, host, port)
        self.world = world

    async def handle(
        self,
        fc: int,
        start: int,
        address: int,
        count: int,
        registers: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        chamber = self.world.chamber
        self.world.advance()
        if values is not None:
            if any(a not in cm.WRITABLE for a in range(address, address + count)):
                return ExcCodes.ILLEGAL_ADDRESS
            try:
                for i, v in enumerate(values):
                    chamber.write(address + i, int(v))
            except ValueError as exc:
                log.info("chamber refused a write: %s", exc)
                return ExcCodes.ILLEGAL_VALUE
            self.world.advance()
        for reg, value in chamber.registers().items():
            registers[reg - start] = value
        return None
