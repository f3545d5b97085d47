"""The safe-state pass: every instrument commanded safe, then read back from the instrument
itself, retried with backoff (and a reconnect where the driver can) until it reports safe or a
deadline passes.

Safe means: the rate table at rest and disabled, the supply's output off, the chamber's
setpoint at the procedure's safe temperature. A first pass tries each instrument once in order
(table first, so nothing turns while the streams stop and the power goes off); instruments
not yet safe then retry in parallel, so a dead table link does not keep the supply on. The
result is a `SafeStateReport`: a failed instrument is a first-class outcome that the engine
puts in the verdict, the event log and the record (page one of the certificate shows it).

Backoff and deadline are wall time as well as station time: a Modbus reply timeout is wall
seconds whatever the bench's speed, and after an abort the station clock no longer sleeps.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field

from common.clock import Clock
from drivers.errors import WrongInstrument
from drivers.protocols import (
    Chamber,
    ChamberReadsBackSafe,
    PartLink,
    RateTable,
    ReadsBackSafe,
    Reconnectable,
    SafeReadback,
    StreamReadsBackSafe,
    Supply,
)

log = logging.getLogger(__name__)

LABELS = {
    "rate_table": "rate table",
    "streams": "part streams",
    "supply": "DC supply",
    "chamber": "thermal chamber",
}


@dataclass(frozen=True)
class SafeStatePolicy:
    """How hard the pass tries. `deadline_s` is station seconds; `wall_floor_s` is the least
    wall time it is given (a fast simulated clock must not cut a slow link short)."""

    deadline_s: float = 120.0
    wall_floor_s: float = 10.0
    first_backoff_wall_s: float = 0.05
    max_backoff_wall_s: float = 2.0
    # each reconnect multiplies the link's reply timeout (wall s) by this, up to the cap
    timeout_growth: float = 2.0
    max_timeout_wall_s: float = 8.0

    def deadline_wall_s(self, speed: float) -> float:
        return max(self.deadline_s / max(speed, 1e-9), self.wall_floor_s)


@dataclass
class InstrumentSafeState:
    """One instrument's outcome of the pass."""

    name: str
    safe: bool
    detail: str
    attempts: int = 0
    read_back: bool = True
    safe_at_station_s: float | None = None
    errors: list[str] = field(default_factory=list)

    @property
    def label(self) -> str:
        return LABELS.get(self.name, self.name)

    def legacy(self) -> str:
        """The record's short form: "safe" or "FAILED: why"."""
        return "safe" if self.safe else f"FAILED: {self.detail}"


@dataclass
class SafeStateReport:
    """The station's own account of the safe state (never the simulator's truth)."""

    instruments: dict[str, InstrumentSafeState] = field(default_factory=dict)
    started_station_s: float = 0.0
    finished_station_s: float = 0.0
    safe_temp_c: float | None = None

    @property
    def failed(self) -> list[InstrumentSafeState]:
        return [s for s in self.instruments.values() if not s.safe]

    @property
    def all_safe(self) -> bool:
        return not self.failed

    def failure_text(self) -> str:
        """One line naming every instrument that is not safe and why ('' when all are)."""
        if self.all_safe:
            return ""
        parts = [f"{s.label} NOT SAFE ({s.detail})" for s in self.failed]
        return (
            "SAFE STATE FAILED: "
            + "; ".join(parts)
            + ": make the bench safe by hand before anyone touches it"
        )

    def legacy(self) -> dict[str, str]:
        return {name: s.legacy() for name, s in self.instruments.items()}

    def as_record(self) -> dict[str, object]:
        return {
            "all_safe": self.all_safe,
            "started_station_s": round(self.started_station_s, 3),
            "finished_station_s": round(self.finished_station_s, 3),
            "safe_temp_c": self.safe_temp_c,
            "summary": self.failure_text() or "every instrument read back safe",
            "instruments": {name: asdict(s) for name, s in self.instruments.items()},
        }


@dataclass
class SafeTarget:
    """One instrument to make safe: how to command it, read it back and reconnect it."""

    name: str
    command: Callable[[], None]
    readback: Callable[[], SafeReadback] | None = None
    reconnect: Callable[[float | None], None] | None = None
    timeout_wall_s: float = 1.0
    retry: bool = True


def _link_timeout(driver: object) -> float:
    link = getattr(driver, "_link", None)
    return float(getattr(link, "timeout_s", 1.0) or 1.0)


def table_target(table: RateTable) -> SafeTarget:
    return SafeTarget(
        "rate_table",
        table.safe_state,
        table.check_safe if isinstance(table, ReadsBackSafe) else _table_readback(table),
        table.reconnect if isinstance(table, Reconnectable) else None,
        _link_timeout(table),
    )


def _table_readback(table: RateTable) -> Callable[[], SafeReadback] | None:
    if not callable(getattr(table, "read_status", None)):
        return None

    def readback() -> SafeReadback:
        s = table.read_status()
        safe = not s.enabled and not s.moving and abs(s.rate_dps) < 0.01
        return SafeReadback(safe, f"rate {s.rate_dps:.3f} deg/s, enabled {s.enabled}")

    return readback


def streams_target(
    links: Mapping[int, PartLink], before: Callable[[], None] | None = None
) -> SafeTarget:
    """Every socket's sample stream stopped: the station's own streams drained first
    (`before`), then STOP to every fixture whatever the station believes (a stream that a
    crashed station started is still started, and a fixture refuses any configuration while
    it streams), each read back from the fixture itself (`check_stream_stopped`)."""
    stop_failed: dict[int, str] = {}

    def command() -> None:
        stop_failed.clear()
        if before is not None:
            before()
        for sock, link in sorted(links.items()):
            try:
                link.stop_stream()
            except Exception as exc:  # the others are still stopped; read back says which
                stop_failed[sock] = f"STOP failed: {type(exc).__name__}: {exc}"

    def readback() -> SafeReadback:
        details: dict[str, list[int]] = {}
        safe = True
        for sock, link in sorted(links.items()):
            if sock in stop_failed:
                one = SafeReadback(False, stop_failed[sock])
            elif isinstance(link, StreamReadsBackSafe):
                try:
                    one = link.check_stream_stopped()
                except Exception as exc:  # a fixture that cannot say is not safe
                    one = SafeReadback(False, f"{type(exc).__name__}: {exc}")
            else:
                one = SafeReadback(True, "STOP sent (this driver cannot read its stream back)")
            safe = safe and one.safe
            details.setdefault(one.detail, []).append(sock)
        text = "; ".join(
            f"socket{'s' if len(socks) > 1 else ''} {', '.join(map(str, socks))}: {detail}"
            for detail, socks in details.items()
        )
        return SafeReadback(safe, text or "no fixture socket in this run")

    # a fixture that does not answer is not retried: each try costs its reply timeout
    return SafeTarget("streams", command, readback, retry=False)


def supply_target(supply: Supply) -> SafeTarget:
    readback: Callable[[], SafeReadback] | None = None
    if isinstance(supply, ReadsBackSafe):
        readback = supply.check_safe
    elif callable(getattr(supply, "output_is_on", None)):

        def readback() -> SafeReadback:
            on = supply.output_is_on()
            return SafeReadback(not on, "output ON" if on else "output off")

    return SafeTarget(
        "supply",
        supply.safe_state,
        readback,
        supply.reconnect if isinstance(supply, Reconnectable) else None,
        _link_timeout(supply),
    )


def chamber_target(chamber: Chamber, safe_temp_c: float) -> SafeTarget:
    readback: Callable[[], SafeReadback] | None = None
    if isinstance(chamber, ChamberReadsBackSafe):

        def readback() -> SafeReadback:
            return chamber.check_safe(safe_temp_c)

    elif callable(getattr(chamber, "read_setpoint", None)):

        def readback() -> SafeReadback:
            sp = chamber.read_setpoint()
            return SafeReadback(abs(sp - safe_temp_c) <= 0.05, f"setpoint {sp:g} C")

    return SafeTarget(
        "chamber",
        lambda: chamber.safe_state(safe_temp_c),
        readback,
        chamber.reconnect if isinstance(chamber, Reconnectable) else None,
        _link_timeout(chamber),
    )


class SafeStatePass:
    """Runs the pass over `targets` (in order) on the station `clock`."""

    def __init__(
        self, targets: list[SafeTarget], clock: Clock, policy: SafeStatePolicy | None = None
    ) -> None:
        self.targets = targets
        self.clock = clock
        self.policy = policy or SafeStatePolicy()
        self._wake = threading.Event()  # never set: a wall sleep the abort cannot cut short

    def run(self) -> SafeStateReport:
        report = SafeStateReport(started_station_s=self.clock.now_s())
        deadline = time.monotonic() + self.policy.deadline_wall_s(self.clock.speed)
        pending: list[tuple[SafeTarget, InstrumentSafeState]] = []
        for target in self.targets:  # one attempt each, in order
            state = InstrumentSafeState(
                target.name, False, "not tried", read_back=target.readback is not None
            )
            report.instruments[target.name] = state
            self._attempt(target, state)
            if not state.safe and target.retry:
                pending.append((target, state))
        threads = [
            threading.Thread(
                target=self._retry, args=(target, state, deadline), name=f"safe-{target.name}",
                daemon=True,
            )
            for target, state in pending
        ]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(max(deadline - time.monotonic(), 0.0) + 2 * self.policy.max_timeout_wall_s)
        report.finished_station_s = self.clock.now_s()
        return report

    def _attempt(self, target: SafeTarget, state: InstrumentSafeState) -> None:
        state.attempts += 1
        try:
            target.command()
            readback = (
                target.readback()
                if target.readback is not None
                else SafeReadback(True, "commanded (this driver cannot read its state back)")
            )
        except Exception as exc:  # any failure is retried until the deadline
            readback = SafeReadback(False, f"{type(exc).__name__}: {exc}")
            if len(state.errors) < 5:
                state.errors.append(readback.detail)
        state.safe, state.detail = readback.safe, readback.detail
        if readback.safe:
            state.safe_at_station_s = round(self.clock.now_s(), 3)

    def _retry(self, target: SafeTarget, state: InstrumentSafeState, deadline: float) -> None:
        backoff = self.policy.first_backoff_wall_s
        timeout = target.timeout_wall_s
        while not state.safe:
            if time.monotonic() + backoff >= deadline:
                state.detail += f" (after {state.attempts} attempts)"
                log.error("safe state: %s is not safe: %s", state.label, state.detail)
                return
            self._wake.wait(backoff)
            backoff = min(2 * backoff, self.policy.max_backoff_wall_s)
            if target.reconnect is not None:
                timeout = min(timeout * self.policy.timeout_growth, self.policy.max_timeout_wall_s)
                timeout = min(timeout, max(deadline - time.monotonic(), 0.1))
                try:
                    target.reconnect(timeout)
                except WrongInstrument as exc:  # another device there now: never poke it
                    state.safe, state.detail = False, f"{type(exc).__name__}: {exc}"
                    log.error("safe state: %s is not safe: %s", state.label, state.detail)
                    return
                except Exception as exc:  # still unreachable: back off and try again
                    state.attempts += 1
                    state.safe, state.detail = False, f"{type(exc).__name__}: {exc}"
                    continue
            self._attempt(target, state)
        log.info("safe state: %s safe after %d attempts", state.label, state.attempts)


# ---------------------------------------------------------------- safe settings


class SafeSettingsError(ValueError):
    """The procedure's safe settings are unsafe for this product or chamber (one line)."""


def check_safe_temperature(
    safe_temp_c: float,
    handling_range_c: tuple[float, float],
    chamber_limits_c: tuple[float, float] | None = None,
) -> None:
    """Refuse a chamber safe temperature outside the product's handling range or the
    chamber's setpoint limits (checked before a run starts)."""
    low, high = handling_range_c
    if not low <= safe_temp_c <= high:  # also refuses NaN
        raise SafeSettingsError(
            f"chamber.safe_temp_c {safe_temp_c:g} C is outside the product's handling range "
            f"[{low:g}, {high:g}] C: set a temperature people can touch in the procedure"
        )
    if chamber_limits_c is not None:
        c_low, c_high = chamber_limits_c
        if not c_low <= safe_temp_c <= c_high:
            raise SafeSettingsError(
                f"chamber.safe_temp_c {safe_temp_c:g} C is outside the chamber's setpoint "
                f"limits [{c_low:g}, {c_high:g}] C: change the procedure's safe temperature"
            )
