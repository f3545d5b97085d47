"""Bounded field types shared by every configuration model (station, procedure, product, sim
config, model YAML): text of limited length without control characters, and the physical
ceilings the schemas use. Numbers are made finite per model with `allow_inf_nan=False`."""

from __future__ import annotations

import re
from typing import Annotated

from pydantic import AfterValidator, Field

ONE_DAY_S = 86_400.0  # any duration of a step, wait or timeout
ONE_HOUR_S = 3_600.0  # settles, rests and check intervals
MAX_RATE_DPS = 20_000.0  # any rate a table or a part could see, deg/s
MAX_ACCEL_DPS2 = 100_000.0
TEMP_LOW_C = -100.0  # chamber-plausible temperatures
TEMP_HIGH_C = 200.0
MAX_SUPPLY_V = 100.0
MAX_LIST = 200  # items in a rate set, condition list, angle list
MAX_REPEATS = 100

_CONTROL = re.compile(r"[\x00-\x08\x0a-\x1f\x7f-\x9f\u2028\u2029]")
_CONTROL_MULTILINE = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\u2028\u2029]")


def _no_control(value: str) -> str:
    if (bad := _CONTROL.search(value)) is not None:
        raise ValueError(f"control character U+{ord(bad.group()):04X} is not allowed; remove it")
    return value


def _no_control_multiline(value: str) -> str:
    if (bad := _CONTROL_MULTILINE.search(value)) is not None:
        raise ValueError(f"control character U+{ord(bad.group()):04X} is not allowed; remove it")
    return value


# a name, serial, model, version: one line, short
Name = Annotated[str, Field(max_length=200), AfterValidator(_no_control)]
ShortName = Annotated[str, Field(max_length=64), AfterValidator(_no_control)]
# free text (a description): line breaks allowed
Text = Annotated[str, Field(max_length=4_000), AfterValidator(_no_control_multiline)]
# a file path or an address
PathText = Annotated[str, Field(max_length=4_096), AfterValidator(_no_control)]
