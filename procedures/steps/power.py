"""Power the parts and identify them: measured supply checked, serial register checked."""

from __future__ import annotations

from typing import Any

from pydantic import Field

from common.bounded import ONE_HOUR_S
from drivers.errors import InstrumentError, PartAbsent
from procedures.runtime.record import InstrumentRecord
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.steps.registry import Declared, StepSettings, StepType
from procedures.units import Volts


class SerialMismatch(InstrumentError):  # noqa: N818 - like drivers.errors
    """The part's own serial register does not match the scanned label."""


def parts_maybe_powered(ctx: RunContext) -> int:
    """Scanned parts still running plus unscanned sockets that may hold a part."""
    # set by the station on each part: fixture sockets that were not scanned and could not
    # be asked whether they hold a part (a part there draws current from the supply too)
    unasked = max((p.unasked_sockets for p in ctx.parts), default=0)
    return len(ctx.parts.alive()) + unasked


class PowerSettings(StepSettings):
    settle_s: float = Field(
        2.0, ge=0, le=ONE_HOUR_S, description="wait after switching the supply on"
    )
    supply_tolerance_v: float = Field(
        0.05, gt=0, le=10, description="allowed |measured - set| supply"
    )
    supply_v: Volts | None = Field(
        None, description="supply level at power-on (default: the first condition's)"
    )


class PowerIdentify(StepType[PowerSettings]):
    """Supply on at the first condition's level, each part identified, streams started."""

    type_name = "power_identify"
    Settings = PowerSettings

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return [Declared("supply_current_a", "A",
                         "supply current at power-on (shared supply, per part)")]

    def estimate_s(self, ctx: RunContext) -> float:
        return self.settings.settle_s + 1.0

    def _supply_v(self, ctx: RunContext) -> float:
        if self.settings.supply_v is not None:
            return self.settings.supply_v
        if self.place.condition is not None:
            return self.place.condition.supply_v
        return ctx.procedure.planned_conditions()[0].supply_v

    def setup(self, ctx: RunContext) -> None:
        self.supply_v = self._supply_v(ctx)
        supply = ctx.instruments.supply
        supply.output(False)
        supply.set_current_limit(ctx.product.current_limit_a * max(parts_maybe_powered(ctx), 1))
        supply.set_voltage(self.supply_v)
        supply.check_errors()
        supply.output(True)
        ctx.wait.sleep(self.settings.settle_s)

    def main(self, ctx: RunContext) -> None:
        supply = ctx.instruments.supply
        _, volts, amps = ctx.instruments.log_environment()
        tol = self.settings.supply_tolerance_v
        if abs(volts - self.supply_v) > tol:
            raise InstrumentError(
                f"supply measures {volts:.3f} V with {self.supply_v:.3f} V set (allowed "
                f"+/-{tol:g} V): check the supply sense leads and the fixture wiring",
                instrument="supply",
            )
        supply.check_errors()
        ctx.parts.each(lambda part: self._identify(ctx, part))
        per_part_a = amps / max(len(ctx.parts.alive()), 1)
        for part in ctx.parts.alive():
            ctx.records.measure(
                part,
                "supply_current_a",
                per_part_a,
                units="A",
                description="supply current at power-on (shared supply, per part)",
            )
            part.power_on_station_s = ctx.wait.clock.now_s()
        ctx.parts.each(self._start)

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
        part.stop_angle = link.stop_angle()
        link.set_compensation(False)  # calibrate on the raw output
        link.set_output_rate(ctx.procedure.output_rate_hz)

    def _start(self, part: PartRun) -> None:
        assert part.stream is not None
        part.stream.start()
