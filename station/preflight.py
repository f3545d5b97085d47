"""Pre-flight: every procedure setting checked against the product and the instruments,
before any run folder exists. One line per problem, each naming the procedure file and line,
the value, the limit and who reports it; the caller refuses the run (exit 2) if any.

A setting the product refuses (a rate beyond the part's range, a supply level outside its
supply range) is found from the files alone, when they are loaded
(`procedures.loading.config.check_procedure_for_product`); a setting an instrument refuses (a
setpoint beyond the chamber's limits, a rate or an acceleration beyond the table's, a voltage
or current beyond the supply's) needs the opened instrument and the capability
(`SetpointLimited`, `RateLimited`, `OutputRanged` or `OutputLimited`); a driver without it is
not checked (and says so in the log). A supply's range is its output's: the model's (an
E36312A's output 1 is 0-6 V, 5 A), narrowed by station.yaml's max_voltage_v / max_current_a.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass

from common.yaml_input import LoadedYaml
from drivers.protocols import (
    OutputLimited,
    OutputRange,
    OutputRanged,
    RateLimited,
    SetpointLimited,
)
from procedures.loading.config import ProcedureConfig, ProductConfig
from procedures.runtime.conditions import Condition
from procedures.runtime.run_parts import Bench
from procedures.thermal.chamber_strategy import steady_die_c

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class _Setting:
    path: tuple[str | int, ...]  # in the procedure file
    value: float
    text: str  # "rate_table.rates_dps" etc.


def _where(loaded: LoadedYaml, path: tuple[str | int, ...]) -> str:
    for n in range(len(path), -1, -1):
        line = loaded.lines.get(path[:n])
        if line is not None:
            return f"{loaded.path}:{line}"
    return str(loaded.path)


def _listed(section: str, key: str, values: list[float]) -> Iterator[_Setting]:
    for i, v in enumerate(values):
        yield _Setting((section, key, i), float(v), f"{section}.{key}")


def _step_values(procedure: ProcedureConfig, key: str, table_only: bool) -> list[_Setting]:
    """Every value of setting `key` in the procedure's step entries (with its place)."""
    out: list[_Setting] = []
    for entry in procedure.entries():
        if table_only and not entry.type.uses_table:
            continue
        value = getattr(entry.settings, key, None)
        if value is None:
            continue
        path = ".".join(map(str, entry.path))
        text = f"{path}.{key} (step {entry.type_name})"
        if isinstance(value, list):
            out += [_Setting((*entry.path, key, i), float(v), text) for i, v in enumerate(value)]
        else:
            out.append(_Setting((*entry.path, key), float(value), text))
    return out


def _rates(procedure: ProcedureConfig) -> list[_Setting]:
    """Every table rate the procedure commands, deg/s."""
    return _step_values(procedure, "rates_dps", table_only=True)


def _accelerations(procedure: ProcedureConfig) -> list[_Setting]:
    return _step_values(procedure, "accel_dps2", table_only=True)


def instrument_problems(
    procedure: ProcedureConfig,
    loaded: LoadedYaml,
    product: ProductConfig,
    bench: Bench,
    n_parts: int,
    names: dict[str, str] | None = None,
) -> list[str]:
    """Settings the opened instruments refuse, as they report their own limits."""
    names = names or {}
    chamber_limits = (
        bench.chamber.setpoint_limits() if isinstance(bench.chamber, SetpointLimited) else None
    )
    return [
        *_chamber(procedure, loaded, bench, names.get("chamber", "the chamber")),
        *part_temperature_problems(procedure, loaded, product, chamber_limits),
        *_table(procedure, loaded, bench, names.get("rate_table", "the rate table")),
        *_supply(procedure, loaded, product, bench, n_parts, names.get("supply", "the supply")),
    ]


def _chamber(procedure: ProcedureConfig, loaded: LoadedYaml, bench: Bench, who: str) -> list[str]:
    if not isinstance(bench.chamber, SetpointLimited):
        log.info("%s reports no setpoint limits: temperatures not checked", who)
        return []
    low, high = bench.chamber.setpoint_limits()
    settings = list(_listed("conditions", "temperatures_c", procedure.conditions.temperatures_c))
    settings.append(
        _Setting(("chamber", "safe_temp_c"), procedure.chamber.safe_temp_c, "chamber.safe_temp_c")
    )
    return [
        f"{_where(loaded, s.path)}: {s.text} {s.value:g} C is outside the setpoint limits "
        f"[{low:g}, {high:g}] C that {who} reports: change the procedure's temperature or "
        "the chamber's limits"
        for s in settings
        if not low <= s.value <= high
    ]


def part_temperature_problems(
    procedure: ProcedureConfig,
    loaded: LoadedYaml,
    product: ProductConfig,
    chamber_limits: tuple[float, float] | None = None,
) -> list[str]:
    """Each planned temperature whose die, at its hottest condition, is predicted beyond the
    product's part temperature range: the setpoint plus the self-heating (the product's C/W
    times the supply times the most current a passing part may draw). Every thermal strategy
    settles there; the fastest one's overshoot is planned inside the same range at run time.
    A setpoint the chamber itself refuses is reported by the chamber's check only."""
    high, low = product.max_part_temperature_c, product.min_part_temperature_c
    if high is None and low is None:
        return []
    current_a = _part_current_a(product)
    out = []
    for i, temp in enumerate(procedure.conditions.temperatures_c):
        if chamber_limits is not None and not chamber_limits[0] <= temp <= chamber_limits[1]:
            continue
        where = _where(loaded, ("conditions", "temperatures_c", i))
        hottest = max(
            (Condition(temp, v) for v in procedure.conditions.supplies_v),
            key=lambda c: c.supply_v,
            default=Condition(temp, product.reference_supply_v),
        )
        die_c = steady_die_c(temp, hottest.supply_v, current_a, product.self_heating_c_per_w)
        if high is not None and die_c > high:
            heating = (
                f"{temp:g} C + {die_c - temp:.1f} C self-heating at {hottest.supply_v:g} V and "
                f"{current_a * 1e3:g} mA"
                if die_c > temp else "the setpoint; the product gives no self_heating_c_per_w"
            )
            out.append(
                f"{where}: condition {hottest.name}: the die is predicted to reach {die_c:.1f} C "
                f"({heating}), above the part's maximum of {high:g} C (the product's "
                "max_part_temperature_c): lower the procedure's temperature"
            )
        elif low is not None and temp < low:  # self-heating only warms it: the air is the floor
            out.append(
                f"{where}: condition {Condition(temp, hottest.supply_v).name}: the die would be "
                f"at {temp:g} C, below the part's minimum of {low:g} C (the product's "
                "min_part_temperature_c): raise the procedure's temperature"
            )
    return out


def _part_current_a(product: ProductConfig) -> float:
    """The most current a part may draw and still pass (its supply_current_a limit), else
    the supply's limit per part: the self-heating is predicted for the hottest good part."""
    limit = product.limits.supply_current_a
    if limit is not None and limit.high is not None:
        return float(limit.high)
    return float(product.current_limit_a)


def _table(procedure: ProcedureConfig, loaded: LoadedYaml, bench: Bench, who: str) -> list[str]:
    if bench.table is None:
        return _no_table(procedure, loaded)
    if not isinstance(bench.table, RateLimited):
        log.info("%s reports no rate limits: rates and accelerations not checked", who)
        return []
    max_rate, max_accel = bench.table.max_rate_dps(), bench.table.max_accel_dps2()
    out = [
        f"{_where(loaded, s.path)}: {s.text} {s.value:g} deg/s is beyond the {max_rate:g} deg/s "
        f"that {who} allows: lower the rate"
        for s in _rates(procedure)
        if abs(s.value) > max_rate
    ]
    out += [
        f"{_where(loaded, s.path)}: {s.text} {s.value:g} deg/s^2 is beyond the {max_accel:g} "
        f"deg/s^2 that {who} allows: lower the acceleration"
        for s in _accelerations(procedure)
        if s.value > max_accel
    ]
    return out


def _supply(
    procedure: ProcedureConfig,
    loaded: LoadedYaml,
    product: ProductConfig,
    bench: Bench,
    n_parts: int,
    who: str,
) -> list[str]:
    """The supply levels and the load's current limit against the range of the output the
    parts hang on (the family's model, the instrument, or station.yaml's limits)."""
    found = _output_range(bench, who)
    if found is None:
        log.info("%s reports no output range: supply levels not checked", who)
        return []
    volts = list(_listed("conditions", "supplies_v", procedure.conditions.supplies_v))
    volts += _step_values(procedure, "supply_v", table_only=False)
    out = [
        f"{_where(loaded, s.path)}: {s.text} {s.value:g} V is beyond {found.output} "
        f"({found.describe()}): change the supply level or the output"
        for s in volts
        if not found.low_v <= s.value <= found.high_v
    ]
    need_a = product.current_limit_a * n_parts
    if need_a > found.max_a:
        out.append(
            f"{loaded.path}: {n_parts} part(s) at the product's current_limit_a "
            f"{product.current_limit_a:g} A need a {need_a:g} A limit, beyond {found.output} "
            f"({found.describe()}): load fewer parts or use an output that gives {need_a:g} A"
        )
    return out


def _output_range(bench: Bench, who: str) -> OutputRange | None:
    supply = bench.supply
    if isinstance(supply, OutputRanged):
        return supply.output_range()
    if isinstance(supply, OutputLimited):
        max_v, max_a = supply.output_limits()
        if max_v is None and max_a is None:
            return None
        inf = float("inf")
        return OutputRange(f"the output of {who}", 0.0, inf if max_v is None else max_v,
                           inf if max_a is None else max_a, "its reported limits")
    return None


def _no_table(procedure: ProcedureConfig, loaded: LoadedYaml) -> list[str]:
    """A station without a rate table refuses a procedure that turns one."""
    if not procedure.needs_table:
        return []
    return [
        f"{loaded.path}: this station has no rate table (no instruments.rate_table in "
        "station.yaml), but the procedure has steps that move one (rate_table, "
        "stop_method, ...): choose a procedure for a hand-turned fixture (manual_stop, e.g. "
        "eol-manual-stop.yaml) or configure the table"
    ]
