"""The condition loop: which (temperature, supply) pairs, in which order.

Chamber transitions are the slow part of the procedure (the die lags the air by minutes), so
both supply levels are measured at one temperature before the chamber moves, and the lot
starts at the temperature the chamber is nearest to (the next lot may start where the last
one ended). Within a temperature the supply order alternates, so consecutive temperatures
share a supply level and the supply changes as rarely as possible.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class Condition:
    temperature_c: float
    supply_v: float

    @property
    def name(self) -> str:
        return f"T{self.temperature_c:g}_V{self.supply_v:g}"


def plan_conditions(
    temperatures_c: list[float],
    supplies_v: list[float],
    *,
    order: Literal["min_transitions", "as_listed"] = "min_transitions",
    start_temp_c: float | None = None,
) -> list[Condition]:
    """Every temperature x supply pair once, ordered to minimise chamber transitions."""
    temps = list(dict.fromkeys(temperatures_c))
    supplies = list(dict.fromkeys(supplies_v))
    if order == "min_transitions" and start_temp_c is not None and temps:
        # monotonic sweep starting from the end nearer the chamber's present temperature
        ascending = sorted(temps)
        nearest_low = abs(ascending[0] - start_temp_c) <= abs(ascending[-1] - start_temp_c)
        temps = ascending if nearest_low else ascending[::-1]
    plan: list[Condition] = []
    for i, temp in enumerate(temps):
        row = supplies if i % 2 == 0 else supplies[::-1]
        plan.extend(Condition(temp, v) for v in row)
    return plan


def with_revisit(
    plan: list[Condition], reversal_c: float | None, start_temp_c: float | None = None
) -> list[Condition]:
    """The plan and, with `reversal_c`, one more condition at the last one's supply,
    `reversal_c` from its temperature against the way the plan reached it (below it after
    heating): a bias reached from the other side of the part's hysteresis
    (procedures.analysis.hysteresis), so that the fit measures the part's own."""
    if reversal_c is None or not plan:
        return plan
    last = plan[-1]
    before = [c.temperature_c for c in plan if c.temperature_c != last.temperature_c]
    came_from = before[-1] if before else start_temp_c
    heated = came_from is None or came_from <= last.temperature_c
    temp = last.temperature_c - reversal_c if heated else last.temperature_c + reversal_c
    return [*plan, Condition(temp, last.supply_v)]


def chamber_transitions(plan: list[Condition], start_temp_c: float | None = None) -> int:
    """How many times the chamber setpoint changes along `plan` (including the first move)."""
    count = 0
    last = start_temp_c
    for cond in plan:
        if last is None or cond.temperature_c != last:
            count += 1 if last is not None else 0
            last = cond.temperature_c
    return count
