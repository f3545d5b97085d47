"""What a step sees while it runs, split by concern.

    ctx.parts        the run's parts (a list of PartRun) with alive(), each(), drop()
    ctx.wait         the station clock, sleep(), check(), abort()
    ctx.instruments  the shared instruments (table, chamber, supply) and their logged reads
    ctx.records      measurements, events, segments and raw-data rows; saving the records
    ctx.progress     the current step and condition, progress events, operator prompts
    ctx.procedure    the procedure's run-wide settings (conditions, chamber, stream, ...)
    ctx.product      the product file (limits, range, nominal values)

A step's own settings are not here: the step holds them as its typed `self.settings`.
"""

from __future__ import annotations

import datetime as dt
import logging
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from common.clock import ScaledClock
from drivers.errors import InstrumentError, PartAbsent, PartSilent, StreamCorrupted
from drivers.protocols import Chamber, RateTable, Supply, TableStatus
from procedures.runtime.limits import judge
from procedures.runtime.progress import ProgressBus, ProgressEvent
from procedures.runtime.record import Event, Measurement, Outcome, Verdict, write_record
from procedures.runtime.run_parts import Bench, PartRun
from procedures.runtime.watchdog import Watchdog

if TYPE_CHECKING:
    from procedures.loading.config import ProcedureConfig, ProductConfig
    from procedures.runtime.streams import PartStream

log = logging.getLogger(__name__)
T = TypeVar("T")
SUPPLY_SETTLE_S = 0.2  # station seconds after a change of supply setting before reading it


class Aborted(Exception):  # noqa: N818 - reads as the event it is
    """The run was asked to stop: by the operator or a signal (ABORTED), or because the
    station itself failed (`error`: an uncaught exception in one of its threads, ERROR)."""

    def __init__(self, reason: str = "the operator aborted the run", error: bool = False) -> None:
        super().__init__(reason)
        self.error = error


class StepTimeout(Exception):  # noqa: N818
    """A step ran longer than its policy allows."""


class NoPartsLeft(Exception):  # noqa: N818
    """Every part has dropped out; nothing left to measure."""


class UndeclaredMeasurement(Exception):  # noqa: N818
    """A step recorded a measurement it does not declare (a bug in the step)."""


def utc_now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")


# ---------------------------------------------------------------- progress


class Progress:
    """The current step and condition, the planned time, and the events the screens show."""

    def __init__(self, bus: ProgressBus, clock: ScaledClock, parts: list[PartRun]) -> None:
        self.bus = bus
        self._clock = clock
        self._parts = parts
        self.step = ""  # the running step's type name (ProgressEvent.step)
        self.condition = ""  # the running step's condition name, "" outside a loop
        self.phase = ""  # the running step's phase (set_phase), "" when it names none
        self.step_started_s = 0.0
        self.step_estimate_s = 0.0
        self.done_estimate_s = 0.0
        self.total_estimate_s = 1.0
        self._last_wall = 0.0
        self._shown = 0.0  # the largest fraction published: the bar never goes back

    def subscribe(self, fn: Callable[[ProgressEvent], None]) -> Callable[[], None]:
        return self.bus.subscribe(fn)

    def begin(self, step: str, condition: str, estimate_s: float) -> None:
        self.step, self.condition, self.phase = step, condition, ""
        self.step_started_s = self._clock.now_s()
        self.step_estimate_s = estimate_s
        self.publish("step", message=step + (f" at {condition}" if condition else ""))

    def set_phase(self, phase: str) -> None:
        """The running step's phase (ProgressEvent.phase): a "step" event when it changes,
        so a line that prints one line per step shows a long step's phases too."""
        if phase != self.phase:
            self.phase = phase
            self.publish("step", message=f"{self.step}: {phase}" if phase else self.step)

    def revise(self, left_s: float) -> None:
        """The running step's own estimate of the station seconds it has left (a step that
        learns its length as it runs, as the ramp does from its heating half): the step's
        planned time and the whole's move by the difference."""
        new = max(self._clock.now_s() - self.step_started_s, 0.0) + max(left_s, 0.0)
        self.total_estimate_s = max(self.total_estimate_s + new - self.step_estimate_s, 1.0)
        self.step_estimate_s = new

    def end(self) -> None:
        self.done_estimate_s += self.step_estimate_s

    def fraction(self) -> tuple[float, float]:
        """(fraction of the planned station time done, station seconds left); the fraction
        never goes back when an estimate is revised upwards."""
        in_step = min(self._clock.now_s() - self.step_started_s, self.step_estimate_s)
        done = self.done_estimate_s + max(in_step, 0.0)
        self._shown = max(self._shown, min(done / self.total_estimate_s, 1.0))
        return self._shown, max(self.total_estimate_s - done, 0.0)

    def maybe_publish(self) -> None:
        """A "progress" event at most every 0.2 wall s."""
        now = time.monotonic()
        if now - self._last_wall >= 0.2:
            self._last_wall = now
            self.publish("progress")

    def socket_states(self) -> dict[int, str]:
        return {p.socket: ("RUNNING" if p.alive else str(p.verdict)) for p in self._parts}

    def publish(self, kind: str, message: str = "", sockets: dict[int, str] | None = None,
                orientation: str | None = None) -> None:
        fraction, remaining = self.fraction()
        self.bus.publish(
            ProgressEvent(
                kind=kind,
                step=self.step,
                condition=self.condition,
                phase=self.phase,
                fraction=fraction,
                station_time_s=self._clock.now_s(),
                remaining_s=remaining,
                message=message,
                sockets=self.socket_states() if sockets is None else sockets,
                orientation=orientation,
            )
        )

    def prompt(self, message: str, sockets: Iterable[int], orientation: str | None = None) -> None:
        """Ask the operator to do something (kind="prompt"); `sockets` are those concerned;
        `orientation`: the cube face a reorientation prompt asks for ("+x" .. "-z")."""
        self.publish("prompt", message=message, sockets={s: "PROMPT" for s in sockets},
                     orientation=orientation)

    def prompt_done(self, sockets: Iterable[int] = ()) -> None:
        """Clear the prompt (kind="prompt_done")."""
        self.publish("prompt_done", sockets={s: "RUNNING" for s in sockets})


# ---------------------------------------------------------------- records and events


class Records:
    """Measurements judged against the product limits, events, segments, raw-data rows."""

    def __init__(self, product: ProductConfig, parts: list[PartRun], progress: Progress,
                 clock: ScaledClock) -> None:
        self.product = product
        self._parts = parts
        self._progress = progress
        self._clock = clock
        # names the running step may set (None: no check), and what each part set in it
        self.declared: set[str] | None = None
        self.made: dict[int, set[str]] = {}
        # the first record or raw data file that could not be written (disk full, read-only)
        self.failure: OSError | None = None
        # set by Parts: called with (part, reason) when a stop_part limit fails
        self.on_stop_part: Callable[[PartRun, str], None] | None = None
        # the sockets the running step measures (None: every part; Parts.only)
        self.focus: frozenset[int] | None = None

    def alive(self) -> list[PartRun]:
        return [p for p in self._parts if p.alive and self.focused(p)]

    def focused(self, part: PartRun) -> bool:
        """Is the part among those the running step measures (`Parts.only`)?"""
        return self.focus is None or part.socket in self.focus

    def append_all(
        self, group: str, parts: list[PartRun] | None = None, **columns: ArrayLike
    ) -> None:
        """One row in raw.h5's `group` of every (alive) part."""
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
        condition: str | None = None,
    ) -> None:
        """A window of the part's data (fixture time) with its reference, for raw.h5;
        `condition`: its label when not the condition in progress."""
        part.rows.append(
            "segments",
            condition=self._progress.condition if condition is None else condition,
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
        """An event in the record of every (alive, or given) part and on the progress bus."""
        t = self._clock.now_s()
        log.log(logging.WARNING if level != "INFO" else logging.INFO, "%s", message)
        for part in parts if parts is not None else self.alive():
            part.record.events.append(
                Event(
                    time_utc=utc_now(),
                    station_time_s=round(t, 3),
                    level=level,
                    step=self._progress.step,
                    message=message,
                )
            )
            part.rows.append("events", station_time_s=t, text=message)
        self._progress.publish("log", message=message)

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
        """Record a measurement judged against the product limits, where it is made.

        The name must be one the running step declares. A FAIL against a limit with
        `on_fail: stop_part` takes the part out of the remaining steps (verdict FAIL)."""
        if self.declared is not None and name not in self.declared:
            raise UndeclaredMeasurement(
                f"step {self._progress.step} recorded {name!r}, which it does not declare "
                f"(it declares: {', '.join(sorted(self.declared)) or 'nothing'})"
            )
        key = limit_name or name
        m = judge(
            name,
            value,
            self.product.limits,
            units=units,
            limit_name=limit_name,
            uncertainty_k2=uncertainty_k2,
            condition=condition,
            description=description,
            decision_rule=self.product.decision_rule,
        )
        part.record.measurements.append(m)
        self.made.setdefault(part.socket, set()).add(name)
        if m.outcome is Outcome.FAIL:
            label = f"{name}@{condition}" if condition else name
            part.failed_limits.append(label)
            limit = getattr(self.product.limits, key, None)
            if limit is not None and limit.on_fail == "stop_part" and self.on_stop_part:
                self.on_stop_part(part, f"failed {label} (on_fail: stop_part)")
        return m

    def not_measured(self, part: PartRun, name: str, units: str, condition: str | None) -> None:
        """A declared measurement the step never set: NOT_MEASURED on the record."""
        part.record.measurements.append(
            judge(name, None, self.product.limits, units=units, condition=condition,
                  description="declared by the procedure but not measured")
        )

    def save(self, part: PartRun) -> None:
        part.rows.flush()
        write_record(part.folder, part.record)

    def save_all(self) -> None:
        """Every part's record; one that cannot be written is kept in `failure`, which the
        run's next check raises (the run ends ERROR naming the file)."""
        for part in self._parts:
            try:
                self.save(part)
            except OSError as exc:
                log.error("could not write the record of socket %d: %s", part.socket, exc)
                self.failure = self.failure or exc


# ---------------------------------------------------------------- parts


class Parts(list[PartRun]):
    """Every part of the run in socket order (a list), with the helpers that work on them."""

    def __init__(self, parts: Iterable[PartRun], records: Records, progress: Progress) -> None:
        super().__init__(parts)
        self._records = records
        self._progress = progress
        records.on_stop_part = lambda part, reason: self.drop(part, Verdict.FAIL, reason)

    def alive(self) -> list[PartRun]:
        """The parts still running (those the running step measures, `only`)."""
        return [p for p in self if p.alive and self._records.focused(p)]

    @contextmanager
    def only(self, sockets: frozenset[int] | None) -> Iterator[None]:
        """Within: `alive()` (and the events of `Records`) hold only these sockets' parts
        (None: every part), for a step run again for some parts only."""
        before, self._records.focus = self._records.focus, sockets
        try:
            yield
        finally:
            self._records.focus = before

    def drop(self, part: PartRun, verdict: Verdict, reason: str) -> None:
        """Take one part out of the run (the others go on)."""
        if not part.alive:
            return
        part.alive = False
        part.verdict = verdict
        part.reason = reason
        self._records.event(
            f"socket {part.socket} ({part.serial}) dropped: {verdict}: {reason}",
            level="ERROR" if verdict is not Verdict.FAIL else "WARNING",
            parts=[part],
        )
        if part.stream is not None:
            try:
                part.stream.stop()
            except Exception as exc:  # the link is probably what failed
                log.info("socket %d: stop after drop failed: %s", part.socket, exc)
        self._records.save(part)
        self._progress.publish("part", message=f"socket {part.socket}: {verdict}")

    def per_part(self, part: PartRun, fn: Callable[[PartRun], T]) -> T | None:
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

    def each(self, fn: Callable[[PartRun], object]) -> None:
        """`fn(part)` for every alive part (per_part), then NoPartsLeft if none is left."""
        for part in self.alive():
            self.per_part(part, fn)
        self.require()

    def storage_failure(self) -> OSError | None:
        """The first file of the run that could not be written, if any."""
        for part in self:
            if part.writer is not None and part.writer.failure is not None:
                return part.writer.failure
        return self._records.failure

    def require(self) -> None:
        if not any(p.alive for p in self):  # any part: those `only` leaves out go on
            raise NoPartsLeft("every part has dropped out of the run")


# ---------------------------------------------------------------- waiting and abort


class Waiting:
    """The station clock and every wait of a step: abort, step timeout, stream health."""

    def __init__(self, clock: ScaledClock, parts: Parts, procedure: ProcedureConfig,
                 progress: Progress, watchdog: Watchdog) -> None:
        self.clock = clock
        self._parts = parts
        self._procedure = procedure
        self._progress = progress
        self.watchdog = watchdog
        self._abort = threading.Event()
        self.abort_reason = ""
        self.abort_error = False
        self.abort_at_s: float | None = None  # station time of the first abort request
        self.deadline_s: float | None = None
        self.timeout_s = 0.0  # of the running step, for the message
        self.on_silent: Callable[[], object] | None = None  # reads the supply (current limit)

    def now_s(self) -> float:
        return self.clock.now_s()

    def abort(self, reason: str = "the operator aborted the run", error: bool = False) -> None:
        """Ask the run to stop now (thread-safe; station/exit_path.py and the UI call this).
        The first reason stands: a later abort (the UI closing after a SIGTERM) must not
        rename why the run stopped."""
        if not self._abort.is_set():
            self.abort_reason, self.abort_error = reason, error
            self.abort_at_s = self.clock.now_s()
        self._abort.set()
        self.clock.interrupt()

    @property
    def aborted(self) -> bool:
        return self._abort.is_set()

    def check(self) -> None:
        """Raise Aborted / StepTimeout when due; drop parts whose stream failed."""
        if self._abort.is_set():
            raise Aborted(self.abort_reason or "the operator aborted the run", self.abort_error)
        self.watchdog.poll()
        limit = self._procedure.stream.max_lost_fraction
        for part in self._parts.alive():
            part.rows.flush_if_due()
        if (failure := self._parts.storage_failure()) is not None:
            raise failure  # a disk that refused ends the run (Engine: ERROR naming the file)
        for part in self._parts.alive():
            stream = part.stream
            if stream is None:
                continue
            if stream.error is not None:
                # a silent part is often a shorted one: a current-limiting supply is the
                # real reason, and it concerns every part on that supply
                if self.on_silent is not None:
                    self.on_silent()
                self._parts.drop(part, Verdict.ERROR, str(stream.error))
                continue
            lost, total = stream.frames_lost, stream.frames_lost + stream.frames_ok
            if lost > 10 and lost > limit * total:
                self._parts.drop(
                    part, Verdict.ERROR, _stream_loss_reason(part.socket, stream, limit)
                )
        self._parts.require()
        if self.deadline_s is not None and self.clock.now_s() > self.deadline_s:
            raise StepTimeout(
                f"step {self._progress.step} took longer than its timeout "
                f"({self.timeout_s:g} s); raise timeout_s of this step in the procedure file "
                "if this is expected"
            )
        self._progress.maybe_publish()

    def sleep(self, duration_s: float, slice_s: float = 1.0) -> None:
        """Wait `duration_s` station seconds, checking abort/timeout/streams in between."""
        end = self.clock.now_s() + duration_s
        while True:
            self.check()
            left = end - self.clock.now_s()
            if left <= 0:
                return
            self.clock.sleep_s(min(left, max(slice_s, self.clock.check_every_s)))


# ---------------------------------------------------------------- instruments


class Instruments:
    """The shared instruments and their reads, each logged to every part's raw data."""

    def __init__(self, bench: Bench, records: Records, wait: Waiting) -> None:
        self.bench = bench
        self._records = records
        self._wait = wait

    @property
    def table(self) -> RateTable | None:
        """The rate table, or None on a bench without one."""
        return self.bench.table

    def need_table(self) -> RateTable:
        """The rate table, for a step that moves the part with it (InstrumentError if the
        station has none: the preflight should have said so before the run)."""
        if self.bench.table is None:
            raise InstrumentError(
                f"step {self._records._progress.step} needs a rate table and this station "
                "has none (station.yaml instruments.rate_table); use a procedure without "
                "table steps",
                instrument="rate_table",
            )
        return self.bench.table

    @property
    def chamber(self) -> Chamber:
        return self.bench.chamber

    @property
    def supply(self) -> Supply:
        return self.bench.supply

    def snapshot(self) -> tuple[float, TableStatus]:
        """Table status with the station time at the middle of the read; logged to raw data."""
        table = self.bench.table
        assert table is not None
        clock = self._wait.clock
        t0 = clock.now_s()
        status = table.read_status()
        t = 0.5 * (t0 + clock.now_s())
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
        self._records.append_all(
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
        t = self._wait.clock.now_s()
        chamber_c = self.bench.chamber.read_temperature()
        setpoint = self.bench.chamber.read_setpoint()
        self._records.append_all("chamber", station_time_s=t, setpoint_c=setpoint, temp_c=chamber_c)
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
        self._wait.sleep(SUPPLY_SETTLE_S)  # a real supply slews: read it once it has settled
        self.log_supply()

    def log_supply(self) -> tuple[float, float]:
        """Read the supply once and log it to every part's raw data."""
        t = self._wait.clock.now_s()
        volts, amps = self.supply_reading()
        self._records.append_all("supply", station_time_s=t, voltage_v=volts, current_a=amps)
        return volts, amps

    def supply_reading(self) -> tuple[float, float]:
        """(volts, amps); raises SupplyCurrentLimit when the supply is current-limiting."""
        supply = self.bench.supply
        check = getattr(supply, "check_current_limit", None)
        if check is not None:
            volts, amps = check()
            return float(volts), float(amps)
        return supply.measure_voltage(), supply.measure_current()


# ---------------------------------------------------------------- the context


class RunContext:
    """What a step sees (see the module docstring)."""

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
        for part in parts:  # the product says how its parts' codes read
            if part.stream is not None:
                part.stream.codes = product.codes
        self.clock = bench.clock
        self.progress = Progress(progress or ProgressBus(), bench.clock, parts)
        self.records = Records(product, parts, self.progress, bench.clock)
        self.parts = Parts(parts, self.records, self.progress)
        # the records and progress see the same list object as ctx.parts
        self.records._parts = self.parts
        self.progress._parts = self.parts
        watchdog = Watchdog({"rate_table": bench.table, "chamber": bench.chamber}, bench.clock)
        self.wait = Waiting(bench.clock, self.parts, procedure, self.progress, watchdog)
        self.instruments = Instruments(bench, self.records, self.wait)
        self.wait.on_silent = self.instruments.supply_reading

    # the few names the station layer (station/uut.py, the UI) calls on a live run
    def abort(self, reason: str = "the operator aborted the run", error: bool = False) -> None:
        """Ask the run to stop now (thread-safe); `error`: it ends ERROR, not ABORTED."""
        self.wait.abort(reason, error)

    @property
    def aborted(self) -> bool:
        return self.wait.aborted


def _stream_loss_reason(socket: int, stream: PartStream, limit: float) -> str:
    """Why a part's stream is no longer trusted: corrupted (frames with a bad CRC) or losing
    frames (none corrupted: dropped on the way)."""
    lost, total = stream.frames_lost, stream.frames_lost + stream.frames_ok
    bad_crc = stream.frames_corrupted
    what = "stream corrupted" if bad_crc else "stream losing frames"
    return (
        f"socket {socket}: {what}: {lost} of {total} frames lost ({bad_crc} with a bad CRC), "
        f"more than the {limit:g} allowed: check the fixture cable and its grounding"
    )
