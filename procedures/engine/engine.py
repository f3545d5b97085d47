"""The procedure engine: steps with setup/main/cleanup, run under one guaranteed cleanup.

A run is a list of steps (`ProcedureConfig.plan()`, from the procedure file's `steps:`
list). Each step has `setup`, `main` and
`cleanup`; `cleanup` always runs. The whole run is wrapped (bluesky's finalize_wrapper idea)
so that on every exit path - pass, fail, error, timeout, operator abort, SIGINT - the table is
brought to rest, the streams stop, the supply is switched off and the chamber goes to its safe
setpoint. Callers never have to remember it.

Several parts run at once: one table sweep and one thermal cycle serve every loaded socket;
each part has its own record, raw data file and verdict. A problem with one part (absent,
wrong serial, silent, corrupted stream) drops that part only; a problem with a shared
instrument (table, chamber, supply) ends the run for all parts in ERROR, with the reason.

Timeouts and aborts are cooperative: steps wait through `ctx.wait.sleep` / `check`, which
raise `StepTimeout` or `Aborted`; `abort()` also interrupts the clock so a long dwell ends
at once. A declared measurement a step never set is recorded NOT_MEASURED when the step ends.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Protocol

from drivers.errors import InstrumentError, InstrumentTimeout
from procedures.engine.safe_state import (
    InstrumentSafeState,
    SafeStatePass,
    SafeStatePolicy,
    SafeStateReport,
    SafeTarget,
    chamber_target,
    streams_target,
    supply_target,
    table_target,
)
from procedures.runtime.limits import overall
from procedures.runtime.record import Event, Outcome, Verdict, os_error_text, save_record_anywhere
from procedures.runtime.results import PlanResults, SafeStateResults, StreamResults
from procedures.runtime.run_context import (
    Aborted,
    NoPartsLeft,
    RunContext,
    StepTimeout,
    utc_now,
)
from procedures.runtime.run_parts import KeptRecord, PartRun
from procedures.runtime.streams import Acquisition
from procedures.steps.registry import Declared, StepPolicy, StepSettings

log = logging.getLogger(__name__)


class Step(Protocol):
    """One step of a procedure: what the engine calls on it (procedures.steps.registry.StepType
    is the full interface, and every step type's base)."""

    @property
    def name(self) -> str: ...

    @property
    def condition(self) -> str: ...

    @property
    def policy(self) -> StepPolicy: ...

    @property
    def settings(self) -> StepSettings: ...

    def measurements(self, settings: StepSettings) -> list[Declared]: ...

    def expected(self) -> list[Declared]: ...

    def estimate_s(self, ctx: RunContext) -> float: ...

    def setup(self, ctx: RunContext) -> None: ...

    def main(self, ctx: RunContext) -> None: ...

    def cleanup(self, ctx: RunContext) -> None: ...


def sockets_of(step: Step) -> frozenset[int] | None:
    """The sockets a step measures (`StepType.sockets`; None, or no such attribute: every
    part still running)."""
    return getattr(step, "sockets", None)


def follow_ups(step: Step) -> Sequence[Step]:
    """The steps a step asks to run next (`StepType.follow_up`; none without it)."""
    follow_up = getattr(step, "follow_up", None)
    return follow_up() if follow_up is not None else ()


# ---------------------------------------------------------------- the engine


@contextmanager
def finalize(cleanup: Callable[[], None]) -> Iterator[None]:
    """Run the body, then `cleanup` on every exit path (bluesky's finalize_wrapper)."""
    try:
        yield
    finally:
        cleanup()


RETRYABLE = (InstrumentTimeout, StepTimeout)


class BenchNotSafe(Exception):  # noqa: N818 - a state, like Aborted
    """The bench could not be made safe before the first step (the message says which
    instrument and what it read back)."""


class Engine:
    """Runs a plan of steps for every loaded part; see the module docstring."""

    def __init__(
        self,
        ctx: RunContext,
        steps: Sequence[Step],
        safe_state_policy: SafeStatePolicy | None = None,
    ) -> None:
        self.ctx = ctx
        self.steps = steps
        self.safe_state_report: dict[str, str] = {}
        self.safe_state: SafeStateReport | None = None
        self.safe_state_policy = safe_state_policy or SafeStatePolicy()

    def abort(self, reason: str = "the operator aborted the run") -> None:
        self.ctx.wait.abort(reason)

    def run(self) -> dict[int, Verdict]:
        ctx = self.ctx
        started = ctx.wait.now_s()
        estimates = [max(step.estimate_s(ctx), 0.0) for step in self.steps]
        ctx.progress.total_estimate_s = max(sum(estimates), 1.0)
        for part in ctx.parts:
            part.record.analysis.plan = PlanResults(
                estimated_station_s=ctx.progress.total_estimate_s,
                steps=list(dict.fromkeys(step.name for step in self.steps)),
            )
        ctx.records.save_all()
        run_error: tuple[Verdict, str] | None = None
        streams = {p.socket: p.stream for p in ctx.parts if p.stream is not None}
        acquisition = Acquisition(streams)
        with finalize(lambda: self._finish(acquisition, started, run_error)):
            acquisition.__enter__()
            step_name = ""
            try:
                self._start_safe()
                queue = deque(zip(self.steps, estimates, strict=True))
                while queue and ctx.parts.alive():
                    step, estimate = queue.popleft()
                    step_name = step.name
                    with ctx.parts.only(sockets_of(step)):
                        self._run_step(step, estimate)
                    # a step may ask for steps to run next (a condition measured again)
                    queue.extendleft(reversed([(s, s.estimate_s(ctx)) for s in follow_ups(step)]))
            except Aborted as exc:
                run_error = (
                    (Verdict.ERROR, f"{exc} (in step {step_name})")
                    if exc.error
                    # the reason says who asked ("the operator pressed ABORT on the station
                    # screen", "... (SIGTERM)"): said once, not wrapped in a second "operator"
                    else (Verdict.ABORTED, f"aborted: {exc}, in step {step_name}")
                )
            except NoPartsLeft:
                pass
            except BenchNotSafe as exc:
                run_error = (Verdict.ERROR, str(exc))
            except StepTimeout as exc:
                run_error = (Verdict.ERROR, str(exc))
            except InstrumentError as exc:
                run_error = (Verdict.ERROR, f"{exc.instrument}: {exc} (in step {step_name})")
            except KeyboardInterrupt:
                run_error = (Verdict.ABORTED, f"interrupted (SIGINT) in step {step_name}")
            except OSError as exc:  # a disk full, read-only or failing: named, not a bug
                log.error("step %s: %s", step_name, exc)
                run_error = (Verdict.ERROR, f"{os_error_text(exc)} (in step {step_name})")
            except Exception as exc:  # a bug must still end in a safe bench and a record
                log.exception("unexpected error in step %s", step_name)
                run_error = (
                    Verdict.ERROR,
                    f"internal error in step {step_name}: "
                    f"{type(exc).__name__}: {exc}; report this with the run folder",
                )
        return {p.socket: p.verdict or Verdict.ERROR for p in ctx.parts}

    def _run_step(self, step: Step, estimate_s: float) -> None:
        ctx = self.ctx
        retries, timeout_s = step.policy.retries, step.policy.timeout_s
        for attempt in range(retries + 1):
            ctx.progress.begin(step.name, step.condition, estimate_s)
            self._declare(step)
            t0 = ctx.wait.now_s()
            ctx.wait.deadline_s, ctx.wait.timeout_s = t0 + timeout_s, timeout_s
            try:
                ctx.wait.watchdog.poll(force=True)  # every step starts on a checked bench
                step.setup(ctx)
                step.main(ctx)
                self._mark_not_measured(step)
                return
            except RETRYABLE as exc:
                if attempt >= retries or ctx.wait.aborted:
                    raise
                ctx.records.event(
                    f"{step.name}: {exc}; retrying ({attempt + 1}/{retries})",
                    level="WARNING",
                )
            finally:
                try:
                    step.cleanup(ctx)
                finally:
                    key = step.name + (f"[{step.condition}]" if step.condition else "")
                    elapsed, only = ctx.wait.now_s() - t0, sockets_of(step)
                    for part in ctx.parts:
                        if only is None:
                            part.record.timings[key] = round(elapsed, 3)
                        elif part.socket in only:  # run again: adds to its time
                            first = part.record.timings.get(key, 0.0)
                            part.record.timings[key] = round(first + elapsed, 3)
                    ctx.progress.end()
                    ctx.wait.deadline_s = None
                    ctx.records.declared = None
                    ctx.records.save_all()

    def _declare(self, step: Step) -> None:
        """The names the step may set (a measurement it does not declare is refused)."""
        self.ctx.records.made = {}
        self.ctx.records.declared = {d.name for d in step.measurements(step.settings)}

    def _mark_not_measured(self, step: Step) -> None:
        """A declared measurement the step never set, on a part still running: NOT_MEASURED."""
        ctx = self.ctx
        for part in ctx.parts.alive():
            made = ctx.records.made.get(part.socket, set())
            for d in step.expected():
                if d.name not in made:
                    ctx.records.not_measured(part, d.name, d.units, step.condition or None)

    # ------------------------------------------------------------ the safe start

    def _start_safe(self) -> None:
        """Before the first step, the bench is made safe whatever state it was found in (a
        crashed run may have left the table turning, the supply on and the fixtures
        streaming): the same pass as at the end, each instrument read back. A bench that
        cannot be made safe ends the run before any step, as ERROR."""
        ctx = self.ctx
        targets = self._safe_targets(None)
        try:
            report = SafeStatePass(targets, ctx.wait.clock, self.safe_state_policy).run()
        except Exception as exc:  # a bug here must not start a run on an unknown bench
            log.exception("the safe-state pass before the first step failed")
            raise BenchNotSafe(
                f"internal error making the bench safe before the first step: {exc}; "
                "report this with the run folder"
            ) from exc
        report.safe_temp_c = ctx.procedure.chamber.safe_temp_c
        for part in ctx.parts:
            part.record.analysis.start_safe_state = SafeStateResults.model_validate(
                report.as_record()
            )
        for state in report.instruments.values():
            if state.safe:
                ctx.records.event(f"safe before the first step: {state.label} ({state.detail})")
            else:
                ctx.records.event(
                    f"NOT SAFE before the first step: {state.label}: {state.detail}",
                    level="ERROR",
                )
        if not report.all_safe:
            raise BenchNotSafe(
                "the bench could not be made safe before the first step, nothing was run: "
                + report.failure_text()
            )

    def _safe_targets(self, before_streams: Callable[[], None] | None) -> list[SafeTarget]:
        """Table, streams (`before_streams` first: the station's own), supply, chamber."""
        bench, ctx = self.ctx.bench, self.ctx
        targets: list[SafeTarget] = []
        if bench.table is not None:
            targets.append(table_target(bench.table))
        targets.append(streams_target(bench.links, before_streams))
        targets.append(supply_target(bench.supply))
        targets.append(chamber_target(bench.chamber, ctx.procedure.chamber.safe_temp_c))
        return targets

    # ------------------------------------------------------------ the guaranteed end

    def _safe_state(self, acquisition: Acquisition) -> SafeStateReport:
        """Table to rest, streams stopped, supply off, chamber to its safe setpoint: each
        read back from the instrument itself, retried until safe or the deadline passes."""
        ctx = self.ctx
        safe_temp_c = ctx.procedure.chamber.safe_temp_c
        targets = self._safe_targets(acquisition.close)
        try:
            report = SafeStatePass(targets, ctx.wait.clock, self.safe_state_policy).run()
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
                ctx.records.event(
                    f"safe state: {state.label} safe ({state.detail}; {state.attempts} "
                    "attempt(s))",
                    parts=list(ctx.parts),
                )
            else:
                ctx.records.event(
                    f"SAFE STATE FAILED: {state.label} is NOT safe: {state.detail}",
                    level="ERROR",
                    parts=list(ctx.parts),
                )
        return report

    def _finish(
        self, acquisition: Acquisition, started_s: float, run_error: tuple[Verdict, str] | None
    ) -> None:
        ctx = self.ctx
        ctx.progress.step, ctx.progress.condition = "cleanup", ""
        ctx.records.declared = None
        report = self._safe_state(acquisition)
        failure = ctx.parts.storage_failure()  # a record or raw.h5 the disk refused, unchecked
        if failure is not None and run_error is None:
            run_error = (Verdict.ERROR, os_error_text(failure))
        unsafe = report.failure_text()
        if unsafe:  # a bench left unsafe is an ERROR whatever else happened, and says so
            run_error = (Verdict.ERROR, f"{run_error[1]}; {unsafe}" if run_error else unsafe)
            for part in ctx.parts:
                if not part.alive:
                    part.verdict = Verdict.ERROR
                    part.reason = f"{part.reason}; {unsafe}" if part.reason else unsafe
        for part in ctx.parts:  # before any verdict: raw data that could not be kept is ERROR
            unkept = self._close_raw(part)
            if unkept and unkept not in (run_error or (None, ""))[1]:
                if part.alive and run_error is None:
                    part.alive = False
                    part.verdict, part.reason = Verdict.ERROR, unkept
                elif part.verdict not in (None, Verdict.ERROR, Verdict.ABORTED):
                    part.verdict = Verdict.ERROR
                    part.reason = f"{part.reason}; {unkept}" if part.reason else unkept
        for part in ctx.parts:
            # judged parts (alive, or taken out FAIL) get the run's lost-frame figure
            judged = part.alive or part.verdict is Verdict.FAIL
            if judged and part.stream is not None:
                lost, ok = part.stream.frames_lost, part.stream.frames_ok
                ctx.records.measure(
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
            elif part.verdict is Verdict.FAIL:
                self._judge_failed(part)
            rec = part.record
            rec.verdict = part.verdict or Verdict.ERROR
            rec.reason = part.reason
            rec.finished_utc = utc_now()
            rec.timings["total"] = round(ctx.wait.now_s() - started_s, 3)
            rec.analysis.safe_state = dict(self.safe_state_report)
            rec.analysis.safe_state_report = SafeStateResults.model_validate(report.as_record())
            if ctx.wait.abort_at_s is not None:  # when the stop was asked (signal, operator)
                rec.analysis.stop_requested_station_s = round(ctx.wait.abort_at_s, 3)
            if part.stream is not None:
                rec.analysis.stream = StreamResults(
                    frames_ok=part.stream.frames_ok,
                    frames_lost=part.stream.frames_lost,
                    frames_corrupted=part.stream.frames_corrupted,
                )
            rec.events.append(
                Event(
                    time_utc=utc_now(),
                    station_time_s=round(ctx.wait.now_s(), 3),
                    level="INFO" if rec.verdict in (Verdict.PASS, Verdict.FAIL) else "ERROR",
                    step="finish",
                    message=f"verdict {rec.verdict}" + (f": {rec.reason}" if rec.reason else ""),
                )
            )
            self._keep(part)
        ctx.progress.step = ""
        ctx.progress.publish(
            "finished", message=", ".join(f"{p.socket}:{p.verdict}" for p in ctx.parts)
        )

    @staticmethod
    def _close_raw(part: PartRun) -> str:
        """Flush and close the part's raw data; the one-line failure ('' if none)."""
        try:
            part.rows.flush()
            if part.writer is not None:
                part.writer.close()
        except OSError as exc:  # a StorageError naming raw.h5
            return os_error_text(exc)
        except Exception:
            log.exception("closing raw data of socket %d", part.socket)
        return ""

    @staticmethod
    def _keep(part: PartRun) -> None:
        """Write the record whatever the disk does: in the run folder, else in the fallback
        folder (procedures.runtime.record.save_record_anywhere, docs/safety.md); never raises."""
        part.kept = KeptRecord(save_record_anywhere(part.folder, part.record))

    def _judge(self, part: PartRun) -> None:
        ok, failed, marginal = overall(part.record.measurements)
        part.record.failed_measurements = failed
        if marginal:
            part.record.analysis.marginal_measurements = marginal
        not_measured = self._note_not_measured(part)
        if ok:
            part.verdict = Verdict.PASS
            part.reason = "all measurements within limits" + (
                f" ({len(marginal)} marginal: {', '.join(marginal)})" if marginal else ""
            ) + (f"; not measured: {', '.join(not_measured)}" if not_measured else "")
        else:
            part.verdict = Verdict.FAIL
            part.reason = f"out of limits: {', '.join(failed)}"

    def _judge_failed(self, part: PartRun) -> None:
        """A part taken out FAIL (a stop_part limit, or not programmed): the record lists
        what failed; the reason it was taken out stays."""
        _, failed, marginal = overall(part.record.measurements)
        part.record.failed_measurements = failed
        if marginal:
            part.record.analysis.marginal_measurements = marginal
        self._note_not_measured(part)

    @staticmethod
    def _note_not_measured(part: PartRun) -> list[str]:
        """Record the names of the declared measurements no step set; return them with their
        conditions (name@condition), as the verdict's reason names them."""
        missing = [m for m in part.record.measurements if m.outcome is Outcome.NOT_MEASURED]
        if missing:
            part.record.analysis.not_measured = [m.name for m in missing]
        return [f"{m.name}@{m.condition}" if m.condition else m.name for m in missing]
