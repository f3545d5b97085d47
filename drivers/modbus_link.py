"""Modbus TCP client helpers shared by the rate table and chamber drivers.

Wraps pymodbus 3.16's synchronous client so a driver sees only register lists and the typed
exceptions of `drivers.errors`: a refused connection or a closed socket becomes
`ConnectionLost`, a reply later than the wall timeout `InstrumentTimeout`, a Modbus exception
response `ModbusRefused`. After a timeout the socket is closed, so a late reply can never be
taken for the answer to the next request; the next request reconnects.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TypeVar

from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from drivers.errors import ConnectionLost, InstrumentTimeout, ProtocolError
from drivers.fd_wait import use_poll
from drivers.protocols import InstrumentIdentity

log = logging.getLogger(__name__)

_DT = ModbusTcpClient.DATATYPE

EXCEPTION_TEXT = {
    1: "illegal function",
    2: "illegal data address (register not writable or not present)",
    3: "illegal data value (value out of range)",
    4: "device failure",
    6: "device busy",
}


class ModbusRefused(ProtocolError):  # noqa: N818 - named like drivers.errors
    """The device answered a request with a Modbus exception response."""

    def __init__(self, message: str, *, exception_code: int, instrument: str | None = None) -> None:
        super().__init__(message, instrument=instrument)
        self.exception_code = exception_code


# ---------------------------------------------------------------- register conversions


def u16_to_i16(value: int) -> int:
    return value - 0x10000 if value & 0x8000 else value


def i16_to_u16(value: int) -> int:
    if not -0x8000 <= value <= 0x7FFF:
        raise ValueError(f"{value} does not fit a signed 16-bit register")
    return value & 0xFFFF


def regs_to_u32(regs: Sequence[int]) -> int:
    """Two registers, high word first, as an unsigned 32-bit value."""
    return int(ModbusTcpClient.convert_from_registers(list(regs[:2]), _DT.UINT32))  # type: ignore[arg-type]


def regs_to_i32(regs: Sequence[int]) -> int:
    return int(ModbusTcpClient.convert_from_registers(list(regs[:2]), _DT.INT32))  # type: ignore[arg-type]


def i32_to_regs(value: int) -> list[int]:
    if not -(1 << 31) <= value < (1 << 31):
        raise ValueError(f"{value} does not fit a signed 32-bit register pair")
    return ModbusTcpClient.convert_to_registers(int(value), _DT.INT32)


def regs_to_str(regs: Sequence[int]) -> str:
    """ASCII, two characters per register, high byte first, NUL padded."""
    raw = b"".join(int(r).to_bytes(2, "big") for r in regs)
    return raw.split(b"\x00", 1)[0].decode("ascii", "replace").strip()


class Unwrapper:
    """Turns a wrapping counter into a continuous one (reads must come within half a wrap)."""

    def __init__(self, modulo: int) -> None:
        self._modulo = modulo
        self._last: int | None = None
        self._offset = 0

    def __call__(self, raw: int) -> int:
        if self._last is not None:
            step = raw - self._last
            if step < -(self._modulo >> 1):
                self._offset += self._modulo
            elif step > self._modulo >> 1:
                self._offset -= self._modulo
        self._last = raw
        return raw + self._offset


# ---------------------------------------------------------------- the link


class ModbusLink:
    """One Modbus TCP connection to one device, with typed errors and a lock.

    `timeout_s` is wall seconds for connecting and for each reply.
    """

    def __init__(
        self,
        host: str,
        port: int,
        *,
        device_id: int = 1,
        timeout_s: float = 1.0,
        instrument: str = "Modbus device",
    ) -> None:
        self.host = host
        self.port = port
        self.device_id = device_id
        self.timeout_s = timeout_s
        self.instrument = instrument
        self._lock = threading.Lock()
        self._client = ModbusTcpClient(host, port=port, timeout=timeout_s, retries=0)

    @property
    def where(self) -> str:
        return f"{self.instrument} at {self.host}:{self.port}"

    def connect(self) -> None:
        with self._lock:
            self._ensure_connected()

    def _ensure_connected(self) -> None:
        if self._client.connected:
            return
        use_poll()  # pymodbus waits with select(): any descriptor number (drivers/fd_wait.py)
        if not self._client.connect():
            raise ConnectionLost(
                f"cannot connect to the {self.where}: check that it is powered, its network "
                "cable is in and the address in the station configuration is right",
                instrument=self.instrument,
            )

    def _call(self, what: str, func: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Any:
        with self._lock:
            self._ensure_connected()
            try:
                response = func(*args, device_id=self.device_id, **kwargs)
            except ModbusIOException as exc:
                self._client.close()  # a late reply must not answer the next request
                raise InstrumentTimeout(
                    f"the {self.where} did not answer {what} within {self.timeout_s:g} s: "
                    "check the controller is running; the station reconnects on the next "
                    f"request ({exc})",
                    instrument=self.instrument,
                ) from exc
            except ConnectionException as exc:
                self._client.close()
                raise ConnectionLost(
                    f"the connection to the {self.where} dropped during {what}: check the "
                    f"network cable and the controller's power, then retry ({exc})",
                    instrument=self.instrument,
                ) from exc
            except ModbusException as exc:
                self._client.close()
                raise ProtocolError(
                    f"the {self.where} sent a reply that does not parse during {what}: {exc}",
                    instrument=self.instrument,
                ) from exc
            except OSError as exc:
                self._client.close()
                raise ConnectionLost(
                    f"socket error talking to the {self.where} during {what}: {exc}; check the "
                    "network cable and the controller's power, then retry",
                    instrument=self.instrument,
                ) from exc
        if response.isError():
            code = int(getattr(response, "exception_code", 0))
            raise ModbusRefused(
                f"the {self.where} refused {what}: Modbus exception {code} "
                f"({EXCEPTION_TEXT.get(code, 'unknown')})",
                exception_code=code,
                instrument=self.instrument,
            )
        return response

    def read(self, address: int, count: int) -> list[int]:
        """Holding registers `address`..`address+count-1` in one request."""
        what = f"a read of registers {address}..{address + count - 1}"
        response = self._call(what, self._client.read_holding_registers, address, count=count)
        regs = list(response.registers)
        if len(regs) != count:
            raise ProtocolError(
                f"the {self.where} returned {len(regs)} registers for {what}, expected {count}",
                instrument=self.instrument,
            )
        return regs

    def write(self, address: int, value: int) -> None:
        self._call(
            f"writing {value} to register {address}",
            self._client.write_register,
            address,
            value & 0xFFFF,
        )

    def write_many(self, address: int, values: Sequence[int]) -> None:
        """Consecutive registers in one request (a 32-bit pair must go this way)."""
        self._call(
            f"writing registers {address}..{address + len(values) - 1}",
            self._client.write_registers,
            address,
            [v & 0xFFFF for v in values],
        )

    def read_i32(self, address: int) -> int:
        return regs_to_i32(self.read(address, 2))

    def write_i32(self, address: int, value: int) -> None:
        self.write_many(address, i32_to_regs(value))

    def read_string(self, address: int, count: int) -> str:
        return regs_to_str(self.read(address, count))

    def close(self) -> None:
        with self._lock:
            self._client.close()


_Reg = TypeVar("_Reg", bound=int)


def read_identity(
    link: ModbusLink, model_reg: _Reg, serial_reg: _Reg, firmware_reg: _Reg,
    string_regs: Mapping[_Reg, int],
) -> InstrumentIdentity:
    """Model, serial and firmware strings read in one request (they sit in one block).

    The manufacturer is the model string's first word when it has more than one.
    """
    first = min(model_reg, serial_reg, firmware_reg)
    last = max(r + string_regs[r] for r in (model_reg, serial_reg, firmware_reg))
    regs = link.read(first, last - first)

    def text(reg: _Reg) -> str:
        at = reg - first
        return regs_to_str(regs[at : at + string_regs[reg]])

    model = text(model_reg)
    maker, _, rest = model.partition(" ")
    return InstrumentIdentity(
        manufacturer=maker if rest else "",
        model=model,
        serial=text(serial_reg),
        firmware=text(firmware_reg),
    )


def reopen_link(link: ModbusLink, timeout_s: float | None = None) -> None:
    """Close `link`'s connection and connect again, with a new reply timeout (wall s) if
    given: used by the safe-state pass to get through to a slow or re-plugged controller."""
    with link._lock:
        link._client.close()
        if timeout_s is not None:
            link.timeout_s = timeout_s
        link._client = ModbusTcpClient(link.host, port=link.port, timeout=link.timeout_s, retries=0)
        link._ensure_connected()
