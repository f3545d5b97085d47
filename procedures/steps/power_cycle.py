"""Switching the shared supply off and on again with the parts' streams stopped and restarted
(the turn-on repeatability and warm-up steps). Every part on the supply is cycled together."""

from __future__ import annotations

from procedures.runtime.run_context import RunContext

# station seconds between the supply coming on and the streams being started (the part's
# own power-on reset); the warm-up is measured from the supply switching on, not from here
BOOT_S = 0.5


def supply_level_v(ctx: RunContext, condition_supply_v: float | None) -> float:
    """The level to power on at: the step's condition's, else the product's reference."""
    if condition_supply_v is not None:
        return condition_supply_v
    return float(ctx.product.reference_supply_v)


def power_off(ctx: RunContext) -> None:
    """Stop every live part's stream, then switch the supply output off."""
    for part in ctx.parts.alive():
        if part.stream is not None:
            ctx.parts.per_part(part, lambda p: p.stream.stop())  # type: ignore[union-attr]
    ctx.wait.check()
    ctx.instruments.supply.output(False)


def power_on(ctx: RunContext, supply_v: float) -> float:
    """Switch the supply on at `supply_v`, restart the streams; returns the station time
    the output was switched on (the parts' power-on)."""
    supply = ctx.instruments.supply
    supply.set_voltage(supply_v)
    supply.output(True)
    on_s = ctx.wait.now_s()
    ctx.wait.sleep(BOOT_S)
    supply.check_errors()
    for part in ctx.parts.alive():
        part.power_on_station_s = on_s
        if part.stream is not None:
            ctx.parts.per_part(part, lambda p: p.stream.start())  # type: ignore[union-attr]
    return on_s
