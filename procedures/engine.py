"""The procedure engine: steps with setup/main/cleanup, run under one guaranteed cleanup.

A run is a list of steps (`procedures.steps.build_plan`). Each step has `setup`, `main` and
`cleanup`; `cleanup` always runs. The whole run is wrapped (bluesky's finalize_wrapper idea)
so that on every exit path - pass, fail, error, timeout, operator abort, SIGINT - the table is
brought to rest, the streams stop, the supply is switched off and the chamber goes to its safe
setpoint. Callers never have to remember it.

Several parts run at once: one table sweep and one thermal cycle serve every loaded socket;
each part has its own record, raw data file and verdict. A problem with one part (absent,
wrong serial, silent, corrupted stream) drops that part only; a problem with a shared
instrument (table, chamber, supply) ends the run for all parts in ERROR, with the reason.

Timeouts and aborts are cooperative: steps wait through `RunContext.sleep` / `check`, which
raise `StepTimeout` or `Aborted`; `abort()` also interrupts the clock so a long dwell ends
at once.
"""

from __future__ import annotations

import datetime as dt
import logging
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from drivers.clock import ScaledClock
from drivers.errors import (
    InstrumentError,
    InstrumentTimeout,
    PartAbsent,
    PartSilent,
    StreamCorrupted,
)
from drivers.protocols import Chamber, PartLink, RateTable, Supply, TableStatus
from procedures.config import ProcedureConfig, ProductConfig
from procedures.limits import judge, overall
from procedures.progress import ProgressBus, ProgressEvent
from procedures.rawdata import RawDataWriter
from procedures.record import (
    ConditionRecord,
    Event,
    Measurement,
    Outcome,
    RunRecord,
    Verdict,
    write_record,
)
from procedures.safe_state import (
    InstrumentSafeState,
    SafeStatePass,
    SafeStatePolicy,
    SafeStateReport,
    SafeTarget,
    chamber_target,
    supply_target,
    table_target,
)
from procedures.streams import Acquisition, PartStream
from procedures.watchdog import Watchdog

log = logging.getLogger(__name__)
SUPPLY_SETTLE_S = 0.2  # station seconds after a change of supply setting before reading it


class Aborted(Exception):  # noqa: N818 - reads as the event it is
    """The operator aborted the run."""


class StepTimeout(Exception):  # noqa: N818
    """A step ran longer than its policy allows."""


class NoPartsLeft(Exception):  # noqa: N818
    """Every part has dropped out; nothing left to measure."""


@dataclass
class Bench:
    """The instruments of one run (shared by every socket) and the station clock."""

    chamber: Chamber
    supply: Supply
    links: dict[int, PartLink]
    clock: ScaledClock
    table: RateTable | None = None


@dataclass
class ConditionResult:
    """What one part measured at one condition (engineering units, k=1 uncertainties)."""

    name: str
    temperature_c: float
    supply_v: float
    die_temperature_c: float | None = None
    supply_measured_v: float | None = None
    supply_current_a: float | None = None
    time_to_stability_s: float | None = None
    stable: bool | None = None
    bias_dps: float | None = None
    u_bias_dps: float | None = None
    table_fit: Any = None  # procedures.analysis.rate_table.RateTableFit
    # die temperature over the measurement windows: the bias and the scale are each paired
    # with the temperature of their own windows (the die may still creep within a condition)
    temp_sums: dict[str, tuple[float, int]] = field(default_factory=dict)

    def note_temperature(self, kind: str, temp_c: Any) -> None:
        """Add a window's die temperatures to `kind` ("bias" or "scale")."""
        arr = np.asarray(temp_c, dtype=np.float64)
        if arr.size:
            total, n = self.temp_sums.get(kind, (0.0, 0))
            self.temp_sums[kind] = (total + float(arr.sum()), n + int(arr.size))
            all_sum = sum(v[0] for v in self.temp_sums.values())
            all_n = sum(v[1] for v in self.temp_sums.values())
            self.die_temperature_c = all_sum / all_n

    def temperature_for(self, kind: str) -> float | None:
        if kind in self.temp_sums:
            total, n = self.temp_sums[kind]
            return total / n
        return self.die_temperature_c

    stop: dict[str, Any] | None = None  # scale, u_scale, bias, moves...


class RowBuffer:
    """Rows for raw.h5's small groups (table, chamber, supply, segments, events), written in
    batches (end of each step, and every 2 wall s): an HDF5 flush per row costs wall time,
    which the simulated bench's fast clock turns into minutes of station time."""

    def __init__(self, writer: RawDataWriter | None) -> None:
        self.writer = writer
        self._rows: dict[str, list[dict[str, Any]]] = {}
        self._last_flush_wall = time.monotonic()

    def flush_if_due(self, every_wall_s: float = 2.0) -> None:
        """Flush when rows have waited `every_wall_s` (a killed run loses at most that)."""
        if self._rows and time.monotonic() - self._last_flush_wall > every_wall_s:
            self.flush()

    def append(self, group: str, **columns: Any) -> None:
        if self.writer is not None:
            self._rows.setdefault(group, []).append(columns)

    def flush(self) -> None:
        if self.writer is None:
            return
        rows, self._rows = self._rows, {}
        self._last_flush_wall = time.monotonic()
        for group, items in rows.items():
            merged = {k: [row[k] for row in items] for k in items[0]}
            try:
                self.writer.append(group, **merged)
            except Exception:  # never lose a run over a log row
                log.exception("could not write %d rows to raw data group %s", len(items), group)


@dataclass
class PartRun:
    """One socket's part: its record, data file, stream and state."""

    socket: int
    serial: str
    folder: Path
    record: RunRecord
    writer: RawDataWriter | None = None
    stream: PartStream | None = None
    alive: bool = True
    verdict: Verdict | None = None
    reason: str = ""
    conditions: dict[str, ConditionResult] = field(default_factory=dict)
    fit: Any = None
    extra: dict[str, Any] = field(default_factory=dict)
    rows: RowBuffer = field(default_factory=lambda: RowBuffer(None))

    def __post_init__(self) -> None:
        self.rows = RowBuffer(self.writer)

    @property
    def link(self) -> PartLink:
        assert self.stream is not None
        return self.stream.link


class Step(Protocol):
    """One step of a procedure; `policy` names its timeout/retry entry in `steps:`."""

    name: str
    policy: str
    condition: str

    def estimate_s(self, ctx: RunContext) -> float: ...

    def setup(self, ctx: RunContext) -> None: ...

    def main(self, ctx: RunContext) -> None: ...

    def cleanup(self, ctx: RunContext) -> None: ...


def _utc() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")


class RunContext:
    """What a step sees: instruments, configs, parts, and the waiting/progress helpers."""

    def __init__(
        self,
        bench: Bench,
        procedure: ProcedureConfig,
        product: ProductConfig,
        parts: list[PartRun],
        progress: ProgressBus | None = None,
    ) -> None:
        self.bench = bench
        self.procedure = procedure
        self.product = product
        self.parts = parts
        for part in parts:  # the product says how its parts' codes read
            if part.stream is not None:
                part.stream.codes = product.codes
        self.progress = progress or ProgressBus()
        self.clock = bench.clock
        self._abort = threading.Event()
        self.abort_reason = ""
        self.step_name = ""
        self.condition = ""
        self._deadline_s: float | None = None
        self._step_started_s = 0.0
        self._step_estimate_s = 0.0
        self.done_estimate_s = 0.0
        self.total_estimate_s = 1.0
        self._last_progress_wall = 0.0
        self.watchdog = Watchdog({"rate_table": bench.table, "chamber": bench.chamber}, bench.clock)

    # ------------------------------------------------------------ parts

    def alive(self) -> list[PartRun]:
        return [p for p in self.parts if p.alive]

    def drop(self, part: PartRun, verdict: Verdict, reason: str) -> None:
        """Take one part out of the run (the others go on)."""
        if not part.alive:
            return
        part.alive = False
        part.verdict = verdict
        part.reason = reason
        self.event(
            f"socket {part.socket} ({part.serial}) dropped: {verdict}: {reason}",
            level="ERROR",
            parts=[part],
        )
        if part.stream is not None:
            try:
                part.stream.stop()
            except Exception as exc:  # the link is probably what failed
                log.info("socket %d: stop after drop failed: %s", part.socket, exc)
        self.save(part)
        self._publish("part", message=f"socket {part.socket}: {verdict}")

    def per_part(self, part: PartRun, fn: Callable[[PartRun], Any]) -> Any:
        """Run `fn(part)`; a part-level instrument error drops this part only."""
        try:
            return fn(part)
        except (PartAbsent, PartSilent, StreamCorrupted) as exc:
            self.drop(part, Verdict.ERROR, str(exc))
        except InstrumentError as exc:
            if exc.instrument.startswith("fixture") or "fixture" in exc.instrument:
                self.drop(part, Verdict.ERROR, str(exc))
            else:
                raise
        return None

    def each(self, fn: Callable[[PartRun], Any]) -> None:
        for part in self.alive():
            self.per_part(part, fn)
        self.require_parts()

    def require_parts(self) -> None:
        if not self.alive():
            raise NoPartsLeft("every part has dropped out of the run")

    # ------------------------------------------------------------ waiting

    def abort(self, reason: str = "operator abort") -> None:
        """Ask the run to stop now (thread-safe; SIGINT handlers and the UI call this)."""
        self.abort_reason = reason
        self._abort.set()
        self.clock.interrupt()

    @property
    def aborted(self) -> bool:
        return self._abort.is_set()

    def check(self) -> None:
        """Raise Aborted / StepTimeout when due; drop parts whose stream failed."""
        if self._abort.is_set():
            raise Aborted(self.abort_reason or "operator abort")
        self.watchdog.poll()
        limit = self.procedure.stream.max_lost_fraction
        for part in self.alive():
            part.rows.flush_if_due()
            stream = part.stream
            if stream is None:
                continue
            if stream.error is not None:
                # a silent part is often a shorted one: a current-limiting supply is the
                # real reason, and it concerns every part on that supply
                self.supply_reading()
                self.drop(part, Verdict.ERROR, str(stream.error))
                continue
            lost, total = stream.frames_lost, stream.frames_lost + stream.frames_ok
            if lost > 10 and lost > limit * total:
                self.drop(
                    part,
                    Verdict.ERROR,
                    (
                        f"socket {part.socket}: stream corrupted: {lost} of {total} frames lost "
                        f"({stream.frames_corrupted} with a bad CRC), more than the "
                        f"{limit:g} allowed: check the fixture cable and its grounding"
                    ),
                )
        self.require_parts()
        if self._deadline_s is not None and self.clock.now_s() > self._deadline_s:
            raise StepTimeout(
                f"step {self.step_name} took longer than its timeout "
                f"({self.procedure.steps.policy(self.step_policy).timeout_s:g} s); "
                "raise steps.<step>.timeout_s in the procedure file if this is expected"
            )
        self._maybe_progress()

    def sleep(self, duration_s: float, slice_s: float = 1.0) -> None:
        """Wait `duration_s` station seconds, checking abort/timeout/streams in between."""
        end = self.clock.now_s() + duration_s
        while True:
            self.check()
            left = end - self.clock.now_s()
            if left <= 0:
                return
            self.clock.sleep_s(min(left, max(slice_s, self.clock.check_every_s)))

    def snapshot(self) -> tuple[float, TableStatus]:
        """Table status with the station time at the middle of the read; logged to raw data."""
        table = self.bench.table
        assert table is not None
        t0 = self.clock.now_s()
        status = table.read_status()
        t = 0.5 * (t0 + self.clock.now_s())
        bits = (
            int(status.ready)
            | int(status.enabled) << 1
            | int(status.fault) << 2
            | int(status.in_position) << 3
            | int(status.at_rate) << 4
            | int(status.moving) << 5
            | int(status.interlock_open) << 7
        )
        counts = status.encoder_counts_unwrapped or status.encoder_counts
        self.append_all(
            "table",
            station_time_s=t,
            controller_time_s=status.controller_time_s,
            encoder_counts=counts,
            position_deg=status.position_deg,
            rate_dps=status.rate_dps,
            status=bits,
        )
        return t, status

    def log_environment(self) -> tuple[float, float, float]:
        """Read chamber and supply once, log them to every part's raw data."""
        t = self.clock.now_s()
        chamber_c = self.bench.chamber.read_temperature()
        setpoint = self.bench.chamber.read_setpoint()
        self.append_all("chamber", station_time_s=t, setpoint_c=setpoint, temp_c=chamber_c)
        volts, amps = self.log_supply()
        return chamber_c, volts, amps

    def set_supply_voltage(self, volts: float) -> None:
        """Set the supply with a logged reading just before and just after, so the raw data
        brackets the moment the parts' supply changed (the discrepancy workflow uses the
        samples between windows only where the supply is known)."""
        supply = self.bench.supply
        self.log_supply()
        supply.set_voltage(volts)
        supply.check_errors()
        self.sleep(SUPPLY_SETTLE_S)  # a real supply slews: read it once it has settled
        self.log_supply()

    def log_supply(self) -> tuple[float, float]:
        """Read the supply once and log it to every part's raw data."""
        t = self.clock.now_s()
        volts, amps = self.supply_reading()
        self.append_all("supply", station_time_s=t, voltage_v=volts, current_a=amps)
        return volts, amps

    def supply_reading(self) -> tuple[float, float]:
        """(volts, amps); raises SupplyCurrentLimit when the supply is current-limiting."""
        supply = self.bench.supply
        check = getattr(supply, "check_current_limit", None)
        if check is not None:
            volts, amps = check()
            return float(volts), float(amps)
        return supply.measure_voltage(), supply.measure_current()

    # ------------------------------------------------------------ records and events

    def append_all(self, group: str, parts: list[PartRun] | None = None, **columns: Any) -> None:
        for part in parts if parts is not None else self.alive():
            part.rows.append(group, **columns)

    def segment(
        self,
        part: PartRun,
        kind: str,
        index: int,
        start_s: float,
        end_s: float,
        ref_rate_dps: float = np.nan,
        ref_angle_deg: float = np.nan,
        temp_setpoint_c: float = np.nan,
        supply_v: float = np.nan,
    ) -> None:
        part.rows.append(
            "segments",
            condition=self.condition,
            kind=kind,
            index=index,
            start_s=start_s,
            end_s=end_s,
            ref_rate_dps=ref_rate_dps,
            ref_angle_deg=ref_angle_deg,
            temp_setpoint_c=temp_setpoint_c,
            supply_v=supply_v,
        )

    def event(self, message: str, level: str = "INFO", parts: list[PartRun] | None = None) -> None:
        t = self.clock.now_s()
        log.log(logging.WARNING if level != "INFO" else logging.INFO, "%s", message)
        for part in parts if parts is not None else self.alive():
            part.record.events.append(
                Event(
                    time_utc=_utc(),
                    station_time_s=round(t, 3),
                    level=level,
                    step=self.step_name,
                    message=message,
                )
            )
            part.rows.append("events", station_time_s=t, text=message)
        self._publish("log", message=message)

    def measure(
        self,
        part: PartRun,
        name: str,
        value: float | None,
        *,
        units: str = "",
        limit_name: str | None = None,
        uncertainty_k2: float | None = None,
        condition: str | None = None,
        description: str = "",
    ) -> Measurement:
        """Record a measurement judged against the product limits, where it is made."""
        m = judge(
            name,
            value,
            self.product.limits,
            units=units,
            limit_name=limit_name,
            uncertainty_k2=uncertainty_k2,
            condition=condition,
            description=description,
        )
        part.record.measurements.append(m)
        return m

    def save(self, part: PartRun) -> None:
        part.rows.flush()
        write_record(part.folder, part.record)

    def save_all(self) -> None:
        for part in self.parts:
            try:
                self.save(part)
            except OSError:
                log.exception("could not write record of socket %d", part.socket)

    # ------------------------------------------------------------ progress

    @property
    def step_policy(self) -> str:
        return getattr(self, "_policy", "default")

    def begin_step(self, step: Step, estimate_s: float) -> None:
        self.step_name = step.name
        self.condition = step.condition
        self._policy = step.policy
        self._step_started_s = self.clock.now_s()
        self._step_estimate_s = estimate_s
        self._deadline_s = self._step_started_s + self.procedure.steps.policy(step.policy).timeout_s
        self._publish(
            "step", message=f"{step.name}" + (f" at {step.condition}" if step.condition else "")
        )

    def end_step(self) -> None:
        self.done_estimate_s += self._step_estimate_s
        self._deadline_s = None

    def _fraction(self) -> tuple[float, float]:
        in_step = min(self.clock.now_s() - self._step_started_s, self._step_estimate_s)
        done = self.done_estimate_s + max(in_step, 0.0)
        return min(done / self.total_estimate_s, 1.0), max(self.total_estimate_s - done, 0.0)

    def _maybe_progress(self) -> None:
        now = time.monotonic()
        if now - self._last_progress_wall >= 0.2:
            self._last_progress_wall = now
            self._publish("progress")

    def socket_states(self) -> dict[int, str]:
        return {p.socket: ("RUNNING" if p.alive else str(p.verdict)) for p in self.parts}

    def _publish(self, kind: str, message: str = "") -> None:
        fraction, remaining = self._fraction()
        self.progress.publish(
            ProgressEvent(
                kind=kind,
                step=self.step_name,
                condition=self.condition,
                fraction=fraction,
                station_time_s=self.clock.now_s(),
                remaining_s=remaining,
                message=message,
                sockets=self.socket_states(),
            )
        )


# ---------------------------------------------------------------- the engine


@contextmanager
def finalize(cleanup: Callable[[], None]) -> Iterator[None]:
    """Run the body, then `cleanup` on every exit path (bluesky's finalize_wrapper)."""
    try:
        yield
    finally:
        cleanup()


RETRYABLE = (InstrumentTimeout, StepTimeout)


class Engine:
    """Runs a plan of steps for every loaded part; see the module docstring."""

    def __init__(self, ctx: RunContext, steps: list[Step]) -> None:
        self.ctx = ctx
        self.steps = steps
        self.safe_state_report: dict[str, str] = {}
        self.safe_state: SafeStateReport | None = None
        self.safe_state_policy = SafeStatePolicy()

    def abort(self, reason: str = "operator abort") -> None:
        self.ctx.abort(reason)

    def run(self) -> dict[int, Verdict]:
        ctx = self.ctx
        started = ctx.clock.now_s()
        estimates = [max(step.estimate_s(ctx), 0.0) for step in self.steps]
        ctx.total_estimate_s = max(sum(estimates), 1.0)
        for part in ctx.parts:
            part.record.analysis.setdefault("plan", {})["estimated_station_s"] = (
                ctx.total_estimate_s
            )
        ctx.save_all()
        run_error: tuple[Verdict, str] | None = None
        streams = {p.socket: p.stream for p in ctx.parts if p.stream is not None}
        acquisition = Acquisition(streams)
        with finalize(lambda: self._finish(acquisition, started, run_error)):
            acquisition.__enter__()
            try:
                for step, estimate in zip(self.steps, estimates, strict=True):
                    if not ctx.alive():
                        break
                    self._run_step(step, estimate)
            except Aborted as exc:
                run_error = (
                    Verdict.ABORTED,
                    f"aborted by the operator ({exc}) in step {ctx.step_name}",
                )
            except NoPartsLeft:
                pass
            except StepTimeout as exc:
                run_error = (Verdict.ERROR, str(exc))
            except InstrumentError as exc:
                run_error = (Verdict.ERROR, f"{exc.instrument}: {exc} (in step {ctx.step_name})")
            except KeyboardInterrupt:
                run_error = (Verdict.ABORTED, f"interrupted (SIGINT) in step {ctx.step_name}")
            except Exception as exc:  # a bug must still end in a safe bench and a record
                log.exception("unexpected error in step %s", ctx.step_name)
                run_error = (
                    Verdict.ERROR,
                    f"internal error in step {ctx.step_name}: "
                    f"{type(exc).__name__}: {exc}; report this with the run folder",
                )
        return {p.socket: p.verdict or Verdict.ERROR for p in ctx.parts}

    def _run_step(self, step: Step, estimate_s: float) -> None:
        ctx = self.ctx
        policy = ctx.procedure.steps.policy(step.policy)
        for attempt in range(policy.retries + 1):
            ctx.begin_step(step, estimate_s)
            t0 = ctx.clock.now_s()
            try:
                ctx.watchdog.poll(force=True)  # every step starts on a checked bench
                step.setup(ctx)
                step.main(ctx)
                return
            except RETRYABLE as exc:
                if attempt >= policy.retries or ctx.aborted:
                    raise
                ctx.event(
                    f"{step.name}: {exc}; retrying ({attempt + 1}/{policy.retries})",
                    level="WARNING",
                )
            finally:
                try:
                    step.cleanup(ctx)
                finally:
                    key = step.name + (f"[{step.condition}]" if step.condition else "")
                    for part in ctx.parts:
                        part.record.timings[key] = round(ctx.clock.now_s() - t0, 3)
                    ctx.end_step()
                    ctx.save_all()

    # ------------------------------------------------------------ the guaranteed end

    def _safe_state(self, acquisition: Acquisition) -> SafeStateReport:
        """Table to rest, streams stopped, supply off, chamber to its safe setpoint: each
        read back from the instrument itself, retried until safe or the deadline passes."""
        bench, ctx = self.ctx.bench, self.ctx
        safe_temp_c = ctx.procedure.chamber.safe_temp_c
        targets: list[SafeTarget] = []
        if bench.table is not None:
            targets.append(table_target(bench.table))
        targets.append(SafeTarget("streams", acquisition.close, retry=False))
        targets.append(supply_target(bench.supply))
        targets.append(chamber_target(bench.chamber, safe_temp_c))
        try:
            report = SafeStatePass(targets, ctx.clock, self.safe_state_policy).run()
        except Exception as exc:  # a bug here must still end in a record that says so
            log.exception("the safe-state pass failed")
            report = SafeStateReport(
                instruments={
                    t.name: InstrumentSafeState(
                        t.name, False, f"internal error in the safe-state pass: {exc}"
                    )
                    for t in targets
                }
            )
        report.safe_temp_c = safe_temp_c
        self.safe_state = report
        self.safe_state_report = report.legacy()
        for state in report.instruments.values():
            if state.safe:
                ctx.event(
                    f"safe state: {state.label} safe ({state.detail}; {state.attempts} "
                    "attempt(s))",
                    parts=ctx.parts,
                )
            else:
                ctx.event(
                    f"SAFE STATE FAILED: {state.label} is NOT safe: {state.detail}",
                    level="ERROR",
                    parts=ctx.parts,
                )
        return report

    def _finish(
        self, acquisition: Acquisition, started_s: float, run_error: tuple[Verdict, str] | None
    ) -> None:
        ctx = self.ctx
        ctx.step_name = "cleanup"
        report = self._safe_state(acquisition)
        unsafe = report.failure_text()
        if unsafe:  # a bench left unsafe is an ERROR whatever else happened, and says so
            run_error = (Verdict.ERROR, f"{run_error[1]}; {unsafe}" if run_error else unsafe)
            for part in ctx.parts:
                if not part.alive:
                    part.verdict = Verdict.ERROR
                    part.reason = f"{part.reason}; {unsafe}" if part.reason else unsafe
        for part in ctx.parts:
            if part.alive and part.stream is not None:
                lost, ok = part.stream.frames_lost, part.stream.frames_ok
                ctx.measure(
                    part,
                    "frames_lost_fraction",
                    lost / max(lost + ok, 1),
                    units="1",
                    description=f"{lost} of {lost + ok} frames lost over the run",
                )
            if part.alive:
                if run_error is not None:
                    part.verdict, part.reason = run_error
                else:
                    self._judge(part)
                part.alive = False
            rec = part.record
            rec.verdict = part.verdict or Verdict.ERROR
            rec.reason = part.reason
            rec.finished_utc = _utc()
            rec.timings["total"] = round(ctx.clock.now_s() - started_s, 3)
            rec.analysis["safe_state"] = dict(self.safe_state_report)
            rec.analysis["safe_state_report"] = report.as_record()
            if part.stream is not None:
                rec.analysis["stream"] = {
                    "frames_ok": part.stream.frames_ok,
                    "frames_lost": part.stream.frames_lost,
                    "frames_corrupted": part.stream.frames_corrupted,
                }
            rec.events.append(
                Event(
                    time_utc=_utc(),
                    station_time_s=round(ctx.clock.now_s(), 3),
                    level="INFO" if rec.verdict in (Verdict.PASS, Verdict.FAIL) else "ERROR",
                    step="finish",
                    message=f"verdict {rec.verdict}" + (f": {rec.reason}" if rec.reason else ""),
                )
            )
            part.rows.flush()
            if part.writer is not None:
                try:
                    part.writer.close()
                except Exception:
                    log.exception("closing raw data of socket %d", part.socket)
            ctx.save(part)
        ctx.step_name = ""
        ctx._publish("finished", message=", ".join(f"{p.socket}:{p.verdict}" for p in ctx.parts))

    def _judge(self, part: PartRun) -> None:
        ok, failed, marginal = overall(part.record.measurements)
        not_measured = [
            m.name for m in part.record.measurements if m.outcome is Outcome.NOT_MEASURED
        ]
        part.record.failed_measurements = failed
        if marginal:
            part.record.analysis["marginal_measurements"] = marginal
        if ok:
            part.verdict = Verdict.PASS
            part.reason = "all measurements within limits" + (
                f" ({len(marginal)} marginal: {', '.join(marginal)})" if marginal else ""
            )
        else:
            part.verdict = Verdict.FAIL
            part.reason = f"out of limits: {', '.join(failed)}"
        if not_measured:
            part.record.analysis["not_measured"] = not_measured


def condition_record(result: ConditionResult) -> ConditionRecord:
    fit = result.table_fit
    stop = result.stop or {}
    return ConditionRecord.model_validate(
        dict(
            name=result.name,
            temperature_c=result.temperature_c,
            supply_v=result.supply_v,
            die_temperature_c=result.die_temperature_c,
            time_to_stability_s=result.time_to_stability_s,
            stable=result.stable,
            bias_dps=result.bias_dps,
            bias_uncertainty_dps=None if result.u_bias_dps is None else 2 * result.u_bias_dps,
            scale_table=None if fit is None else fit.scale,
            scale_table_uncertainty=None if fit is None else 2 * fit.u_scale,
            scale_stop=stop.get("scale"),
            scale_stop_uncertainty=None if stop.get("u_scale") is None else 2 * stop["u_scale"],
            supply_current_a=result.supply_current_a,
            supply_measured_v=result.supply_measured_v,
        )
    )
