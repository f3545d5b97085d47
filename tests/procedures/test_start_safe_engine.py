"""The engine makes a bench found in any state safe before the first step (in-process fakes):
table at rest and disabled, every fixture stream stopped whatever the station believes,
supply off, chamber at its safe temperature, each read back; a bench that cannot be made safe
runs no step. The streams' safe state is read back from the fixture, never assumed."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from common.clock import ScaledClock
from drivers.protocols import SafeReadback
from procedures.engine.engine import Engine
from procedures.loading.config import load_procedure, load_product
from procedures.runtime.record import Dut, FileRef, RunRecord, Verdict, read_record
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import Bench, PartRun
from procedures.steps.registry import StepPolicy
from tests.procedures.fake_step import DeclaresNothing

ROOT = Path(__file__).resolve().parents[2]


class Table:
    """Left turning by a crashed run."""

    def __init__(self) -> None:
        self.moving = self.enabled = True

    def safe_state(self) -> None:
        self.moving = self.enabled = False

    def check_safe(self) -> SafeReadback:
        return SafeReadback(not self.moving and not self.enabled, f"moving {self.moving}")


class Supply:
    def __init__(self) -> None:
        self.on = True

    def safe_state(self) -> None:
        self.on = False

    def check_safe(self) -> SafeReadback:
        return SafeReadback(not self.on, "output ON" if self.on else "output off")


class Chamber:
    def __init__(self) -> None:
        self.setpoint_c = 85.0

    def safe_state(self, safe_temp_c: float) -> None:
        self.setpoint_c = safe_temp_c

    def check_safe(self, safe_temp_c: float) -> SafeReadback:
        return SafeReadback(self.setpoint_c == safe_temp_c, f"setpoint {self.setpoint_c:g} C")


class Link:
    """A fixture whose stream a crashed station started (this station never did)."""

    def __init__(self, stops: bool = True) -> None:
        self.started, self.stops = True, stops

    def stop_stream(self) -> None:
        if self.stops:
            self.started = False

    def check_stream_stopped(self) -> SafeReadback:
        return SafeReadback(not self.started, f"STREAM? {int(self.started)}")


class LinkWithoutReadback:
    def __init__(self) -> None:
        self.stopped = 0

    def stop_stream(self) -> None:
        self.stopped += 1


@dataclass
class Look(DeclaresNothing):
    """A step that notes the bench as it finds it at its setup."""

    bench: Bench
    name: str = "power_identify"
    condition: str = ""
    policy: StepPolicy = field(default_factory=StepPolicy)
    seen: list[dict[str, Any]] = field(default_factory=list)

    def estimate_s(self, ctx: RunContext) -> float:
        return 1.0

    def setup(self, ctx: RunContext) -> None:
        b = self.bench
        self.seen.append({
            "table_moving": b.table.moving or b.table.enabled,  # type: ignore[union-attr]
            "supply_on": b.supply.on,  # type: ignore[attr-defined]
            "chamber_c": b.chamber.setpoint_c,  # type: ignore[attr-defined]
            "streams": [getattr(link, "started", False) for link in b.links.values()],
        })

    def main(self, ctx: RunContext) -> None:
        ctx.wait.sleep(1.0)

    def cleanup(self, ctx: RunContext) -> None:
        return None


def _run(tmp_path: Path, links: dict[int, Any]) -> tuple[Look, RunContext]:
    proc, _ = load_procedure(ROOT / "config/procedures/eol-rate-table.yaml")
    prod, _ = load_product(ROOT / "config/products/gyr130.yaml")
    bench = Bench(chamber=Chamber(), supply=Supply(), links=links,  # type: ignore[arg-type]
                  clock=ScaledClock(1000.0), table=Table())  # type: ignore[arg-type]
    ref = FileRef(path="x", sha256="0" * 64)
    parts = [
        PartRun(socket=s, serial=f"SIM-000{s}", folder=tmp_path / f"p{s}", record=RunRecord(
            run_id=f"r{s}", verdict=Verdict.RUNNING, started_utc="t",
            dut=Dut(serial=f"SIM-000{s}", socket=s), product=ref, procedure=ref))
        for s in links
    ]
    ctx = RunContext(bench, proc, prod, parts)
    step = Look(bench)
    Engine(ctx, [step]).run()  # type: ignore[list-item]
    return step, ctx


def test_a_bench_left_unsafe_is_safe_before_the_first_step(tmp_path: Path) -> None:
    step, ctx = _run(tmp_path, {1: Link(), 2: Link()})
    safe_c = ctx.procedure.chamber.safe_temp_c
    assert step.seen == [
        {"table_moving": False, "supply_on": False, "chamber_c": safe_c, "streams": [False, False]}
    ]
    rec = read_record(tmp_path / "p1")
    assert rec.verdict is Verdict.PASS, rec.reason
    start = rec.analysis.start_safe_state
    assert start is not None and start.all_safe
    assert start.instruments["streams"].detail == "sockets 1, 2: STREAM? 0"
    assert any(e.message.startswith("safe before the first step: part streams") for e in rec.events)


def test_a_stream_that_will_not_stop_runs_no_step_and_is_not_called_safe(tmp_path: Path) -> None:
    step, _ = _run(tmp_path, {1: Link(), 2: Link(stops=False)})
    assert step.seen == []  # no step ran on a bench that could not be made safe
    rec = read_record(tmp_path / "p1")
    assert rec.verdict is Verdict.ERROR
    assert "could not be made safe before the first step" in rec.reason
    assert "part streams NOT SAFE" in rec.reason and "socket 2: STREAM? 1" in rec.reason
    # the end's pass read the fixture back too: the stream is named, not "commanded"
    assert rec.analysis.safe_state_report is not None
    end = rec.analysis.safe_state_report.instruments["streams"]
    assert end.safe is False and "socket 2: STREAM? 1" in end.detail


def test_a_link_that_cannot_read_back_is_still_sent_stop(tmp_path: Path) -> None:
    link = LinkWithoutReadback()
    _, _ = _run(tmp_path, {1: link})
    assert link.stopped == 2  # before the first step and at the end, whatever it believed
    rec = read_record(tmp_path / "p1")
    assert rec.analysis.start_safe_state is not None
    assert "cannot read its stream back" in rec.analysis.start_safe_state.instruments[
        "streams"].detail
