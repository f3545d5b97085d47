"""Power the parts and identify them: measured supply checked, serial register checked."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.errors import InstrumentError, PartAbsent
from procedures.engine import PartRun, RunContext
from procedures.record import InstrumentRecord
from procedures.steps.base import BaseStep


class SerialMismatch(InstrumentError):  # noqa: N818 - like drivers.errors
    """The part's own serial register does not match the scanned label."""


# set by the station on each part: fixture sockets that were not scanned and could not be
# asked whether they hold a part (a part there draws current from the shared supply too)
UNASKED_SOCKETS = "unasked_sockets"


def parts_maybe_powered(ctx: RunContext) -> int:
    """Scanned parts still running plus unscanned sockets that may hold a part."""
    unasked = max((int(p.extra.get(UNASKED_SOCKETS, 0)) for p in ctx.parts), default=0)
    return len(ctx.alive()) + unasked


@dataclass
class PowerIdentify(BaseStep):
    """Supply on at the first condition's level, each part identified, streams started."""

    supply_v: float = 5.0
    name: str = "power_identify"
    policy: str = "power"

    def estimate_s(self, ctx: RunContext) -> float:
        return ctx.procedure.power.settle_s + 1.0

    def setup(self, ctx: RunContext) -> None:
        supply = ctx.bench.supply
        supply.output(False)
        supply.set_current_limit(ctx.product.current_limit_a * max(parts_maybe_powered(ctx), 1))
        supply.set_voltage(self.supply_v)
        supply.check_errors()
        supply.output(True)
        ctx.sleep(ctx.procedure.power.settle_s)

    def main(self, ctx: RunContext) -> None:
        supply = ctx.bench.supply
        _, volts, amps = ctx.log_environment()
        tol = ctx.procedure.power.supply_tolerance_v
        if abs(volts - self.supply_v) > tol:
            raise InstrumentError(
                f"supply measures {volts:.3f} V with {self.supply_v:.3f} V set (allowed "
                f"+/-{tol:g} V): check the supply sense leads and the fixture wiring",
                instrument="supply",
            )
        supply.check_errors()
        ctx.each(lambda part: self._identify(ctx, part))
        per_part_a = amps / max(len(ctx.alive()), 1)
        for part in ctx.alive():
            ctx.measure(
                part,
                "supply_current_a",
                per_part_a,
                units="A",
                description="supply current at power-on (shared supply, per part)",
            )
            part.extra["power_on_station_s"] = ctx.clock.now_s()
        ctx.each(self._start)

    def _identify(self, ctx: RunContext, part: PartRun) -> None:
        assert part.stream is not None
        link = part.stream.link
        ident = link.identify()
        role = f"fixture_{part.socket}"
        known = next((i for i in part.record.instruments if i.role == role), None)
        if known is None:  # the station layer lists it with its address and due date
            known = InstrumentRecord(role=role)
            part.record.instruments.append(known)
        known.manufacturer, known.model = ident.manufacturer, ident.model
        known.serial, known.firmware = ident.serial, ident.firmware
        if not link.part_present():
            raise PartAbsent(
                f"socket {part.socket}: no part in the socket; seat the part and rescan",
                instrument=f"fixture_{part.socket}",
            )
        register = link.read_part_serial().strip()
        part.record.dut.part_serial_register = register
        if register != part.serial:
            raise SerialMismatch(
                f"socket {part.socket}: the part's serial register says {register!r} but the "
                f"scanned label is {part.serial!r}: wrong part or wrong label; the part is "
                "refused, check which part is in which socket",
                instrument=f"fixture_{part.socket}",
            )
        part.extra["stop_angle"] = link.stop_angle()
        link.set_compensation(False)  # calibrate on the raw output
        link.set_output_rate(ctx.procedure.power.output_rate_hz)

    def _start(self, part: PartRun) -> None:
        assert part.stream is not None
        part.stream.start()
