"""The unit types of procedure and product files (pydantic-annotated floats bounded to what
the bench can do) and the strict base model of their sections.

They sit below the steps, whose settings use them, and below procedures.loading.config, which builds
the plan out of the steps: a step's settings import from here, never from the config.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from common.bounded import MAX_RATE_DPS, MAX_SUPPLY_V, ONE_DAY_S, TEMP_HIGH_C, TEMP_LOW_C


class StrictModel(BaseModel):
    """A section of a procedure or product file: unknown keys refused, frozen, finite."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


Seconds = Annotated[float, Field(le=ONE_DAY_S)]  # a duration or timeout: within a day
Rate = Annotated[float, Field(ge=-MAX_RATE_DPS, le=MAX_RATE_DPS)]
ChamberTemp = Annotated[float, Field(ge=TEMP_LOW_C, le=TEMP_HIGH_C)]
Volts = Annotated[float, Field(gt=0, le=MAX_SUPPLY_V)]
LimitValue = Annotated[float, Field(ge=-1e9, le=1e9)]
