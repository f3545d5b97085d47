"""Three-axis parts in a cube on the single-axis table: orientation, measurement per face.

`cube_faces` (inside `for_each: condition`) measures each part in the faces that
procedures/runtime/orientation_plan.py plans for this condition (all six at the first condition, one
per axis at the others, starting in the face the cube is in). For each face it prompts the
operator (a ProgressEvent kind="prompt" with `orientation` set and the instruction in plain
words), waits until every part's accelerometer shows gravity along the named axis (within
`max_tilt_deg`) at rest, re-prompts a socket whose cube came to rest in another face, then
records a static window and a +r/-r table plateau pair. Each window becomes a
procedures.analysis.three_axis.Window in the part's `three_axis_windows`, which
`fit_three_axis` (procedures/steps/three_axis_fit.py) fits.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from pydantic import Field

from common.bounded import MAX_ACCEL_DPS2, ONE_HOUR_S
from drivers.orientation import face_from_accel, normalise_face
from procedures.analysis.bias import window_mean
from procedures.analysis.errors import AnalysisError
from procedures.analysis.three_axis import Window, vec3
from procedures.runtime.orientation_plan import faces_for_condition
from procedures.runtime.record import Verdict
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.runtime.streams import XYZ_COLUMNS
from procedures.steps.base import check_window, sample_rate_hz, samples_between
from procedures.steps.registry import Declared, Provided, StepSettings, StepType
from procedures.steps.sweep import Plateau, run_plateaus

log = logging.getLogger(__name__)
POLL_S = 0.5
AT_REST_ACCEL_STD_MPS2 = 0.05  # accelerometer scatter over the look window at rest


def prompt_text(face: str, sockets: list[int]) -> str:
    """The instruction in plain words."""
    up = face.upper()
    if len(sockets) == 1:
        return f"Turn socket {sockets[0]}'s cube so that face {up} points up"
    listed = ", ".join(str(s) for s in sockets[:-1]) + f" and {sockets[-1]}"
    return f"Turn the cubes of sockets {listed} so that face {up} points up"


class CubeFacesSettings(StepSettings):
    rate_dps: float = Field(100.0, gt=0, le=2000.0, description="table rate of the +/- plateaus")
    static_s: float = Field(10.0, gt=0.5, le=ONE_HOUR_S, description="averaging time per window")
    settle_s: float = Field(1.0, ge=0, le=ONE_HOUR_S, description="wait at rate before averaging")
    accel_dps2: float = Field(200.0, gt=0, le=MAX_ACCEL_DPS2, description="table acceleration")
    at_rate_timeout_s: float = Field(60.0, gt=0, le=ONE_HOUR_S, description="time to reach rate")
    turn_timeout_s: float = Field(
        120.0, gt=0, le=ONE_HOUR_S, description="time for the operator to turn the cube"
    )
    reprompts: int = Field(2, ge=0, le=10, description="re-prompts for a cube in a wrong face")
    look_s: float = Field(1.0, gt=0.1, le=60.0, description="accelerometer window to confirm")
    max_tilt_deg: float = Field(10.0, gt=0, le=30.0, description="gravity off the axis, at most")
    wander_factor: float = Field(
        1.0, ge=0, le=100, description="bias wander shared between windows close in time, "
        "in units of the product's bias_instability_deg_per_h and "
        "rate_random_walk_deg_per_h_per_sqrt_h (0: windows independent)",
    )


class CubeFaces(StepType[CubeFacesSettings]):
    """Orient each part's cube (operator prompts, confirmed by the accelerometer) and measure
    at rest and on +/- table plateaus in each planned face."""

    type_name = "cube_faces"
    Settings = CubeFacesSettings
    uses_table = True
    provides = frozenset({Provided.THREE_AXIS_WINDOWS})

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return []

    def _faces(self, ctx: RunContext) -> list[str]:
        current = next((p.cube_face for p in ctx.parts.alive()), None)
        return faces_for_condition(self.place.condition_index, current)

    def estimate_s(self, ctx: RunContext) -> float:
        cfg = self.settings
        n = 6 if self.place.condition_index == 0 else 3
        ramp_s = 4 * cfg.rate_dps / cfg.accel_dps2
        return n * (8.0 + 3 * cfg.static_s + 2 * cfg.settle_s + ramp_s)

    def main(self, ctx: RunContext) -> None:
        ctx.instruments.need_table().enable()
        for face in self._faces(ctx):
            ctx.wait.check()
            self._orient(ctx, face)
            t0 = ctx.wait.now_s()
            ctx.wait.sleep(self.settings.static_s)
            static = Plateau(0.0, t0, ctx.wait.now_s(), 0.0, 0.0, 0.0)
            cfg = self.settings
            plateaus = run_plateaus(ctx, [cfg.rate_dps, -cfg.rate_dps], cfg.static_s,
                                    cfg.settle_s, cfg.accel_dps2, cfg.at_rate_timeout_s)
            windows = [static, *plateaus]

            def measure(part: PartRun, face: str = face, ws: list[Plateau] = windows) -> None:
                self._windows(ctx, part, face, ws)

            ctx.parts.each(measure)

    # ------------------------------------------------------------ orientation

    def _orient(self, ctx: RunContext, face: str) -> None:
        face = normalise_face(face)
        pending = [p for p in ctx.parts.alive() if p.cube_face != face]
        if not pending:
            return
        before = {p.socket: self._face_now(ctx, p) for p in pending}
        prompts = {p.socket: 0 for p in pending}
        self._prompt(ctx, face, pending)
        deadline = ctx.wait.now_s() + self.settings.turn_timeout_s
        while pending:
            ctx.wait.sleep(POLL_S)
            for part in list(pending):
                seen = self._face_now(ctx, part)
                if seen == face:
                    part.cube_face = face
                    pending.remove(part)
                elif seen is not None and seen != before[part.socket]:
                    self._wrong_face(ctx, part, face, seen, prompts, pending)
                    before[part.socket] = seen
            if pending and ctx.wait.now_s() > deadline:
                for part in pending:
                    ctx.parts.drop(part, Verdict.ERROR, (
                        f"socket {part.socket}: the cube did not reach face {face.upper()} "
                        f"within {self.settings.turn_timeout_s:g} s of the prompt; check the "
                        "cube and the part's accelerometer"))
                pending = []
        ctx.progress.prompt_done([p.socket for p in ctx.parts.alive()])
        ctx.parts.require()

    def _wrong_face(self, ctx: RunContext, part: PartRun, face: str, seen: str,
                    prompts: dict[int, int], pending: list[PartRun]) -> None:
        prompts[part.socket] += 1
        ctx.records.event(f"socket {part.socket}: cube in face {seen.upper()}, "
                          f"not {face.upper()}: asked again", level="WARNING", parts=[part])
        if prompts[part.socket] > self.settings.reprompts:
            ctx.parts.drop(part, Verdict.ERROR, (
                f"socket {part.socket}: the cube was turned to a wrong face "
                f"{prompts[part.socket]} times (asked for {face.upper()}, last {seen.upper()})"))
            pending.remove(part)
            return
        self._prompt(ctx, face, [part])

    def _prompt(self, ctx: RunContext, face: str, parts: list[PartRun]) -> None:
        sockets = [p.socket for p in parts]
        ctx.progress.prompt(prompt_text(face, sockets), sockets, orientation=face)

    def _face_now(self, ctx: RunContext, part: PartRun) -> str | None:
        """The face up now, if the part is at rest (steady accelerometer), else None."""
        now = ctx.wait.now_s()
        try:
            data = samples_between(ctx, part, now - self.settings.look_s, now)
        except Exception:  # noqa: BLE001 - no samples yet: not confirmed this time
            return None
        if "accel_x_mps2" not in data or data["accel_x_mps2"].size < 2:
            return None
        acc = np.column_stack([data[c] for c in XYZ_COLUMNS[3:]])
        acc = acc[np.all(np.isfinite(acc), axis=1)]
        if len(acc) < 2 or float(np.max(acc.std(axis=0))) > AT_REST_ACCEL_STD_MPS2:
            return None
        return face_from_accel(acc.mean(axis=0), self.settings.max_tilt_deg)

    # ------------------------------------------------------------ windows

    def _windows(self, ctx: RunContext, part: PartRun, face: str, plateaus: list[Plateau]) -> None:
        fs = sample_rate_hz(ctx)
        res = part.conditions[self.condition]
        out: list[Window] = part.three_axis_windows
        for p in plateaus:
            data = samples_between(ctx, part, p.t0_s, p.t1_s)
            what = f"face {face.upper()} at {p.ref_dps:+.1f} deg/s, {self.condition}"
            if not check_window(ctx, part, data, what, p.t1_s - p.t0_s):
                return
            if "rate_x_dps" not in data:
                ctx.parts.drop(part, Verdict.ERROR, (
                    f"socket {part.socket}: {what}: no three-axis samples: the part streams "
                    "single-axis frames; check the product file's axes and the fixture"))
                return
            try:
                means = [window_mean(data[c], fs) for c in XYZ_COLUMNS[:3]]
            except AnalysisError as exc:
                ctx.parts.drop(part, Verdict.ERROR, f"{what}: {exc}")
                return
            accel = np.column_stack([data[c] for c in XYZ_COLUMNS[3:]])
            factor = self.settings.wander_factor
            bi_dps = factor * ctx.product.bias_instability_deg_per_h / 3600
            rrw = factor * ctx.product.rate_random_walk_deg_per_h_per_sqrt_h / 3600 / 60
            u = [m.u_mean_dps for m in means]
            start_s, end_s = float(data["time_s"][0]), float(data["time_s"][-1])
            out.append(Window(
                face=face, table_rate_dps=p.ref_dps,
                rate_dps=(means[0].mean_dps, means[1].mean_dps, means[2].mean_dps),
                u_rate_dps=(u[0], u[1], u[2]),
                accel_mps2=vec3(np.nanmean(accel, axis=0)),
                temp_c=float(np.mean(data["temp_c"])), supply_v=res.supply_v,
                condition=self.condition, start_s=start_s, end_s=end_s,
                bias_instability_dps=bi_dps, rate_random_walk_dps_per_sqrt_s=rrw,
            ))
            ctx.records.segment(part, "static" if p.ref_dps == 0 else "plateau", len(out) - 1,
                                start_s, end_s, ref_rate_dps=p.ref_dps,
                                temp_setpoint_c=res.temperature_c, supply_v=res.supply_v)
            res.note_temperature("scale", data["temp_c"], data["time_s"])
