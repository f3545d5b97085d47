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

from dataclasses import dataclass, field

import numpy as np

from procedures.engine import PartRun, RunContext
from procedures.steps.base import BaseStep, check_window, samples_between

SEGMENT_KIND = "position_static"
AT_REST_DPS = 0.05  # |rate| at the snapshot above this: the table was not at rest


@dataclass
class PositionWindow:
    angle_cmd_deg: float
    angle_deg: float  # encoder position at the mid-dwell snapshot
    rate_dps: float  # table rate at the snapshot
    t0_s: float  # station time, window start
    t1_s: float  # station time, window end


@dataclass
class Positions(BaseStep):
    name: str = "positions"
    policy: str = "positions"
    windows: list[PositionWindow] = field(default_factory=list)

    def estimate_s(self, ctx: RunContext) -> float:
        cfg = ctx.procedure.positions
        assert cfg is not None
        angles = list(cfg.angles_deg)
        travel = [
            abs(b - a) for a, b in zip([angles[0], *angles], [*angles, angles[0]], strict=True)
        ]
        # triangle move at the acceleration limit: 2 sqrt(d / a), plus settling
        moves = sum(2.0 * np.sqrt(d / cfg.accel_dps2) + 0.5 for d in travel)
        return len(angles) * (cfg.dwell_s + cfg.settle_s) + float(moves)

    def main(self, ctx: RunContext) -> None:
        cfg = ctx.procedure.positions
        table = ctx.bench.table
        assert cfg is not None and table is not None
        table.enable()
        table.set_rate(0.0)
        table.wait_at_rate(cfg.move_timeout_s)
        _, start = ctx.snapshot()
        home = start.position_deg
        # angles are table angles within the current turn: never unwind the turns a rate
        # sweep left on the (continuous) position feedback
        origin = 360.0 * round(home / 360.0)
        self.windows = []
        for angle in cfg.angles_deg:
            ctx.check()
            table.move_to(origin + angle, accel_dps2=cfg.accel_dps2)
            table.wait_in_position(cfg.move_timeout_s)
            ctx.sleep(cfg.settle_s)
            t0 = ctx.clock.now_s()
            ctx.sleep(0.5 * cfg.dwell_s)
            _, rest = ctx.snapshot()
            ctx.sleep(t0 + cfg.dwell_s - ctx.clock.now_s())
            t1 = ctx.clock.now_s()
            if abs(rest.rate_dps) > AT_REST_DPS:
                ctx.event(
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
        ctx.each(lambda part: self._analyse(ctx, part))

    def _analyse(self, ctx: RunContext, part: PartRun) -> None:
        cfg = ctx.procedure.positions
        assert cfg is not None
        res = part.conditions[self.condition]
        summary = []
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
            ctx.segment(
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
                {
                    "angle_cmd_deg": w.angle_cmd_deg,
                    "angle_deg": w.angle_deg,
                    "start_s": start_s,
                    "end_s": end_s,
                    "mean_dps": float(np.mean(data["rate_dps"])),
                    "samples": int(data["rate_dps"].size),
                }
            )
        part.record.analysis.setdefault("positions", {})[self.condition] = summary
