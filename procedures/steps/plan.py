"""From a procedure file to the list of steps the engine runs."""

from __future__ import annotations

from procedures.conditions import plan_conditions
from procedures.config import ProcedureConfig
from procedures.engine import Step
from procedures.steps.bias import Bias
from procedures.steps.fit import Fit
from procedures.steps.positions import Positions
from procedures.steps.power import PowerIdentify
from procedures.steps.program import Program
from procedures.steps.stop import StopMethod, VerifyStop
from procedures.steps.sweep import RateSweep
from procedures.steps.thermal import Stabilise
from procedures.steps.verify import Verify


def build_plan(procedure: ProcedureConfig, start_temp_c: float | None = None) -> list[Step]:
    """Power/identify, then per condition: stabilise, bias, positions (optional), sweep,
    stop; fit, program, verify."""
    cond = procedure.conditions
    conditions = plan_conditions(
        cond.temperatures_c, cond.supplies_v, order=cond.order, start_temp_c=start_temp_c
    )
    steps: list[Step] = [PowerIdentify(supply_v=conditions[0].supply_v)]
    previous = start_temp_c
    for i, c in enumerate(conditions):
        steps.append(
            Stabilise(
                target=c,
                first=i == 0,
                condition=c.name,
                temperature_changes=previous is None or c.temperature_c != previous,
            )
        )
        previous = c.temperature_c
        steps.append(Bias(first=i == 0, condition=c.name))
        pos = procedure.positions
        if pos is not None and pos.enabled and (pos.at == "every_condition" or i == 0):
            steps.append(Positions(condition=c.name))
        if procedure.table_enabled:
            steps.append(RateSweep(condition=c.name))
        if procedure.stop_enabled:
            steps.append(StopMethod(condition=c.name))
    steps.append(Fit())
    steps.append(Program())
    method = procedure.verify_method
    if method == "rate_table":
        steps.append(Verify())
    elif method == "stop_method":
        steps.append(VerifyStop())
    return steps
