"""Engine mechanics with in-process fakes: cleanup on every exit path, abort, timeout, retry,
progress, one part dropping without stopping the others. (End-to-end runs are in test_e2e_*.)"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from common.clock import ScaledClock
from drivers.errors import InstrumentTimeout, PartAbsent, TableFault
from procedures.engine.engine import Engine
from procedures.loading.config import load_procedure, load_product
from procedures.runtime.progress import ProgressEvent
from procedures.runtime.record import Dut, FileRef, RunRecord, Verdict, read_record
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import Bench, PartRun
from procedures.steps.registry import StepPolicy
from tests.procedures.fake_step import DeclaresNothing

ROOT = Path(__file__).resolve().parents[2]


class FakeInstrument:
    def __init__(self, calls: list[str], name: str) -> None:
        self.calls, self.name = calls, name

    def safe_state(self, *args: Any) -> None:
        self.calls.append(f"{self.name}.safe_state")


# the policies of the steps these tests name (as a procedure file would give them)
POLICIES = {"power": StepPolicy(timeout_s=60.0, retries=1)}


@dataclass
class Scripted(DeclaresNothing):
    """A step that sleeps, then does what it is told (the engine's Step protocol)."""

    name: str = "step"
    policy: Any = None
    condition: str = ""
    sleep_s: float = 1.0
    action: Any = None
    attempts: list[int] = field(default_factory=list)
    cleaned: list[str] | None = None  # the steps' names, as each is cleaned up

    def __post_init__(self) -> None:
        if not isinstance(self.policy, StepPolicy):
            self.policy = POLICIES.get(self.policy or "", StepPolicy())

    def setup(self, ctx: RunContext) -> None:
        return None

    def estimate_s(self, ctx: RunContext) -> float:
        return self.sleep_s

    def main(self, ctx: RunContext) -> None:
        self.attempts.append(1)
        ctx.wait.sleep(self.sleep_s)
        if self.action is not None:
            self.action(ctx, len(self.attempts))

    def cleanup(self, ctx: RunContext) -> None:
        if self.cleaned is not None:
            self.cleaned.append(self.name)


def _ctx(tmp_path: Path, n_parts: int = 1, speed: float = 1000.0) -> tuple[RunContext, list[str]]:
    proc, _ = load_procedure(ROOT / "config/procedures/eol-rate-table.yaml")
    prod, _ = load_product(ROOT / "config/products/gyr130.yaml")
    calls: list[str] = []
    bench = Bench(
        chamber=FakeInstrument(calls, "chamber"),
        supply=FakeInstrument(calls, "supply"),  # type: ignore[arg-type]
        links={},
        clock=ScaledClock(speed),
        table=FakeInstrument(calls, "table"),
    )  # type: ignore[arg-type]
    parts = []
    for s in range(1, n_parts + 1):
        ref = FileRef(path="x", sha256="0" * 64)
        rec = RunRecord(
            run_id=f"r{s}",
            verdict=Verdict.RUNNING,
            started_utc="t",
            dut=Dut(serial=f"SIM-000{s}", socket=s),
            product=ref,
            procedure=ref,
        )
        parts.append(PartRun(socket=s, serial=f"SIM-000{s}", folder=tmp_path / f"p{s}", record=rec))
    return RunContext(bench, proc, prod, parts), calls


SAFE = ["table.safe_state", "supply.safe_state", "chamber.safe_state"]
# the bench is made safe before the first step, and again at the end
SAFE_START_AND_END = SAFE + SAFE


def test_pass_path_cleans_up_and_judges(tmp_path: Path) -> None:
    ctx, calls = _ctx(tmp_path)
    cleaned: list[str] = []
    steps = [Scripted(name="a", cleaned=cleaned), Scripted(name="b", cleaned=cleaned)]
    verdicts = Engine(ctx, steps).run()  # type: ignore[arg-type]
    assert verdicts == {1: Verdict.PASS}
    assert calls == SAFE_START_AND_END
    assert cleaned == ["a", "b"]
    rec = read_record(tmp_path / "p1")
    assert (
        rec.verdict is Verdict.PASS
        and "a" in rec.timings
        and (rec.analysis.safe_state or {}).get("supply") == "safe"
    )


def test_instrument_error_ends_in_error_with_cleanup(tmp_path: Path) -> None:
    ctx, calls = _ctx(tmp_path)

    def boom(ctx: RunContext, n: int) -> None:
        raise TableFault("following error", fault_code=2, instrument="rate table")

    verdicts = Engine(ctx, [Scripted(name="sweep", action=boom), Scripted(name="never")]).run()  # type: ignore[arg-type]
    assert verdicts == {1: Verdict.ERROR}
    assert calls == SAFE_START_AND_END
    rec = read_record(tmp_path / "p1")
    assert "following error" in rec.reason and "sweep" in rec.reason
    assert "never" not in rec.timings


def test_bug_in_a_step_still_cleans_up(tmp_path: Path) -> None:
    ctx, calls = _ctx(tmp_path)

    def bug(ctx: RunContext, n: int) -> None:
        raise ZeroDivisionError("oops")

    assert Engine(ctx, [Scripted(name="x", action=bug)]).run() == {1: Verdict.ERROR}  # type: ignore[arg-type]
    assert calls == SAFE_START_AND_END
    assert "internal error" in read_record(tmp_path / "p1").reason


def test_abort_from_another_thread_stops_a_long_dwell(tmp_path: Path) -> None:
    ctx, calls = _ctx(tmp_path, speed=1.0)  # a 3600 s dwell at real speed: only abort ends it
    engine = Engine(ctx, [Scripted(name="dwell", sleep_s=3600.0)])  # type: ignore[arg-type]
    events: list[ProgressEvent] = []
    ctx.progress.subscribe(events.append)
    why = "the operator pressed ABORT on the station screen"  # the UI's reason
    threading.Timer(0.3, engine.abort, args=(why,)).start()
    verdicts = engine.run()
    assert verdicts == {1: Verdict.ABORTED}
    assert calls == SAFE_START_AND_END
    # said once (was "aborted by the operator (operator abort (station UI)) in step dwell")
    assert read_record(tmp_path / "p1").reason == f"aborted: {why}, in step dwell"
    assert events[-1].kind == "finished"


def test_an_error_stop_ends_error_and_the_first_reason_stands(tmp_path: Path) -> None:
    """station/exit_path.py: an uncaught exception in a station thread stops the run as
    ERROR (not ABORTED); a later abort (the UI closing) does not rename why it stopped."""
    ctx, calls = _ctx(tmp_path, speed=1.0)
    engine = Engine(ctx, [Scripted(name="dwell", sleep_s=3600.0)])  # type: ignore[arg-type]

    def stop() -> None:
        ctx.abort("internal error in thread 'acquisition' (ValueError: x)", error=True)
        ctx.abort("operator abort (station UI)")

    threading.Timer(0.3, stop).start()
    assert engine.run() == {1: Verdict.ERROR}
    assert calls == SAFE_START_AND_END
    rec = read_record(tmp_path / "p1")
    assert rec.reason.startswith("internal error in thread 'acquisition'"), rec.reason
    assert "station UI" not in rec.reason and "dwell" in rec.reason
    requested = rec.analysis.stop_requested_station_s
    assert requested is not None and 0.0 < requested < 60.0


def test_step_timeout_and_retry_policy(tmp_path: Path) -> None:
    ctx, calls = _ctx(tmp_path)
    # power has retries: 1 in the procedure file: one timeout is retried, then it passes
    flaky = Scripted(
        name="power",
        policy="power",
        action=lambda c, n: (_ for _ in ()).throw(InstrumentTimeout("slow")) if n == 1 else None,
    )
    assert Engine(ctx, [flaky]).run() == {1: Verdict.PASS}  # type: ignore[arg-type]
    assert len(flaky.attempts) == 2
    ctx2, _ = _ctx(tmp_path / "t")
    # power's timeout is 60 s: a 100 s dwell times out (twice, with the retry)
    slow = Scripted(name="power", policy="power", sleep_s=100.0)
    assert Engine(ctx2, [slow]).run() == {1: Verdict.ERROR}  # type: ignore[arg-type]
    assert "timeout" in read_record(tmp_path / "t" / "p1").reason
    assert len(slow.attempts) == 2


def test_one_part_dropping_does_not_stop_the_others(tmp_path: Path) -> None:
    ctx, _ = _ctx(tmp_path, n_parts=3)

    def absent_two(ctx: RunContext, n: int) -> None:
        def go(part: PartRun) -> None:
            if part.socket == 2:
                raise PartAbsent("socket 2: no part", instrument="fixture on socket 2")
            assert part.alive

        ctx.parts.each(go)

    verdicts = Engine(
        ctx, [Scripted(name="identify", action=absent_two), Scripted(name="more")]
    ).run()  # type: ignore[arg-type]
    assert verdicts == {1: Verdict.PASS, 2: Verdict.ERROR, 3: Verdict.PASS}
    assert read_record(tmp_path / "p2").reason == "socket 2: no part"
    assert "more" in read_record(tmp_path / "p3").timings


def test_progress_fraction_rises_to_one(tmp_path: Path) -> None:
    ctx, _ = _ctx(tmp_path)
    events: list[ProgressEvent] = []
    ctx.progress.subscribe(events.append)
    Engine(ctx, [Scripted(name=f"s{i}", sleep_s=50.0) for i in range(4)]).run()  # type: ignore[arg-type]
    fractions = [e.fraction for e in events]
    assert fractions == sorted(fractions) and fractions[-1] == pytest.approx(1.0)
    assert {e.step for e in events if e.kind == "step"} == {"s0", "s1", "s2", "s3"}
    mid = [e for e in events if e.step == "s2" and e.kind == "step"][0]
    assert mid.fraction == pytest.approx(0.5, abs=0.02) and mid.remaining_s == pytest.approx(
        100, abs=5
    )
