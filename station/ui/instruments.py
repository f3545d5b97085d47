"""The instrument status lights: connected, in calibration (not overdue), faulted.

Between runs the station probes each instrument lightly with its own configured driver: the
driver is opened, asked its own `probe()` (a status or fault query of its protocol; its
`identify()` when it has no probe) and closed. An instrument that cannot be opened is not
connected; one that answers with a fault (or an open interlock) is faulted. During a run the
engine owns the instruments and is not disturbed: the lights keep their last state.
"""

from __future__ import annotations

import datetime as dt
import logging
from dataclasses import dataclass
from typing import Any

from station.instruments import probe_role

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class InstrumentLight:
    """An instrument's three lights: connected, in calibration (not overdue), faulted."""

    name: str
    connected: bool
    in_calibration: bool | None  # None: the station does not know the due date
    faulted: bool
    calibration_due: str = ""  # ISO date
    detail: str = ""
    socket: int | None = None  # a socket's fixture: needed only when that socket is loaded


@dataclass(frozen=True)
class InstrumentAddress:
    name: str
    address: str  # in its driver's own form
    calibration_due: dt.date | None
    plan: Any = None  # station.instruments.RoleDriver: how to open it (None: cannot be)
    error: str = ""  # why it has no plan (a bad driver name in station.yaml)
    socket: int | None = None  # a socket's fixture


def _in_calibration(due: dt.date | None, today: dt.date) -> bool | None:
    return None if due is None else due >= today


def probe(
    instruments: list[InstrumentAddress], today: dt.date | None = None
) -> list[InstrumentLight]:
    """One light per instrument, probed now with its own driver."""
    today = today or dt.date.today()
    lights = []
    for inst in instruments:
        due = inst.calibration_due.isoformat() if inst.calibration_due else ""
        cal = _in_calibration(inst.calibration_due, today)
        detail = "" if cal is not False else f"calibration overdue since {due}"
        if inst.plan is None or not inst.address:
            why = inst.error or "no address configured"
            lights.append(InstrumentLight(inst.name, False, cal, False, due, why, inst.socket))
            continue
        connected, report = probe_role(inst.plan)
        faulted = connected and bool(report)
        lights.append(
            InstrumentLight(
                inst.name, connected, cal, faulted, due, report or detail, inst.socket
            )
        )
    return lights
