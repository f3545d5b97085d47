"""The thermal step's glue to the `fastest` strategy: its settings from the procedure, the
product and the chamber; a part's latest reading; the chamber left at the target on exit."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.errors import InstrumentError, SetpointOutOfRange
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.thermal.chamber_strategy import Criterion, ThermalLimits, ThermalModel
from procedures.thermal.thermal_control import ControlSettings, FastestController

if TYPE_CHECKING:
    from procedures.steps.thermal import Stabilise

log = logging.getLogger(__name__)

READING_WINDOW_S = 1.0  # the latest reading: the mean of the last second of samples


def latest_reading_c(part: PartRun, station_now_s: float) -> float:
    """The part's own die temperature now (mean of the last second); nan without samples."""
    if part.stream is None:
        return float("nan")
    end = part.stream.fixture_time(station_now_s)
    temp = part.stream.window(end - READING_WINDOW_S, np.inf)["temp_c"]
    return float(np.mean(temp)) if temp.size else float("nan")


def control_settings(ctx: RunContext, step: Stabilise) -> ControlSettings:
    """The planner's model and limits: the chamber's ramp and air lag from the procedure, its
    setpoint limits from the chamber itself, the die lag and maximum from the product."""
    cfg, product = ctx.procedure.chamber, ctx.product
    low_c, high_c = ctx.instruments.chamber.setpoint_limits()
    max_part_c, min_part_c = product.max_part_temperature_c, product.min_part_temperature_c
    high_c = high_c if max_part_c is None else min(high_c, max_part_c)
    low_c = low_c if min_part_c is None else max(low_c, min_part_c)
    target: Any = step.target
    if not low_c <= target.temperature_c <= high_c:
        raise SetpointOutOfRange(
            f"{step.condition}: {target.temperature_c:g} C is outside what the chamber and the "
            f"product allow ({low_c:g}..{high_c:g} C): lower the procedure's temperature or "
            "check max_part_temperature_c / min_part_temperature_c in the product file",
            instrument="chamber",
        )
    limits = ThermalLimits(
        setpoint_low_c=low_c,
        setpoint_high_c=high_c,
        max_overshoot_c=cfg.max_overshoot_c,
        max_part_c=high_c,
        min_part_c=low_c,
    )
    model = ThermalModel(
        air_tau_s=cfg.air_tau_s, die_tau_s=product.die_tau_s, ramp_c_per_min=cfg.ramp_c_per_min
    )
    settings = step.settings
    return ControlSettings(
        target_c=target.temperature_c,
        criterion=Criterion(
            window_s=settings.window_s,
            slope_c_per_min=settings.slope_c_per_min,
            band_c=settings.band_c,
            target_c=target.temperature_c,
            tolerance_c=settings.target_tolerance_c,
        ),
        model=model,
        limits=limits,
        die_tau_prior_s=product.die_tau_s,
        heat_tau_s=product.self_heating_tau_s,
        replan_interval_s=cfg.replan_interval_s,
    )


def leave_at_target(control: FastestController) -> None:
    """On any exit from the step: the chamber at the target, never at an overshoot. A
    failure here is logged, not raised over the error that ended the step (the run's safe
    state follows)."""
    try:
        control.finish()
    except InstrumentError as exc:
        log.error("could not return the chamber to %.1f C: %s", control.cfg.target_c, exc)
