"""What the model knows of an effect (EffectSpec) and the pinned vocabulary of the base
variables a term may depend on: shared by the effect catalog (effects.py) and the library of
generic terms (library.py), which therefore need not import each other both ways."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(frozen=True)
class EffectSpec:
    id: str
    params: Mapping[str, str]  # parameter name -> units
    description: str
    pattern: str  # the variable its residual signature shows against
    nonlinear: tuple[str, ...] = ()  # parameters profiled, not solved linearly
    n_columns: int = 1
    first_order: bool = False
    # base variables the term depends on (vocabulary REGRESSOR_VOCABULARY)
    regressors: tuple[str, ...] = ()
    # readable formula, str.format()-ed with the parameters
    formula: str = ""
    # a term coupling the axes of a three-axis part: (the axis it acts on, the axis it comes
    # from), e.g. ("y", "x"): couples y <- x (procedures/model/cross_axis.py)
    couples: tuple[str, ...] = ()


# Pinned vocabulary of the base variables a term may depend on (JSON `regressors`).
# Words keep their meaning; the vocabulary may grow (temperature_direction: issue 29).
# Three-axis parts (issue 29): the other axes' reference rates and accelerometer readings.
REGRESSOR_VOCABULARY = ("rate", "temperature", "temperature_rate", "supply", "angle", "time",
                        "temperature_direction", "rate_x", "rate_y", "rate_z", "accel_x",
                        "accel_y", "accel_z")
