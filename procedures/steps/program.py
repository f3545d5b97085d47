"""Write the fitted coefficients to each part, read them back, compare, switch compensation on."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from drivers.protocols import CalibrationRegisters
from procedures.engine import PartRun, RunContext
from procedures.record import Verdict
from procedures.steps.base import BaseStep

READBACK_REL_TOL = 1e-6


def registers_from_fit(part: PartRun) -> CalibrationRegisters:
    co = part.fit.coefficients
    return CalibrationRegisters(
        bias_dps=co.bias_dps,
        scale=co.scale,
        bias_tc_dps_per_c=co.bias_temp_coeff_dps_per_c,
        scale_tc_per_c=co.scale_temp_coeff_per_c,
        bias_vc_dps_per_v=co.bias_supply_coeff_dps_per_v,
        scale_vc_per_v=co.scale_supply_coeff_per_v,
        t0_c=co.reference_temperature_c,
        v0_v=co.reference_supply_v,
    )


def readback_differences(written: CalibrationRegisters, read: CalibrationRegisters) -> list[str]:
    bad = []
    for key, w in asdict(written).items():
        r = getattr(read, key)
        if not math.isclose(w, r, rel_tol=READBACK_REL_TOL, abs_tol=1e-9 + 1e-6 * abs(w) * 0):
            bad.append(f"{key}: wrote {w:.9g}, read {r:.9g}")
    return bad


@dataclass
class Program(BaseStep):
    name: str = "program"
    policy: str = "program"

    def estimate_s(self, ctx: RunContext) -> float:
        return 2.0

    def main(self, ctx: RunContext) -> None:
        for part in ctx.alive():
            assert part.stream is not None
            ctx.per_part(part, lambda p: p.stream.stop())  # type: ignore[union-attr]
        ctx.check()  # the watchdog: programming is no reason to miss an e-stop
        ctx.each(lambda part: self._program(ctx, part))
        ctx.check()
        for part in ctx.alive():
            ctx.per_part(part, lambda p: p.stream.start())  # type: ignore[union-attr]

    def _program(self, ctx: RunContext, part: PartRun) -> None:
        if part.fit is None:
            ctx.drop(part, Verdict.ERROR, "no fitted coefficients to program")
            return
        regs = registers_from_fit(part)
        link = part.link
        link.write_calibration(regs)
        read = link.read_calibration()
        diffs = readback_differences(regs, read)
        cal = part.record.calibration
        if cal is not None:
            cal.readback_ok = not diffs
            cal.readback = {k: float(v) for k, v in asdict(read).items()}
        if diffs:
            ctx.drop(
                part,
                Verdict.FAIL,
                "calibration read back differs from what was written ("
                + "; ".join(diffs)
                + "): the part's calibration memory may be faulty",
            )
            return
        link.set_compensation(True)
        ctx.event(f"socket {part.socket}: coefficients written and read back", parts=[part])
