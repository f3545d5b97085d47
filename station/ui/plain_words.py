"""Plain words for the operator: what the station is doing and why a part failed.

The engine speaks in step type names ("thermal"), condition names ("T45_V5.25") and
measurement names ("raw_bias_dps"). Here they become phrases: a catalog key with its
parameters, {"key": "step.thermal.heat", "params": {"temp_c": "45"}}. The page renders a
phrase with its own language's catalog (station/ui/messages/); a parameter may itself be a
phrase. No text lives here, only keys, so every language gets the same facts.
"""

from __future__ import annotations

import math
import re
from typing import Any

from station.ui import catalog

Phrase = dict[str, Any]

# A step type or measurement name reads as its own words when the catalog (English is
# complete by definition) has a `step.<type>` / `measure.<name>` entry; others read their name.
# tests/ui/test_plain_words.py checks that every shipped step type and limit has words.
VERDICTS = ("PASS", "FAIL", "ERROR", "ABORTED")
ROOM_BAND_C = (20.0, 30.0)  # a thermal step to a target inside this band "settles"
_CONDITION = re.compile(r"^T(?P<temp>-?\d+(?:\.\d+)?)(?:_V(?P<supply>\d+(?:\.\d+)?))?$")
_SUPPLY_ONLY = re.compile(r"^V(?P<supply>\d+(?:\.\d+)?)$")


def _has_words(key: str) -> bool:
    return key in catalog.load(catalog.DEFAULT_LANGUAGE)


def phrase(key: str, **params: Any) -> Phrase:
    return {"key": key, "params": params}


def parse_condition(condition: str) -> tuple[float | None, float | None]:
    """(temperature C, supply V) of a condition name like "T45_V5.25"; None where absent."""
    text = condition.strip()
    m = _CONDITION.match(text)
    if m:
        supply = m.group("supply")
        return float(m.group("temp")), float(supply) if supply else None
    m = _SUPPLY_ONLY.match(text)
    if m:
        return None, float(m.group("supply"))
    return None, None


def step_type_of(label: str) -> str:
    """The step type of an engine label ("thermal T45_V5.25" -> "thermal")."""
    return label.strip().split(" ")[0] if label.strip() else ""


def step_phrases(step: str, condition: str, phase: str = "") -> list[Phrase]:
    """What the station is doing, as phrases the page joins with commas.

    step_phrases("thermal", "T45_V5.25") -> "Heating to 45 C", "supply 5.25 V";
    step_phrases("ramp_calibration", "", "cooling") -> the step's words, then its phase's
    ("phase.ramp_calibration.cooling"; a phase without words is left out)."""
    out = _step_and_condition(step, condition)
    if phase and _has_words(f"phase.{step}.{phase}"):
        out.append(phrase(f"phase.{step}.{phase}"))
    return out


def _step_and_condition(step: str, condition: str) -> list[Phrase]:
    temp_c, supply_v = parse_condition(condition)
    out: list[Phrase] = []
    if step == "thermal" and temp_c is not None:
        low, high = ROOM_BAND_C
        how = "heat" if temp_c > high else "cool" if temp_c < low else "settle"
        out.append(phrase(f"step.thermal.{how}", temp_c=_num(temp_c)))
        if supply_v is not None:
            out.append(phrase("cond.supply", supply_v=_num(supply_v)))
        return out
    if step not in ("other", "starting") and _has_words(f"step.{step}"):
        out.append(phrase(f"step.{step}"))
    elif step:
        out.append(phrase("step.other", name=step.replace("_", " ")))
    else:
        out.append(phrase("step.starting"))
    if temp_c is not None and supply_v is not None:
        out.append(phrase("cond.both", temp_c=_num(temp_c), supply_v=_num(supply_v)))
    elif temp_c is not None:
        out.append(phrase("cond.temp", temp_c=_num(temp_c)))
    elif supply_v is not None:
        out.append(phrase("cond.supply", supply_v=_num(supply_v)))
    elif condition.strip():
        out.append(phrase("cond.other", name=condition.strip()))
    return out


def measurement_phrase(name: str) -> Phrase:
    if _has_words(f"measure.{name}"):
        return phrase(f"measure.{name}")
    return phrase("measure.other", name=name.replace("_", " "))


def failure_phrase(failed: dict[str, Any]) -> Phrase:
    """Why one measurement failed: "Bias too high: 14.2 deg/s, limit +/-10 deg/s"."""
    what = measurement_phrase(str(failed.get("name", "")))
    units = _units(failed.get("units"))
    value, low, high = (_finite(failed.get(k)) for k in ("value", "low", "high"))
    limit = limit_phrase(low, high, units)
    if value is None:
        return phrase("fail.not_measured", what=what, limit=limit)
    shown = phrase("value", value=_num(value, sig=3), units=units)
    if high is not None and value > high:
        return phrase("fail.too_high", what=what, value=shown, limit=limit)
    if low is not None and value < low:
        return phrase("fail.too_low", what=what, value=shown, limit=limit)
    return phrase("fail.out_of_limits", what=what, value=shown, limit=limit)


def limit_phrase(low: float | None, high: float | None, units: str) -> Phrase:
    if low is not None and high is not None:
        if math.isclose(low, -high) and high > 0:
            return phrase("limit.symmetric", high=_num(high), units=units)
        return phrase("limit.range", low=_num(low), high=_num(high), units=units)
    if high is not None:
        return phrase("limit.max", high=_num(high), units=units)
    if low is not None:
        return phrase("limit.min", low=_num(low), units=units)
    return phrase("limit.none")


def _units(units: Any) -> str:
    text = str(units or "").strip()
    return "" if text in ("1", "-") else text


def _finite(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def _num(value: float, sig: int | None = None) -> str:
    """A number as an operator reads it: 45, 5.25, 14.2 (sig: significant digits kept)."""
    if sig is not None:
        text = f"{value:#.{sig}g}"
        if "e" not in text:
            return text.rstrip(".")
        return f"{value:.{sig - 1}e}"
    return f"{value:g}"
