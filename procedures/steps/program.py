"""Write the fitted coefficients to each part, read them back, compare, switch compensation on."""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any

from drivers.protocols import CalibrationRegisters
from procedures.runtime.record import Outcome, Verdict
from procedures.runtime.results import ProgrammingResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun, ProgrammableFit
from procedures.runtime.streams import PartStream
from procedures.steps.fit_order import readback_dict
from procedures.steps.registry import Declared, Provided, S, StepSettings, StepType

READBACK_REL_TOL = 1e-6


def registers_from_fit(fit: ProgrammableFit) -> CalibrationRegisters:
    co = fit.coefficients
    return CalibrationRegisters(
        bias_dps=co.bias_dps,
        scale=co.scale,
        bias_tc_dps_per_c=co.bias_temp_coeff_dps_per_c,
        scale_tc_per_c=co.scale_temp_coeff_per_c,
        bias_vc_dps_per_v=co.bias_supply_coeff_dps_per_v,
        scale_vc_per_v=co.scale_supply_coeff_per_v,
        t0_c=co.reference_temperature_c,
        v0_v=co.reference_supply_v,
        **fit.registers_beyond_first_order,  # procedures.steps.fit_order
    )


def readback_differences(written: CalibrationRegisters, read: CalibrationRegisters) -> list[str]:
    bad = []
    for key, w in asdict(written).items():
        r = getattr(read, key)
        if not math.isclose(w, r, rel_tol=READBACK_REL_TOL, abs_tol=1e-9 + 1e-6 * abs(w) * 0):
            bad.append(f"{key}: wrote {w:.9g}, read {r:.9g}")
    return bad


class ProgramSettings(StepSettings):
    """No settings: the fitted coefficients are written as they are."""


def failed_limits(part: PartRun) -> list[str]:
    """What the part failed so far (name@condition), from its record."""
    return [f"{m.name}@{m.condition}" if m.condition else m.name
            for m in part.record.measurements if m.outcome is Outcome.FAIL]


def _stream(part: PartRun) -> PartStream:
    assert part.stream is not None
    return part.stream


class ProgramStep(StepType[S]):
    """What every programming step does around writing its registers (`_program`, one part):
    a part that failed any limit is never programmed (it leaves the run FAIL, the record
    says why); the parts' streams stop while their registers are written."""

    provides = frozenset({Provided.PROGRAMMED})
    Results = ProgrammingResults

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return []

    def estimate_s(self, ctx: RunContext) -> float:
        return 2.0

    def setup(self, ctx: RunContext) -> None:
        for part in ctx.parts.alive():
            failed = failed_limits(part)
            if failed:
                reason = f"not programmed: failed {', '.join(failed)}"
                part.record.analysis.programming = ProgrammingResults(
                    programmed=False, reason=reason
                )
                ctx.parts.drop(part, Verdict.FAIL, reason)
        ctx.parts.require()

    def main(self, ctx: RunContext) -> None:
        for part in ctx.parts.alive():
            ctx.parts.per_part(part, lambda p: _stream(p).stop())
        ctx.wait.check()  # the watchdog: programming is no reason to miss an e-stop
        ctx.parts.each(lambda part: self._program(ctx, part))
        ctx.wait.check()
        for part in ctx.parts.alive():
            ctx.parts.per_part(part, lambda p: _stream(p).start())

    def _program(self, ctx: RunContext, part: PartRun) -> None:
        raise NotImplementedError


class Program(ProgramStep[ProgramSettings]):
    """Write the fit to each part, read it back, switch compensation on; a part that failed
    any limit is never programmed (it leaves the run FAIL, the record says why)."""

    type_name = "program"
    Settings = ProgramSettings

    @classmethod
    def requires(cls, settings: Any) -> set[Provided]:
        return {Provided.FIT}

    def _program(self, ctx: RunContext, part: PartRun) -> None:
        if part.fit is None:
            ctx.parts.drop(part, Verdict.ERROR, "no fitted coefficients to program")
            return
        regs = registers_from_fit(part.fit)
        link = part.link
        link.write_calibration(regs)
        read = link.read_calibration()
        diffs = readback_differences(regs, read)
        cal = part.record.calibration
        if cal is not None:
            cal.readback_ok = not diffs
            cal.readback = readback_dict(read)
        if diffs:
            ctx.parts.drop(
                part,
                Verdict.FAIL,
                "calibration read back differs from what was written ("
                + "; ".join(diffs)
                + "): the part's calibration memory may be faulty",
            )
            return
        link.set_compensation(True)
        ctx.records.event(f"socket {part.socket}: coefficients written and read back", parts=[part])
