"""The instrument status lights: connected, in calibration (not overdue), faulted.

Between runs the station probes each instrument lightly: the rate table is asked for its
status register (fault, interlock), the chamber's Modbus port must accept a connection, the
supply's and fixtures' serial ports must exist. During a run the engine owns the
instruments and is not disturbed: the lights keep their last state.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import os
import socket
from dataclasses import dataclass

from station.ui.runner_adapter import InstrumentLight

log = logging.getLogger(__name__)

_PROBE_TIMEOUT_S = 0.5


@dataclass(frozen=True)
class InstrumentAddress:
    name: str
    address: str  # host:port or a serial port path
    calibration_due: dt.date | None


def _is_tcp(address: str) -> bool:
    host, _, port = address.rpartition(":")
    return bool(host) and port.isdigit() and not address.startswith("/")


def _tcp_open(address: str) -> bool:
    host, _, port = address.rpartition(":")
    try:
        with socket.create_connection((host, int(port)), timeout=_PROBE_TIMEOUT_S):
            return True
    except OSError:
        return False


def _in_calibration(due: dt.date | None, today: dt.date) -> bool | None:
    return None if due is None else due >= today


def _table_fault(address: str) -> str:
    """'' when the table reports no fault, else what it reports (or why it cannot be read)."""
    from drivers.clock import ScaledClock
    from drivers.rate_table import ModbusRateTable

    host, _, port = address.rpartition(":")
    try:
        table = ModbusRateTable.connect(
            host, int(port), ScaledClock(1.0), timeout_s=_PROBE_TIMEOUT_S
        )
    except Exception as exc:  # noqa: BLE001 - any failure to talk is "not connected"
        return f"cannot connect: {exc}"
    try:
        status = table.read_status()
    except Exception as exc:  # noqa: BLE001
        return f"status unreadable: {exc}"
    finally:
        with contextlib.suppress(Exception):
            table.close()
    if status.fault:
        return f"fault code {status.fault_code}"
    if status.interlock_open:
        return "interlock open"
    return ""


def probe(
    instruments: list[InstrumentAddress], today: dt.date | None = None
) -> list[InstrumentLight]:
    """One light per instrument, probed now."""
    today = today or dt.date.today()
    lights = []
    for inst in instruments:
        due = inst.calibration_due.isoformat() if inst.calibration_due else ""
        cal = _in_calibration(inst.calibration_due, today)
        detail = "" if cal is not False else f"calibration overdue since {due}"
        if not inst.address:
            lights.append(
                InstrumentLight(inst.name, False, cal, False, due, "no address configured")
            )
            continue
        faulted = False
        if _is_tcp(inst.address):
            connected = _tcp_open(inst.address)
            if connected and inst.name == "rate table":
                fault = _table_fault(inst.address)
                faulted = bool(fault) and not fault.startswith("cannot connect")
                detail = fault or detail
        else:
            connected = os.path.exists(inst.address)
        if not connected:
            detail = f"no answer at {inst.address}"
        lights.append(InstrumentLight(inst.name, connected, cal, faulted, due, detail))
    return lights
