"""The safe-state pass (retries, reconnect, deadline, readback), the watchdog through waits,
per-window frame loss and the safe-temperature check, with in-process fakes."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.clock import ScaledClock
from drivers.errors import ChamberFault, ConnectionLost, TableFault, WrongInstrument
from drivers.protocols import SafeReadback, TableStatus
from procedures.engine.engine import Engine
from procedures.engine.safe_state import (
    SafeSettingsError,
    SafeStatePass,
    SafeStatePolicy,
    chamber_target,
    check_safe_temperature,
    supply_target,
    table_target,
)
from procedures.loading.config import load_procedure, load_product
from procedures.runtime.record import Dut, FileRef, RunRecord, Verdict, read_record
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import Bench, PartRun
from procedures.steps.base import frames_lost_in
from procedures.steps.registry import StepPolicy
from tests.procedures.fake_step import DeclaresNothing

ROOT = Path(__file__).resolve().parents[2]
FAST = SafeStatePolicy(deadline_s=0.0, wall_floor_s=0.5, first_backoff_wall_s=0.01)


class FakeTable:
    """Reads back safe after `safe_after` commands; `dead` raises ConnectionLost until a
    reconnect with a timeout of at least `needs_timeout_s`."""

    def __init__(self, safe_after: int = 1, dead: bool = False, needs_timeout_s: float = 0.0):
        self.commands = 0
        self.safe_after = safe_after
        self.dead = dead
        self.needs_timeout_s = needs_timeout_s
        self.reconnects: list[float | None] = []
        self.fault = False

    def _alive(self) -> None:
        if self.dead:
            raise ConnectionLost("cannot connect to the rate table", instrument="rate table")

    def safe_state(self) -> None:
        self._alive()
        self.commands += 1

    def check_safe(self) -> SafeReadback:
        self._alive()
        safe = self.commands >= self.safe_after
        return SafeReadback(safe, "at rest, disabled" if safe else "rate -50.000 deg/s, enabled")

    def reconnect(self, timeout_s: float | None = None) -> None:
        self.reconnects.append(timeout_s)
        if timeout_s is not None and self.needs_timeout_s and timeout_s >= self.needs_timeout_s:
            self.dead = False

    def watchdog_check(self) -> None:
        if self.fault:
            raise TableFault("rate table fault 4: emergency stop pressed", fault_code=4)

    def read_status(self) -> TableStatus:  # not used when watchdog_check exists
        raise AssertionError


class FakeSupply:
    def __init__(self) -> None:
        self.on = True
        self.off_at: float | None = None

    def safe_state(self) -> None:
        self.on = False
        self.off_at = time.monotonic()

    def check_safe(self) -> SafeReadback:
        return SafeReadback(not self.on, "output off" if not self.on else "output ON")


class FakeChamber:
    def __init__(self) -> None:
        self.setpoint_c = 45.0
        self.fault = False

    def safe_state(self, safe_temp_c: float = 25.0) -> None:
        self.setpoint_c = safe_temp_c

    def check_safe(self, safe_temp_c: float) -> SafeReadback:
        return SafeReadback(self.setpoint_c == safe_temp_c, f"setpoint {self.setpoint_c:g} C")

    def watchdog_check(self) -> None:
        if self.fault:
            raise ChamberFault("the chamber reports a fault at 41 C", instrument="chamber")


def test_retries_until_the_instrument_reads_back_safe() -> None:
    table = FakeTable(safe_after=3)
    report = SafeStatePass([table_target(table)], ScaledClock(100.0), FAST).run()
    state = report.instruments["rate_table"]
    assert state.safe and state.attempts == 3 and table.commands == 3
    assert state.safe_at_station_s is not None and report.all_safe


def test_reconnects_with_growing_timeouts_until_the_link_answers() -> None:
    table = FakeTable(dead=True, needs_timeout_s=3.0)
    policy = SafeStatePolicy(deadline_s=0.0, wall_floor_s=10.0, first_backoff_wall_s=0.01)
    report = SafeStatePass([table_target(table)], ScaledClock(100.0), policy).run()
    assert report.instruments["rate_table"].safe
    timeouts = [t for t in table.reconnects if t is not None]
    assert timeouts == sorted(timeouts) and timeouts[-1] >= 3.0


def test_a_reconnect_that_finds_another_device_is_not_retried() -> None:
    """The address leads elsewhere now (WrongInstrument): every retry would poke that other
    device, so the pass reports the instrument unsafe at once and asks no more of it."""

    class Elsewhere(FakeTable):
        def reconnect(self, timeout_s: float | None = None) -> None:
            self.reconnects.append(timeout_s)
            raise WrongInstrument("the rate table's address now answers as another device",
                                  instrument="rate table")

    table = Elsewhere(dead=True)
    policy = SafeStatePolicy(deadline_s=0.0, wall_floor_s=5.0, first_backoff_wall_s=0.01)
    t0 = time.monotonic()
    report = SafeStatePass([table_target(table)], ScaledClock(100.0), policy).run()
    state = report.instruments["rate_table"]
    assert not state.safe and "another device" in state.detail
    assert len(table.reconnects) == 1 and time.monotonic() - t0 < 2.0


def test_a_dead_instrument_fails_by_the_deadline_and_does_not_hold_up_the_others() -> None:
    table, supply, chamber = FakeTable(dead=True), FakeSupply(), FakeChamber()
    targets = [table_target(table), supply_target(supply), chamber_target(chamber, 25.0)]
    t0 = time.monotonic()
    report = SafeStatePass(targets, ScaledClock(100.0), FAST).run()
    assert 0.2 < time.monotonic() - t0 < 3.0
    assert supply.off_at is not None and supply.off_at - t0 < 0.2
    assert not report.all_safe and [s.name for s in report.failed] == ["rate_table"]
    assert report.instruments["rate_table"].attempts > 2
    text = report.failure_text()
    assert text.startswith("SAFE STATE FAILED") and "rate table NOT SAFE" in text
    assert "cannot connect" in text and "supply" not in text


def test_safe_temperature_is_checked_against_the_product_and_the_chamber() -> None:
    check_safe_temperature(25.0, (10.0, 40.0), (-40.0, 125.0))
    with pytest.raises(SafeSettingsError, match="handling range"):
        check_safe_temperature(300.0, (10.0, 40.0))
    with pytest.raises(SafeSettingsError, match="handling range"):
        check_safe_temperature(float("nan"), (10.0, 40.0))
    with pytest.raises(SafeSettingsError, match="setpoint limits"):
        check_safe_temperature(25.0, (10.0, 40.0), (30.0, 125.0))


def test_frames_lost_in_a_window_counts_sequence_gaps_across_the_wrap() -> None:
    seq = np.array([65530, 65531, 65533, 65535, 0, 1, 5])
    assert frames_lost_in({"seq": seq}) == 1 + 1 + 3
    assert frames_lost_in({"seq": np.arange(10)}) == 0


# ---------------------------------------------------------------- through the engine


def _ctx(tmp_path: Path, table: FakeTable, chamber: FakeChamber) -> RunContext:
    proc, _ = load_procedure(ROOT / "config/procedures/eol-rate-table.yaml")
    prod, _ = load_product(ROOT / "config/products/gyr130.yaml")
    bench = Bench(
        chamber=chamber,  # type: ignore[arg-type]
        supply=FakeSupply(),  # type: ignore[arg-type]
        links={},
        clock=ScaledClock(50.0),  # the watchdog's wall floor (20 ms) is 1 station s here
        table=table,  # type: ignore[arg-type]
    )
    ref = FileRef(path="x", sha256="0" * 64)
    rec = RunRecord(
        run_id="r1", verdict=Verdict.RUNNING, started_utc="t",
        dut=Dut(serial="SIM-0001", socket=1), product=ref, procedure=ref,
    )
    part = PartRun(socket=1, serial="SIM-0001", folder=tmp_path / "p1", record=rec)
    return RunContext(bench, proc, prod, [part])


class Dwell(DeclaresNothing):
    name, condition, policy = "dwell", "", StepPolicy()

    def __init__(self, sleep_s: float, hook: Any = None) -> None:
        self.sleep_s, self.hook = sleep_s, hook

    def estimate_s(self, ctx: RunContext) -> float:
        return self.sleep_s

    def setup(self, ctx: RunContext) -> None:
        return None

    def cleanup(self, ctx: RunContext) -> None:
        return None

    def main(self, ctx: RunContext) -> None:
        if self.hook:
            self.hook()
        ctx.wait.sleep(self.sleep_s)


def test_estop_at_rest_ends_a_long_dwell_within_two_station_seconds(tmp_path: Path) -> None:
    table, chamber = FakeTable(), FakeChamber()
    ctx = _ctx(tmp_path, table, chamber)
    trip_at: list[float] = []

    def trip() -> None:
        trip_at.append(ctx.wait.clock.now_s())
        table.fault = True

    engine = Engine(ctx, [Dwell(600.0, trip)])  # type: ignore[list-item]
    assert engine.run() == {1: Verdict.ERROR}
    rec = read_record(tmp_path / "p1")
    assert "emergency stop" in rec.reason
    assert rec.timings["dwell"] <= 2.5  # station seconds, not the 600 s dwell


def test_chamber_fault_ends_the_wait_at_once(tmp_path: Path) -> None:
    table, chamber = FakeTable(), FakeChamber()
    ctx = _ctx(tmp_path, table, chamber)
    engine = Engine(ctx, [Dwell(1800.0, lambda: setattr(chamber, "fault", True))])  # type: ignore[list-item]
    assert engine.run() == {1: Verdict.ERROR}
    rec = read_record(tmp_path / "p1")
    assert "chamber reports a fault" in rec.reason and rec.timings["dwell"] <= 2.5


def test_a_failed_safe_state_is_an_error_in_the_reason_record_and_events(tmp_path: Path) -> None:
    table, chamber = FakeTable(dead=True), FakeChamber()
    ctx = _ctx(tmp_path, table, chamber)
    table.dead = False  # alive through the run, lost at the end
    engine = Engine(ctx, [Dwell(1.0, None)])  # type: ignore[list-item]
    engine.safe_state_policy = FAST
    orig = table.safe_state

    def dies() -> None:
        table.dead = True
        orig()

    table.safe_state = dies  # type: ignore[method-assign]
    assert engine.run() == {1: Verdict.ERROR}
    rec = read_record(tmp_path / "p1")
    assert "SAFE STATE FAILED" in rec.reason and "rate table NOT SAFE" in rec.reason
    report = rec.analysis.safe_state_report
    assert report is not None and report.all_safe is False
    assert report.instruments["rate_table"].safe is False
    assert report.instruments["chamber"].safe is True
    assert rec.analysis.safe_state is not None and rec.analysis.safe_state["supply"] == "safe"
    assert any(
        e.level == "ERROR" and "SAFE STATE FAILED: rate table" in e.message for e in rec.events
    )
