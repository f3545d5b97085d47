"""Declared measurements at run time (in-process fakes): one never set is NOT_MEASURED on the
record; an undeclared one is a bug that ends the run in ERROR; a FAIL under a limit with
`on_fail: stop_part` takes the part out at once; a failed part is never programmed."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from procedures.runtime.limits import Limit, Limits
from procedures.runtime.record import Outcome, Verdict, read_record
from procedures.runtime.results import ProgrammingResults
from procedures.runtime.run_context import RunContext
from procedures.steps.program import Program, ProgramSettings
from procedures.steps.registry import Declared, Place, StepSettings, StepType

from .test_engine_mechanics import _ctx


class Settings(StepSettings):
    values: dict[str, float] = {}  # what to set, by name


class Measures(StepType[Settings]):
    """Declares raw_bias_dps (per condition) and bias_instability_deg_per_h; sets `values`."""

    type_name = "measures"
    Settings = Settings
    ran: list[int] = []

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return [Declared("raw_bias_dps", "deg/s", per_condition=True),
                Declared("bias_instability_deg_per_h", "deg/h")]

    def main(self, ctx: RunContext) -> None:
        for part in ctx.parts.alive():
            Measures.ran.append(part.socket)
            for name, value in self.settings.values.items():
                ctx.records.measure(part, name, value, condition=self.condition or None)


def _step(values: dict[str, float], condition: str = "") -> Measures:
    from procedures.runtime.conditions import Condition

    cond = Condition(25.0, 5.0) if condition else None
    return Measures(Settings(values=values), Place(condition=cond))


def test_a_declared_measurement_never_set_is_not_measured(tmp_path: Path) -> None:
    ctx, _ = _ctx(tmp_path)
    from procedures.engine.engine import Engine

    verdicts = Engine(ctx, [_step({"raw_bias_dps": 1.0}, condition="T25_V5")]).run()
    assert verdicts == {1: Verdict.PASS}
    rec = read_record(tmp_path / "p1")
    missing = [m for m in rec.measurements if m.name == "bias_instability_deg_per_h"]
    assert len(missing) == 1
    m = missing[0]
    assert m.value is None and m.outcome is Outcome.NOT_MEASURED
    assert m.units == "deg/h" and m.high == 60.0 and m.condition == "T25_V5"
    assert rec.analysis.not_measured == ["bias_instability_deg_per_h"]
    # the PASS says what it does not cover (a new user read "all within limits" as all measured)
    assert rec.reason == ("all measurements within limits; "
                          "not measured: bias_instability_deg_per_h@T25_V5")
    set_ = [m for m in rec.measurements if m.name == "raw_bias_dps"]
    assert len(set_) == 1 and set_[0].outcome is Outcome.PASS


def test_an_undeclared_measurement_ends_the_run_in_error(tmp_path: Path) -> None:
    ctx, calls = _ctx(tmp_path)
    from procedures.engine.engine import Engine

    assert Engine(ctx, [_step({"asymmetry": 0.0})]).run() == {1: Verdict.ERROR}
    rec = read_record(tmp_path / "p1")
    assert "step measures recorded 'asymmetry', which it does not declare" in rec.reason
    assert calls  # the bench was still made safe


def _stop_part(ctx: RunContext, name: str) -> None:
    limits = ctx.product.limits.model_dump()
    limits[name] = {**limits[name], "on_fail": "stop_part"}
    ctx.records.product = ctx.product.model_copy(update={"limits": Limits.model_validate(limits)})


def test_on_fail_stop_part_takes_the_failing_part_out_at_once(tmp_path: Path) -> None:
    ctx, _ = _ctx(tmp_path, n_parts=2)
    _stop_part(ctx, "raw_bias_dps")
    from procedures.engine.engine import Engine

    Measures.ran = []

    class Bias2(Measures):
        def main(self, ctx: RunContext) -> None:
            for part in ctx.parts.alive():
                Measures.ran.append(part.socket)
                value = 20.0 if part.socket == 2 else 1.0  # the limit is +/-10
                ctx.records.measure(part, "raw_bias_dps", value, condition="T25_V5")
                ctx.records.measure(part, "bias_instability_deg_per_h", 10.0)

    first = Bias2(Settings(), Place())
    later = _step({"raw_bias_dps": 1.0, "bias_instability_deg_per_h": 10.0})
    verdicts = Engine(ctx, [first, later]).run()
    assert verdicts == {1: Verdict.PASS, 2: Verdict.FAIL}
    assert Measures.ran == [1, 2, 1]  # part 2 measured nothing after the failing value
    rec = read_record(tmp_path / "p2")
    assert rec.reason == "failed raw_bias_dps@T25_V5 (on_fail: stop_part)"
    assert rec.failed_measurements == ["raw_bias_dps@T25_V5"]
    # what it measured before it stopped stays on the record; no NOT_MEASURED for the rest
    assert [m.name for m in rec.measurements].count("raw_bias_dps") == 1
    assert [m.name for m in rec.measurements if m.outcome is Outcome.NOT_MEASURED] == []
    assert any(m.name == "frames_lost_fraction" for m in rec.measurements) is False  # no stream


def test_a_part_that_failed_a_limit_is_never_programmed(tmp_path: Path) -> None:
    ctx, _ = _ctx(tmp_path, n_parts=2)
    from procedures.engine.engine import Engine

    class Scale(Measures):
        def main(self, ctx: RunContext) -> None:
            for part in ctx.parts.alive():
                # raw_bias_dps limit is +/-10 with on_fail: continue (the default)
                value = 12.0 if part.socket == 1 else 1.0
                ctx.records.measure(part, "raw_bias_dps", value, condition="T25_V5")
                ctx.records.measure(part, "bias_instability_deg_per_h", 10.0)

    programmed: list[int] = []

    class Program2(Program):
        def main(self, ctx: RunContext) -> None:
            programmed.extend(p.socket for p in ctx.parts.alive())

    assert Limit.model_validate({"high": 1.0}).on_fail == "continue"
    verdicts = Engine(ctx, [Scale(Settings(), Place()), Program2(ProgramSettings())]).run()
    assert verdicts == {1: Verdict.FAIL, 2: Verdict.PASS}
    assert programmed == [2]
    rec = read_record(tmp_path / "p1")
    assert rec.reason == "not programmed: failed raw_bias_dps@T25_V5"
    assert rec.analysis.programming == ProgrammingResults(programmed=False, reason=rec.reason)
    assert rec.failed_measurements == ["raw_bias_dps@T25_V5"]
