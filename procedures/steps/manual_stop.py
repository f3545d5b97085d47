"""The article's own bench: the stop method with the fixture turned by hand, no rate table.

The step rests, then prompts the operator (a ProgressEvent kind="prompt", shown on the
operator screen and printed by `station run`) to turn the fixture by hand to its other stop,
and watches the part's own output for the move: a move starts when the rate leaves the rest
level by more than `detect_dps` and ends when it has stayed inside that band for `rest_s`.
Nothing moving within `move_timeout_s` of the prompt is an ERROR naming the socket, the
prompt and the timeout. After each move the fixture rests `static_s` at the stop. The whole
record is then analysed by `procedures.analysis.stop_method` (bias from the leading rest,
scale from integrating each move), as the table-driven stop method is.

A move that over-ranges the part is refused by the analysis and warned about (the operator
is asked for one more move, up to `extra_moves`); a bounce at the stop (the rate reversing
at the end of a move) is warned about; its angle is inside the integral, so the move still
counts. The reference angle between the stops is, by `reference`:

- `inclinometer`: the station's inclinometer (station.yaml role `inclinometer`) read on the
  fixture at each stop; the mean travel over the moves, with the readings' uncertainty;
- `fixture`: the fixture's stored stop angle and its uncertainty (read at power-up);
- `stored`: `stop_angle_deg` +/- `stop_angle_u_deg` given here (a fixture measured once).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, Field, model_validator

from common.bounded import ONE_HOUR_S
from drivers.errors import InstrumentError
from drivers.protocols import SampleStatus
from procedures.analysis.errors import AnalysisError
from procedures.analysis.stop_method import (
    StopMethodResult,
    StopMethodSettings,
    analyze_stop_method,
)
from procedures.runtime.record import Verdict
from procedures.runtime.results import StopMethodResults, StopMove, Verification, VerificationRow
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun, StopScale, condition_record
from procedures.steps.base import check_window, samples_between
from procedures.steps.registry import Declared, Provided, StepSettings, StepType
from procedures.steps.stop import stop_angle, stop_noise_model
from procedures.units import Volts

CLIP_BITS = int(SampleStatus.OVER_RANGE | SampleStatus.SATURATED)
POLL_S = 0.25  # station seconds between looks at the part's data while waiting for a move
CATCH_UP_WALL_S = 10.0  # at most this long (wall) for late samples before the analysis


class ManualStopSettings(StepSettings):
    moves: int = Field(2, ge=1, le=20, description="moves between the stops (out, back, ...)")
    extra_moves: int = Field(
        1, ge=0, le=5, description="further moves asked for when a move over-ranges the part"
    )
    static_s: float = Field(
        5.0, gt=1.0, le=ONE_HOUR_S, description="rest before the first move and after each"
    )
    move_timeout_s: float = Field(
        60.0, gt=0, le=ONE_HOUR_S,
        description="after the prompt, time for the move to start (and again to end)",
    )
    detect_dps: float = Field(
        3.0, gt=0, le=100.0, description="the rate leaving the rest level by this is a move"
    )
    rest_s: float = Field(
        1.0, gt=0, le=60.0, description="inside the band this long: the fixture is at rest"
    )
    reference: Literal["inclinometer", "fixture", "stored"] = Field(
        "inclinometer", description="reference angle: inclinometer at each stop, the "
        "fixture's stored angle, or stop_angle_deg given here",
    )
    stop_angle_deg: float | None = Field(
        None, gt=10.0, lt=350.0, description="reference: stored: the angle between the stops"
    )
    stop_angle_u_deg: float | None = Field(
        None, gt=0.0, le=10.0, description="reference: stored: its standard uncertainty"
    )

    @model_validator(mode="after")
    def _stored(self) -> ManualStopSettings:
        if self.reference == "stored" and (
            self.stop_angle_deg is None or self.stop_angle_u_deg is None
        ):
            raise ValueError(
                "reference: stored needs stop_angle_deg and stop_angle_u_deg (the fixture's "
                "measured angle between its stops and its standard uncertainty)"
            )
        return self


@dataclass
class _Watch:
    """One part's move while the station waits for it, in the part's own (fixture) time: the
    samples reach the station a little late, more so on a loaded machine, so the timeouts
    are judged on the data that has arrived, never on the station clock alone."""

    prompt_f: float  # fixture time of the prompt
    level_dps: float  # the rate at rest just before the prompt
    last_f: float = 0.0  # the newest sample seen
    started_f: float | None = None
    rested: bool = False
    over_range: bool = False


@dataclass
class _PartStops:
    """One part's record of the step: inclinometer readings at each stop, warnings."""

    readings: list[tuple[float, float]] = field(default_factory=list)
    over_ranged_moves: int = 0


def prompt_text(sockets: list[int]) -> str:
    """The instruction in plain words (BRIEF contract 2)."""
    if len(sockets) == 1:
        return f"Turn socket {sockets[0]}'s fixture by hand to the other stop"
    listed = ", ".join(str(s) for s in sockets[:-1]) + f" and {sockets[-1]}"
    return f"Turn the fixtures of sockets {listed} by hand to the other stop, one after another"


class ManualStop(StepType[ManualStopSettings]):
    """The stop method on a fixture turned by hand when the station prompts."""

    type_name = "manual_stop"
    Settings = ManualStopSettings
    provides = frozenset({Provided.SCALE_STOP})  # a fit may take its scale (source: stop_method)
    Results: ClassVar[type[BaseModel] | None] = StopMethodResults

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return [
            Declared("raw_scale_error", "1", "stop-method scale - nominal (turned by hand)",
                     per_condition=True),
            Declared("manual_stop_reference_angle_deg", "deg",
                     "the reference angle between the stops", informational=True,
                     per_condition=True),
        ]

    def estimate_s(self, ctx: RunContext) -> float:
        cfg = self.settings
        per_move = 2.0 + 4.0 + cfg.rest_s + cfg.static_s  # reaction, move, rest, static
        return cfg.static_s + cfg.moves * per_move + 1.0

    # ------------------------------------------------------------ the moves

    def setup(self, ctx: RunContext) -> None:
        self._inclinometer = ctx.instruments.bench.inclinometer
        if self.settings.reference == "inclinometer" and self._inclinometer is None:
            for part in ctx.parts.alive():
                ctx.parts.drop(
                    part, Verdict.ERROR,
                    "manual_stop: reference: inclinometer, but this station has no "
                    "inclinometer (station.yaml instruments.inclinometer): add it, or use "
                    "reference: fixture or stored in the procedure",
                )

    def main(self, ctx: RunContext) -> None:
        cfg = self.settings
        stops = {p.socket: _PartStops() for p in ctx.parts.alive()}
        t_start = ctx.wait.now_s()
        ctx.wait.sleep(cfg.static_s)
        self._read_stops(ctx, stops)
        usable = 0
        asked = 0
        while usable < cfg.moves and asked < cfg.moves + cfg.extra_moves:
            watches = self._one_move(ctx)
            asked += 1
            clipped = [s for s, w in watches.items() if w.over_range]
            for sock in clipped:
                stops[sock].over_ranged_moves += 1
                ctx.records.event(
                    f"socket {sock}: the hand move over-ranged the part: that move gives no "
                    "scale; turn the fixture more slowly (3 to 4 s from stop to stop)",
                    "WARNING", [p for p in ctx.parts.alive() if p.socket == sock],
                )
            if not clipped:
                usable += 1
            self._read_stops(ctx, stops)
        t_end = ctx.wait.now_s()
        # a loaded station receives samples late: have them all before cutting the record
        bound_s = max(cfg.move_timeout_s, CATCH_UP_WALL_S * ctx.wait.clock.speed)
        self._catch_up(ctx, t_end, bound_s)
        ctx.parts.each(lambda part: self._analyse(ctx, part, stops[part.socket], t_start, t_end))

    def _one_move(self, ctx: RunContext) -> dict[int, _Watch]:
        """Prompt, wait for every alive part to move and come to rest, then rest."""
        cfg = self.settings
        ctx.parts.require()  # every part dropped (an inclinometer unread): nobody to prompt for
        parts = ctx.parts.alive()
        sockets = [p.socket for p in parts]
        t_prompt = ctx.wait.now_s()
        self._catch_up(ctx, t_prompt)
        watches = {p.socket: self._watch(p, t_prompt) for p in ctx.parts.alive()}
        message = prompt_text(sockets)
        ctx.progress.prompt(message, sockets)
        try:
            while True:
                ctx.wait.sleep(POLL_S)
                for part in ctx.parts.alive():
                    self._look(part, watches[part.socket])
                waiting = [p for p in ctx.parts.alive() if not watches[p.socket].rested]
                if not waiting:
                    break
                self._drop_late(ctx, waiting, watches, message)
                ctx.parts.require()
        finally:
            ctx.progress.prompt_done(sockets)
        ctx.wait.sleep(cfg.static_s)
        return watches

    def _catch_up(self, ctx: RunContext, t_s: float, bound_s: float | None = None) -> None:
        """Wait (station time, bounded) until every alive part's samples up to `t_s` arrived."""
        deadline = ctx.wait.now_s() + (bound_s or self.settings.move_timeout_s)
        while ctx.wait.now_s() < deadline:
            behind = [
                p for p in ctx.parts.alive()
                if p.stream is not None
                and (p.stream.last_time_s() or -math.inf) < p.stream.fixture_time(t_s)
            ]
            if not behind:
                return
            ctx.wait.sleep(POLL_S)

    def _watch(self, part: PartRun, t_prompt: float) -> _Watch:
        stream = part.stream
        assert stream is not None
        prompt_f = stream.fixture_time(t_prompt)
        rest = stream.window(prompt_f - self.settings.rest_s, prompt_f)["rate_dps"]
        level = float(np.median(rest)) if rest.size else 0.0
        return _Watch(prompt_f, level, last_f=prompt_f)

    def _drop_late(
        self, ctx: RunContext, waiting: list[PartRun], watches: dict[int, _Watch], message: str
    ) -> None:
        cfg = self.settings
        for part in waiting:
            watch = watches[part.socket]
            if watch.started_f is None and watch.last_f - watch.prompt_f > cfg.move_timeout_s:
                ctx.parts.drop(
                    part, Verdict.ERROR,
                    f"manual_stop: no move within {cfg.move_timeout_s:g} s of the prompt "
                    f"\"{message}\": socket {part.socket}'s fixture was not turned to its other "
                    "stop (the part's rate never left its rest level); turn it by hand when "
                    "the station asks, and check that it turns freely",
                )
            elif (
                watch.started_f is not None
                and watch.last_f - watch.started_f > cfg.move_timeout_s
            ):
                ctx.parts.drop(
                    part, Verdict.ERROR,
                    f"manual_stop: socket {part.socket}'s fixture did not come to rest within "
                    f"{cfg.move_timeout_s:g} s of starting to move: hold it still against the "
                    "stop after each turn",
                )

    def _look(self, part: PartRun, watch: _Watch) -> None:
        """Update one part's move from the samples received since the prompt."""
        cfg = self.settings
        stream = part.stream
        assert stream is not None
        data = stream.window(watch.prompt_f, math.inf)
        t, rate = data["time_s"], data["rate_dps"]
        if t.size < 2:
            return
        watch.last_f = float(t[-1])
        moving = np.abs(rate - watch.level_dps) > cfg.detect_dps
        if (data["status"].astype(np.int64) & CLIP_BITS).any():
            watch.over_range = True
        if not moving.any():
            return
        if watch.started_f is None:
            watch.started_f = float(t[int(np.argmax(moving))])
        last_move = int(np.flatnonzero(moving)[-1])
        watch.rested = bool(t[-1] - t[last_move] >= cfg.rest_s)

    def _read_stops(self, ctx: RunContext, stops: dict[int, _PartStops]) -> None:
        """Read the inclinometer on every alive part's fixture (reference: inclinometer)."""
        if self.settings.reference != "inclinometer" or self._inclinometer is None:
            return
        for part in ctx.parts.alive():
            try:
                stops[part.socket].readings.append(self._inclinometer.read_angle(part.socket))
            except InstrumentError as exc:
                ctx.parts.drop(
                    part, Verdict.ERROR,
                    f"manual_stop: the inclinometer on socket {part.socket}'s fixture could not "
                    f"be read: {exc}",
                )

    # ------------------------------------------------------------ analysis

    def _reference(self, part: PartRun, stops: _PartStops) -> tuple[float, float]:
        cfg = self.settings
        if cfg.reference == "stored":
            assert cfg.stop_angle_deg is not None and cfg.stop_angle_u_deg is not None
            return cfg.stop_angle_deg, cfg.stop_angle_u_deg
        if cfg.reference == "fixture":
            ref, u_ref = stop_angle(part)
            return float(ref), float(u_ref)
        angles = np.array([a for a, _ in stops.readings])
        u_read = max(u for _, u in stops.readings)
        travel = np.abs(np.diff(angles))
        if travel.size == 0:
            raise AnalysisError("the inclinometer was not read at both stops")
        # each travel is two readings; their mean over the moves
        return float(travel.mean()), u_read * math.sqrt(2.0) / math.sqrt(travel.size)

    def _analyse(self, ctx: RunContext, part: PartRun, stops: _PartStops, t0: float,
                 t1: float) -> None:
        cfg = self.settings
        condition = self.place.condition_name
        data = samples_between(ctx, part, t0, t1)
        masked = dict(data, status=data["status"] & ~CLIP_BITS)  # over-range: warned, below
        if not check_window(ctx, part, masked, "manual stop method", cfg.static_s * 2):
            return
        try:
            ref, u_ref = self._reference(part, stops)
            result = analyze_stop_method(
                data["time_s"], data["rate_dps"], ref, u_ref, status=data["status"],
                settings=StopMethodSettings(full_scale_dps=ctx.product.range_dps),
                noise=stop_noise_model(ctx, part),
            )
            if result.scale is None or result.u_scale is None:
                raise AnalysisError("no usable move: " + "; ".join(result.warnings))
        except AnalysisError as exc:
            ctx.parts.drop(part, Verdict.ERROR, f"manual stop method: {exc}")
            return
        self._warn_bounces(ctx, part, data, result)
        self._record(ctx, part, result, ref, u_ref, condition, data["temp_c"])

    def _warn_bounces(self, ctx: RunContext, part: PartRun, data: dict[str, NDArray[Any]],
                      result: StopMethodResult) -> None:
        """A move whose rate reverses beyond the detection band bounced at the stop: one
        warning per part naming every such move (one line a move read as a flood)."""
        t, e = data["time_s"], data["rate_dps"] - result.bias_dps
        bounced: list[tuple[int, float]] = []
        for i, mv in enumerate(result.moves):
            sel = (t >= mv.start_s) & (t <= mv.end_s)
            back = float(np.max(-mv.direction * e[sel], initial=0.0))
            if back > self.settings.detect_dps:
                bounced.append((i + 1, back))
        if bounced:
            moves = ", ".join(str(n) for n, _ in bounced)
            worst = max(b for _, b in bounced)
            ctx.records.event(
                f"socket {part.socket}: the fixture bounced at the stop after "
                f"{'move' if len(bounced) == 1 else 'moves'} {moves} of {len(result.moves)} "
                f"(up to {worst:.1f} deg/s back); the moves still count (each angle is "
                "integrated through its bounce), but let the fixture come gently to the stop",
                "WARNING", [part],
            )

    def _record(self, ctx: RunContext, part: PartRun, result: StopMethodResult, ref: float,
                u_ref: float, condition: str, data_temp_c: NDArray[Any]) -> None:
        scale, u_scale = result.scale, result.u_scale
        assert scale is not None and u_scale is not None
        cond = condition or None
        ctx.records.measure(
            part, "raw_scale_error", scale - ctx.product.nominal_scale, units="1",
            uncertainty_k2=2 * u_scale, condition=cond,
            description="stop-method scale - nominal (fixture turned by hand)",
        )
        ctx.records.measure(
            part, "manual_stop_reference_angle_deg", ref, units="deg",
            uncertainty_k2=2 * u_ref, condition=cond,
            description=f"reference angle between the stops ({self.settings.reference})",
        )
        res = part.conditions.get(condition)
        if res is not None:
            res.stop = StopScale(scale, u_scale, result.bias_dps, ref, u_ref)
            res.note_temperature("scale", data_temp_c)
            # the conditions so far on the record (a later fit step writes them again), so a
            # procedure without a fit still shows its condition and stop scale
            part.record.conditions = [condition_record(r) for r in part.conditions.values()]
        for i, mv in enumerate(result.moves):
            ctx.records.segment(
                part, "stop_move", i, mv.start_s, mv.end_s,
                ref_angle_deg=ref * (1 if mv.direction > 0 else -1),
            )
        part.record.analysis.stop_method[condition or "manual"] = StopMethodResults(
            method="manual_stop",
            bias_dps=result.bias_dps,
            scale=scale,
            u_scale=u_scale,
            scale_correction=result.scale_correction,
            reference_angle_deg=ref,
            u_reference_angle_deg=u_ref,
            reference=self.settings.reference,
            static_windows=[[a, b] for a, b in result.static_segments_s],
            moves=[
                StopMove(start_s=m.start_s, end_s=m.end_s,
                         measured_angle_deg=m.measured_angle_deg,
                         peak_rate_dps=m.peak_rate_dps, over_range_samples=m.n_over_range,
                         scale_correction=m.scale_correction)
                for m in result.moves
            ],
            warnings=list(result.warnings),
        )


class VerifyManualStopSettings(ManualStopSettings):
    supply_v: Volts | None = Field(
        None, description="supply during verification (default: the product's V0)"
    )


class VerifyManualStop(ManualStop):
    """Verification on the hand-turned bench: the operator turns the fixture again, now on
    the part's own compensated output; the residual scale error is the compensated scale
    minus one, the residual bias the compensated output at rest."""

    type_name = "verify_manual_stop"
    Settings = VerifyManualStopSettings
    provides = frozenset()
    Results = Verification

    @classmethod
    def requires(cls, settings: Any) -> set[Provided]:
        return {Provided.PROGRAMMED}

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return [
            Declared("residual_bias_dps", "deg/s", "compensated output at rest (turned by hand)"),
            Declared("residual_scale_error", "1", "compensated stop-method scale - 1 (turned "
                     "by hand)"),
        ]

    def setup(self, ctx: RunContext) -> None:
        super().setup(ctx)
        supply_v = self.settings.supply_v  # type: ignore[attr-defined]
        self.supply_v = ctx.product.reference_supply_v if supply_v is None else supply_v
        ctx.instruments.set_supply_voltage(self.supply_v)

    def _record(self, ctx: RunContext, part: PartRun, result: StopMethodResult, ref: float,
                u_ref: float, condition: str, data_temp_c: NDArray[Any]) -> None:
        scale, u_scale = result.scale, result.u_scale
        assert scale is not None and u_scale is not None
        ctx.records.measure(
            part, "residual_bias_dps", result.bias_dps, units="deg/s",
            uncertainty_k2=2 * result.bias.u_bias_dps, condition="verify",
            description="compensated output at rest (fixture turned by hand)",
        )
        ctx.records.measure(
            part, "residual_scale_error", scale - 1.0, units="1",
            uncertainty_k2=2 * u_scale, condition="verify@stop",
            description="compensated stop-method scale - 1 (fixture turned by hand)",
        )
        for i, mv in enumerate(result.moves):
            ctx.records.segment(
                part, "verify", i, mv.start_s, mv.end_s,
                ref_angle_deg=ref * (1 if mv.direction > 0 else -1), supply_v=self.supply_v,
            )
        # a hand move has no set rate: its mean rate stands for "the rate" of the row
        move_s = float(np.mean([m.end_s - m.start_s for m in result.moves]))
        rate_in = ref / move_s if move_s > 0 else math.nan
        part.record.verification = Verification(
            method="manual_stop",
            residuals=[VerificationRow(
                condition="verify@stop",
                rate_in_dps=rate_in,
                error_dps=(scale - 1.0) * rate_in,
                error_pct=100 * (scale - 1.0),
                u_error_pct_k2=200 * u_scale,
            )],
            residual_bias_dps=result.bias_dps,
            max_error_pct=abs(100 * (scale - 1.0)),
            supply_v=self.supply_v,
            reference=self.settings.reference,
            reference_angle_deg=ref,
            u_reference_angle_deg=u_ref,
        )
