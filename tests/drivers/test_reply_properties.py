"""Property-based tests of the drivers' reply decoding (hypothesis): whatever a Modbus
instrument or the SCPI supply answers, a driver call returns a decoded value or raises one of
drivers/errors.py's typed InstrumentErrors, within its timeout; never another exception,
never a hang. Replies come from the byte-level fakes (tests/drivers/_fakes.py)."""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.chamber import ModbusChamber
from drivers.errors import InstrumentError, InstrumentTimeout
from drivers.modbus_link import ModbusLink
from drivers.rate_table import ModbusRateTable
from drivers.supply import ScpiSupply
from tests.drivers._fakes import ManualClock
from tests.drivers.expected_protocol import MODBUS, Pair, TcpPeer

TIMEOUT_S = 0.25
SETTINGS = settings(
    max_examples=30,
    deadline=None,  # the wall time is asserted below, with room for a loaded machine
    suppress_health_check=[HealthCheck.too_slow],
)

# a Modbus reply PDU: any bytes, or a well-formed register read of any length and values
modbus_replies = st.one_of(
    st.binary(max_size=40),
    st.lists(st.integers(0, 0xFFFF), max_size=40).map(
        lambda regs: struct.pack(f">BB{len(regs)}H", 3, 2 * len(regs), *regs)
    ),
    st.tuples(st.integers(0x80, 0xFF), st.integers(0, 255)).map(bytes),  # exception replies
)

TABLE_CALLS: dict[str, Callable[[ModbusRateTable], Any]] = {
    "read_status": lambda t: t.read_status(),
    "check": lambda t: t.check(),
    "identify": lambda t: t.identify(),
}
CHAMBER_CALLS: dict[str, Callable[[ModbusChamber], Any]] = {
    "read_state": lambda c: c.read_state(),
    "read_temperature": lambda c: c.read_temperature(),
    "setpoint_limits": lambda c: c.setpoint_limits(),
    "identify": lambda c: c.identify(),
}


def _modbus_call(make: Callable[[ModbusLink], Any], call: Callable[[Any], Any],
                 reply: bytes) -> Any:
    server = TcpPeer([Pair(b"", reply)], MODBUS)  # any request gets this reply
    link = ModbusLink("127.0.0.1", server.port, timeout_s=TIMEOUT_S, instrument="instrument")
    t0 = time.monotonic()
    try:
        return call(make(link))
    except InstrumentError as exc:
        assert str(exc), "a typed error without a message"
        return exc
    finally:
        link.close()
        server.close()
        assert time.monotonic() - t0 < 10 * TIMEOUT_S + 2.0


@pytest.mark.parametrize("name", sorted(TABLE_CALLS))
@SETTINGS
@given(reply=modbus_replies)
def test_any_table_reply_decodes_or_raises_a_typed_error(name: str, reply: bytes) -> None:
    out = _modbus_call(lambda link: ModbusRateTable(link, ManualClock()), TABLE_CALLS[name],
                       reply)
    if name == "read_status" and not isinstance(out, Exception):
        assert math.isfinite(out.rate_dps) and math.isfinite(out.position_deg)


@pytest.mark.parametrize("name", sorted(CHAMBER_CALLS))
@SETTINGS
@given(reply=modbus_replies)
def test_any_chamber_reply_decodes_or_raises_a_typed_error(name: str, reply: bytes) -> None:
    out = _modbus_call(lambda link: ModbusChamber(link, ManualClock()), CHAMBER_CALLS[name],
                       reply)
    if name == "read_temperature" and not isinstance(out, Exception):
        assert math.isfinite(out)


# ---------------------------------------------------------------- SCPI supply

SUPPLY_CALLS: dict[str, Callable[[ScpiSupply], Any]] = {
    "identify": lambda s: s.identify(),
    "measure_voltage": lambda s: s.measure_voltage(),
    "measure_current": lambda s: s.measure_current(),
    "output_is_on": lambda s: s.output_is_on(),
    "check_errors": lambda s: s.check_errors(),
    "set_voltage": lambda s: s.set_voltage(5.0),
    "check_current_limit": lambda s: s.check_current_limit(),
}
scpi_replies = st.one_of(
    st.binary(max_size=120),
    st.text(max_size=60).map(lambda t: t.encode("utf-8", "surrogatepass") + b"\n"),
    st.sampled_from([b"nan\n", b"inf\n", b"-1e999\n", b"1e308\n", b"+0\n", b"\xff\xfe\n",
                     b'-113,"Undefined header"\n', b'+0,"No error"\n', b"x" * 5000 + b"\n",
                     b"1,2\n", b"\r\n", b"\x00\n"]),
)


class _ReplyTransport:
    """A line transport answering every query with the next scripted bytes, read as
    drivers.visa reads them (latin-1, up to the LF; no LF is a timeout, as VISA's read)."""

    instrument = "DC supply"

    def __init__(self, replies: list[bytes]) -> None:
        self._buffer = b"".join(replies)

    def write(self, command: str) -> None:
        pass

    def query(self, command: str) -> str:
        line, sep, self._buffer = self._buffer.partition(b"\n")
        if not sep:
            raise InstrumentTimeout(f"no reply to {command!r}", instrument=self.instrument)
        return line.decode("latin-1")

    def close(self) -> None:
        pass


@pytest.mark.parametrize("name", sorted(SUPPLY_CALLS))
@SETTINGS
@given(replies=st.lists(scpi_replies, min_size=1, max_size=4))
def test_any_supply_reply_decodes_or_raises_a_typed_error(
    name: str, replies: list[bytes]
) -> None:
    supply = ScpiSupply(_ReplyTransport(replies))
    t0 = time.monotonic()
    try:
        out = SUPPLY_CALLS[name](supply)
    except InstrumentError as exc:
        assert str(exc)
    else:
        if name.startswith("measure_"):
            assert math.isfinite(out)
    assert time.monotonic() - t0 < 5.0
