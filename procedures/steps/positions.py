"""Multi-position static: the part at rest at several table angles, one window per angle.

At rest on a table turning about a vertical axis a perfect part reads its bias whatever the
angle; a part whose sensitive axis is tilted in the fixture also sees g sensitivity times the
share of gravity along it, which turns with the table (g_sensitivity_tilt in the effect
catalog). The bias step's window is at one angle only: this step adds static windows at the
configured angles (default 0/90/180/270 deg) so the model-discrepancy workflow can see it.

Each window is written to raw.h5 as a segment of kind `position_static` (reference rate 0,
reference angle the encoder position from a snapshot taken in the middle of the dwell; the
snapshot is also logged to the table group, where the run-folder loader finds it). The table
goes back to where it started, so the steps after this one see the table as the bias step
left it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import Field, field_validator

from common.bounded import MAX_ACCEL_DPS2, MAX_LIST, ONE_HOUR_S
from procedures.runtime.results import PositionWindow as PositionResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.steps.base import check_window, samples_between
from procedures.steps.registry import StepSettings, StepType
from procedures.units import Seconds

SEGMENT_KIND = "position_static"
AT_REST_DPS = 0.05  # |rate| at the snapshot above this: the table was not at rest


@dataclass
class PositionWindow:
    angle_cmd_deg: float
    angle_deg: float  # encoder position at the mid-dwell snapshot
    rate_dps: float  # table rate at the snapshot
    t0_s: float  # station time, window start
    t1_s: float  # station time, window end


class PositionsSettings(StepSettings):
    """Multi-position static: the table at rest at several angles, one static window each."""

    angles_deg: list[float] = Field(
        default_factory=lambda: [0.0, 90.0, 180.0, 270.0],
        min_length=1,
        max_length=MAX_LIST,
        description="table angles (encoder, deg) at which the part rests, in this order",
    )
    dwell_s: Seconds = Field(10.0, gt=0, description="static window at each angle, s")
    settle_s: float = Field(
        1.0, ge=0, le=ONE_HOUR_S, description="wait after in-position before the window"
    )
    accel_dps2: float = Field(
        100.0, gt=0, le=MAX_ACCEL_DPS2, description="acceleration of each move, deg/s^2"
    )
    at: Literal["every_condition", "first_condition"] = Field(
        "every_condition",
        description="every_condition: at each condition of the loop; "
        "first_condition: only at the first",
    )
    move_timeout_s: Seconds = Field(60.0, gt=0, description="time allowed for a move")

    @field_validator("angles_deg")
    @classmethod
    def _angles(cls, value: list[float]) -> list[float]:
        if any(not -3600.0 <= a <= 3600.0 for a in value):
            raise ValueError("angles must lie within +/-3600 deg")
        return value


class Positions(StepType[PositionsSettings]):
    """Static windows at several table angles (records segments; no judged measurement)."""

    type_name = "positions"
    Results = PositionResults
    Settings = PositionsSettings
    uses_table = True

    def runs_here(self) -> bool:
        return self.settings.at == "every_condition" or self.place.condition_index == 0

    def estimate_s(self, ctx: RunContext) -> float:
        cfg = self.settings
        angles = list(cfg.angles_deg)
        travel = [
            abs(b - a) for a, b in zip([angles[0], *angles], [*angles, angles[0]], strict=True)
        ]
        # triangle move at the acceleration limit: 2 sqrt(d / a), plus settling
        moves = sum(2.0 * np.sqrt(d / cfg.accel_dps2) + 0.5 for d in travel)
        return len(angles) * (cfg.dwell_s + cfg.settle_s) + float(moves)

    def main(self, ctx: RunContext) -> None:
        cfg = self.settings
        table = ctx.instruments.need_table()
        table.enable()
        table.set_rate(0.0)
        table.wait_at_rate(cfg.move_timeout_s)
        _, start = ctx.instruments.snapshot()
        home = start.position_deg
        # angles are table angles within the current turn: never unwind the turns a rate
        # sweep left on the (continuous) position feedback
        origin = 360.0 * round(home / 360.0)
        self.windows: list[PositionWindow] = []
        for angle in cfg.angles_deg:
            ctx.wait.check()
            table.move_to(origin + angle, accel_dps2=cfg.accel_dps2)
            table.wait_in_position(cfg.move_timeout_s)
            ctx.wait.sleep(cfg.settle_s)
            t0 = ctx.wait.clock.now_s()
            ctx.wait.sleep(0.5 * cfg.dwell_s)
            _, rest = ctx.instruments.snapshot()
            ctx.wait.sleep(t0 + cfg.dwell_s - ctx.wait.clock.now_s())
            t1 = ctx.wait.clock.now_s()
            if abs(rest.rate_dps) > AT_REST_DPS:
                ctx.records.event(
                    f"positions: table not at rest at {angle:g} deg "
                    f"({rest.rate_dps:.3f} deg/s at the snapshot)",
                    "WARNING",
                )
            self.windows.append(
                PositionWindow(angle, float(rest.position_deg), float(rest.rate_dps), t0, t1)
            )
        # back to where the bias step left the table
        table.move_to(home, accel_dps2=cfg.accel_dps2)
        table.wait_in_position(cfg.move_timeout_s)
        ctx.parts.each(lambda part: self._analyse(ctx, part))

    def _analyse(self, ctx: RunContext, part: PartRun) -> None:
        cfg = self.settings
        res = part.conditions[self.condition]
        summary: list[PositionResults] = []
        for i, w in enumerate(self.windows):
            data = samples_between(ctx, part, w.t0_s, w.t1_s)
            if not check_window(
                ctx,
                part,
                data,
                f"static at {w.angle_cmd_deg:g} deg at {self.condition}",
                cfg.dwell_s,
            ):
                return
            start_s, end_s = float(data["time_s"][0]), float(data["time_s"][-1])
            ctx.records.segment(
                part,
                SEGMENT_KIND,
                i,
                start_s,
                end_s,
                ref_rate_dps=0.0,
                ref_angle_deg=w.angle_deg,
                temp_setpoint_c=res.temperature_c,
                supply_v=res.supply_v,
            )
            summary.append(
                PositionResults(
                    angle_cmd_deg=w.angle_cmd_deg,
                    angle_deg=w.angle_deg,
                    start_s=start_s,
                    end_s=end_s,
                    mean_dps=float(np.mean(data["rate_dps"])),
                    samples=int(data["rate_dps"].size),
                )
            )
        part.record.analysis.positions[self.condition] = summary
