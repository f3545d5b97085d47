"""Three-axis fit and programming: b, M, G and the per-axis coefficients from the cube's
windows (procedures/analysis/three_axis.py), judged per axis against the product limits,
written into the part as CalibrationRegisters3 and read back.

record.json gets `calibration_three_axis` (vectors and matrices with their k=2
uncertainties; a key single-axis records never have) and the measurements per axis:
raw_bias_x_dps ..., raw_scale_error_x ..., misalignment_xy_mrad ... (M's off-diagonal over its
row's diagonal), g_sensitivity_xy_dps_per_mps2 ... (row: gyro axis, column: accelerometer
axis) and, when the conditions span temperature and supply, bias_temp_coeff_x_dps_per_c ...
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

import numpy as np

from drivers.protocols import CalibrationRegisters3, CalibrationStore3
from procedures.analysis.errors import AnalysisError
from procedures.analysis.three_axis import ThreeAxisCalibration, fit_three_axis, vec3
from procedures.runtime.record import CalibrationThreeAxis, Verdict
from procedures.runtime.results import ProgrammingResults, ThreeAxisWindow
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun, condition_record
from procedures.steps.program import ProgramStep
from procedures.steps.registry import Declared, Provided, StepSettings, StepType

AXES = "xyz"
PER_AXIS_TV = (
    ("bias_temp_coeff", "dps_per_c", "bias_temp_coeff_dps_per_c", "deg/s/C"),
    ("bias_supply_coeff", "dps_per_v", "bias_supply_coeff_dps_per_v", "deg/s/V"),
    ("scale_temp_coeff", "per_c", "scale_temp_coeff_per_c", "1/C"),
    ("scale_supply_coeff", "per_v", "scale_supply_coeff_per_v", "1/V"),
)


def per_axis_measurements(cal: ThreeAxisCalibration) -> list[tuple[str, float, float, str, str]]:
    """(name, value, U k=2, units, limit name) of every per-axis measurement of the fit."""
    out: list[tuple[str, float, float, str, str]] = []
    u_m = cal.uncertainty_k2("matrix")
    m = cal.matrix
    for i, a in enumerate(AXES):
        out.append((f"raw_bias_{a}_dps", float(cal.bias_dps[i]),
                    float(cal.uncertainty_k2("bias_dps")[i]), "deg/s", "raw_bias_dps"))
        out.append((f"raw_scale_error_{a}", float(1.0 / m[i, i] - 1.0),
                    float(u_m[i, i] / m[i, i] ** 2), "1", "raw_scale_error"))
        for j, b in enumerate(AXES):
            if i != j:
                out.append((f"misalignment_{a}{b}_mrad", float(1e3 * m[i, j] / m[i, i]),
                            float(1e3 * u_m[i, j] / abs(m[i, i])), "mrad", "misalignment_mrad"))
            out.append((f"g_sensitivity_{a}{b}_dps_per_mps2",
                        float(cal.g_sensitivity_dps_per_mps2[i, j]),
                        float(cal.uncertainty_k2("g_sensitivity_dps_per_mps2")[i, j]),
                        "deg/s/(m/s^2)", "g_sensitivity_dps_per_mps2"))
        if cal.temp_supply_fitted:
            for stem, unit_name, field, units in PER_AXIS_TV:
                out.append((f"{stem}_{a}_{unit_name}", float(cal.value(field)[i]),
                            float(cal.uncertainty_k2(field)[i]), units, field))
    return out


Row = tuple[float, float, float]


def _mat3(m: Any) -> tuple[Row, Row, Row]:
    a = np.asarray(m, dtype=np.float64).reshape(3, 3)
    return (vec3(a[0]), vec3(a[1]), vec3(a[2]))


def registers_from(cal: ThreeAxisCalibration) -> CalibrationRegisters3:
    return CalibrationRegisters3(
        bias_dps=vec3(cal.bias_dps),
        matrix=_mat3(cal.matrix),
        g_sensitivity_dps_per_mps2=_mat3(cal.g_sensitivity_dps_per_mps2),
        bias_tc_dps_per_c=vec3(cal.bias_temp_coeff_dps_per_c),
        bias_vc_dps_per_v=vec3(cal.bias_supply_coeff_dps_per_v),
        scale_tc_per_c=vec3(cal.scale_temp_coeff_per_c),
        scale_vc_per_v=vec3(cal.scale_supply_coeff_per_v),
        t0_c=cal.reference_temperature_c,
        v0_v=cal.reference_supply_v,
    )


class FitThreeAxisSettings(StepSettings):
    pass


class FitThreeAxis(StepType[FitThreeAxisSettings]):
    """Fit b, M, G and the per-axis temperature and supply coefficients of each part."""

    type_name = "fit_three_axis"
    Settings = FitThreeAxisSettings
    provides = frozenset({Provided.FIT_THREE_AXIS})
    Results = ThreeAxisWindow

    @classmethod
    def requires(cls, settings: Any) -> set[Provided]:
        return {Provided.THREE_AXIS_WINDOWS}

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        out: list[Declared] = []
        for a in AXES:
            out.append(Declared(f"raw_bias_{a}_dps", "deg/s", f"bias of axis {a} at T0, V0",
                                limit="raw_bias_dps"))
            out.append(Declared(f"raw_scale_error_{a}", "1", f"1/M_{a}{a} - 1",
                                limit="raw_scale_error"))
            for b in AXES:
                if a != b:
                    out.append(Declared(f"misalignment_{a}{b}_mrad", "mrad",
                                        f"M_{a}{b} / M_{a}{a}", limit="misalignment_mrad"))
                out.append(Declared(f"g_sensitivity_{a}{b}_dps_per_mps2", "deg/s/(m/s^2)",
                                    f"G_{a}{b}", limit="g_sensitivity_dps_per_mps2"))
            for stem, unit_name, field, units in PER_AXIS_TV:
                out.append(Declared(f"{stem}_{a}_{unit_name}", units, f"{field} of axis {a}",
                                    limit=field, optional=True))
        return out

    def estimate_s(self, ctx: RunContext) -> float:
        return 1.0

    def main(self, ctx: RunContext) -> None:
        ctx.parts.each(lambda part: self._fit(ctx, part))

    def _fit(self, ctx: RunContext, part: PartRun) -> None:
        try:
            cal = fit_three_axis(
                part.three_axis_windows,
                ctx.product.reference_temperature_c,
                ctx.product.reference_supply_v,
            )
        except AnalysisError as exc:
            ctx.parts.drop(part, Verdict.ERROR, f"three-axis fit: {exc}")
            return
        part.three_axis_fit = cal
        part.record.calibration_three_axis = CalibrationThreeAxis.model_validate(
            cal.as_calibration_dict()
        )
        part.record.conditions = [condition_record(r) for r in part.conditions.values()]
        part.record.analysis.three_axis_windows = [
            ThreeAxisWindow.model_validate(asdict(w)) for w in part.three_axis_windows
        ]
        for note in cal.notes:
            ctx.records.event(f"socket {part.socket}: {note}", parts=[part])
        for name, value, u_k2, units, limit in per_axis_measurements(cal):
            if np.isfinite(value):
                ctx.records.measure(part, name, value, units=units, limit_name=limit,
                                    uncertainty_k2=u_k2)


class ProgramThreeAxisSettings(StepSettings):
    pass


class ProgramThreeAxis(ProgramStep[ProgramThreeAxisSettings]):
    """Write CalibrationRegisters3 to each part that passed, read back, compensation on."""

    type_name = "program_three_axis"
    Settings = ProgramThreeAxisSettings

    @classmethod
    def requires(cls, settings: Any) -> set[Provided]:
        return {Provided.FIT_THREE_AXIS}

    def _program(self, ctx: RunContext, part: PartRun) -> None:
        cal = part.three_axis_fit
        link = part.link
        if cal is None or not isinstance(link, CalibrationStore3):
            ctx.parts.drop(part, Verdict.ERROR, (
                "no three-axis fit to program" if cal is None else
                "the part link cannot hold three-axis registers: check the product's axes"))
            return
        regs = registers_from(cal)
        link.write_calibration3(regs)  # reads back and compares; raises on a mismatch
        read = link.read_calibration3()
        block = part.record.calibration_three_axis
        if block is not None:
            block.readback_ok = True  # write_calibration3 compared the read-back
            block.readback = {"bias_dps": list(read.bias_dps),
                              "matrix": [list(r) for r in read.matrix]}
        link.set_compensation(True)
        part.record.analysis.programming = ProgrammingResults(programmed=True)
        ctx.records.event(f"socket {part.socket}: three-axis registers written and read back",
                          parts=[part])
