"""From a procedure file to the list of steps the engine runs."""

from __future__ import annotations

from typing import Any

from procedures.loading.config import ProcedureConfig
from procedures.steps.registry import StepType


def build_plan(
    procedure: ProcedureConfig, start_temp_c: float | None = None
) -> list[StepType[Any]]:
    """The procedure's steps in run order, loops unrolled (`ProcedureConfig.plan`)."""
    return procedure.plan(start_temp_c)
