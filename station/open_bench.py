"""Opening the bench: every instrument role through its configured driver and each socket's
part link; the instruments' entries of the run's record."""

from __future__ import annotations

import datetime as dt
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from common.clock import ScaledClock
from drivers.protocols import Chamber, InstrumentIdentity, PartLink, RateTable, Supply
from procedures.runtime.record import InstrumentRecord
from procedures.runtime.run_parts import Bench
from station import instruments as roles
from station.bench_clock import station_clock
from station.endpoints import Endpoints
from station.errors import UserError
from station.settings import LoadedSettings

log = logging.getLogger(__name__)


@dataclass
class OpenBench:
    bench: Bench
    instruments: list[InstrumentRecord]
    closers: list[Callable[[], None]]
    names: dict[str, str] = field(default_factory=dict)  # role -> "driver at address"

    def close(self) -> None:
        for closer in reversed(self.closers):
            try:
                closer()
            except Exception as exc:  # closing a dead link must not hide the run's result
                log.info("closing an instrument: %s", exc)


def instrument_record(
    role: str,
    ident: InstrumentIdentity | None,
    address: str,
    due: dt.date | None = None,
) -> InstrumentRecord:
    return InstrumentRecord(
        role=role,
        manufacturer=ident.manufacturer if ident else "",
        model=ident.model if ident else "",
        serial=ident.serial if ident else "",
        firmware=ident.firmware if ident else "",
        address=address,
        calibration_due=due.isoformat() if due else None,
        calibration_overdue=bool(due and due < dt.date.today()),
    )


def open_part_link(
    settings: LoadedSettings,
    socket: int,
    port: str,
    clock: ScaledClock,
    silent_after_s: float,
    endpoints: Endpoints | None = None,
) -> PartLink:
    """The part driver of one socket (station.yaml's part role, default `part.fixture`), at the
    fixture's configured baud; it judges silence after `silent_after_s` station s (floored)."""
    plan = roles.plan_part(settings, socket, port, endpoints)
    link: PartLink = roles.open_role(settings, plan, clock)
    if hasattr(link, "silent_after_s"):
        # frame loss is judged by the engine against the procedure's fraction, not by the
        # driver; silence needs a wall-time floor too: at 200x, 5 station s are 25 wall ms
        link.silent_after_s = silent_floor_s(silent_after_s, clock)
    return link


def silent_floor_s(silent_after_s: float, clock: ScaledClock, wall_floor_s: float = 1.0) -> float:
    """Station seconds of silence before a part counts as silent (at least `wall_floor_s` wall,
    and two of a lockstep clock's steps: a step's frames arrive only after it)."""
    return max(silent_after_s, wall_floor_s * clock.speed, 2 * clock.check_every_s)


def open_bench(
    settings: LoadedSettings,
    sockets: list[int],
    endpoints: Endpoints | None,
    needs_table: bool,
    silent_after_s: float = 5.0,
) -> OpenBench:
    """Open every role through its configured driver (station.yaml `driver:`, or the family
    the bench's twin serves). A bad driver name or setting is a UserError (file:line); an
    instrument that cannot be reached raises `station.instruments.Unreachable`."""
    closers: list[Callable[[], None]] = []
    clock = station_clock(endpoints, closers)
    records: list[InstrumentRecord] = []
    names: dict[str, str] = {}
    opened: dict[str, Any] = {}
    try:
        for role in roles.station_roles(needs_table):
            plan = roles.plan_role(settings, role, endpoints)
            if plan is None:
                continue
            driver = roles.open_role(settings, plan, clock)
            closers.append(driver.close)
            opened[role] = driver
            names[role] = f"the {plan.label} ({plan.name} at {plan.address})"
            records.append(
                instrument_record(role, roles.identity(driver), plan.address, plan.calibration_due)
            )
        ports = endpoints.duts if endpoints else settings.settings.instruments.fixture.ports
        links: dict[int, PartLink] = {}
        for s in sockets:
            port = ports.get(s)
            if not port:
                raise UserError(
                    f"socket {s} has no fixture port (station.yaml instruments.fixture.ports "
                    "or the bench's sockets); load fewer parts or configure the socket"
                )
            link = open_part_link(settings, s, port, clock, silent_after_s, endpoints)
            closers.append(link.close)
            links[s] = link
        chamber: Chamber = opened["chamber"]
        supply: Supply = opened["supply"]
        table: RateTable | None = opened.get("rate_table")
        return OpenBench(
            Bench(chamber=chamber, supply=supply, links=links, clock=clock, table=table,
                  inclinometer=opened.get("inclinometer")),
            records,
            closers,
            names,
        )
    except BaseException:
        OpenBench(None, [], closers).close()  # type: ignore[arg-type]
        raise
