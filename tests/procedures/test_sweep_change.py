"""measure_plateau's `sleep_through_change` (the ramp's): the station sleeps for the rate
change the acceleration allows, less a margin, before it polls the table; without it (the
rate_table step) it polls at once. Fakes for the table and the clock: what is checked is the
order and length of the waits, not the physics."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from procedures.steps.sweep import CHANGE_MARGIN_S, measure_plateau


class Table:
    def __init__(self, events: list[tuple[str, float]], rate_dps: float) -> None:
        self.events, self.rate_dps = events, rate_dps

    def read_status(self) -> Any:
        self.events.append(("status", self.rate_dps))
        return SimpleNamespace(rate_dps=self.rate_dps)

    def set_rate(self, rate: float, accel: float) -> None:
        self.events.append(("set_rate", rate))
        self.rate_dps = rate

    def wait_at_rate(self, timeout_s: float) -> None:
        self.events.append(("wait_at_rate", timeout_s))

    def counts_per_rev(self) -> float:
        return 3_600_000.0


def _ctx(events: list[tuple[str, float]], table: Table) -> Any:
    clock = {"t": 0.0}

    def sleep(s: float) -> None:
        events.append(("sleep", s))
        clock["t"] += s

    def snapshot() -> tuple[float, Any]:
        t = clock["t"]
        counts = int(round(table.rate_dps * t * 10_000))  # 10,000 counts per degree
        return t, SimpleNamespace(encoder_counts_unwrapped=counts, encoder_counts=counts,
                                  controller_time_s=t, controller_time_resolution_s=1e-3)

    return SimpleNamespace(
        instruments=SimpleNamespace(need_table=lambda: table, snapshot=snapshot),
        wait=SimpleNamespace(check=lambda: None, sleep=sleep))


@pytest.mark.parametrize(("before", "after", "accel"), [(200.0, -200.0, 200.0),
                                                        (20.0, 50.0, 100.0)])
def test_a_ramp_plateau_sleeps_through_the_change_before_it_polls(
        before: float, after: float, accel: float) -> None:
    events: list[tuple[str, float]] = []
    table = Table(events, before)
    plateau = measure_plateau(_ctx(events, table), after, 6.0, 0.5, accel, 30.0,
                              sleep_through_change=True)
    kinds = [k for k, _ in events]
    assert kinds[:4] == ["status", "set_rate", "sleep", "wait_at_rate"], events
    assert events[0] == ("status", before)
    assert events[2][1] == pytest.approx(abs(after - before) / accel - CHANGE_MARGIN_S)
    assert plateau.ref_dps == pytest.approx(after, rel=1e-3)


def test_the_rate_table_step_polls_at_once() -> None:
    events: list[tuple[str, float]] = []
    table = Table(events, 200.0)
    measure_plateau(_ctx(events, table), -200.0, 6.0, 0.5, 200.0, 30.0)
    assert [k for k, _ in events][:2] == ["set_rate", "wait_at_rate"], events


def test_a_change_shorter_than_the_margin_is_polled_at_once() -> None:
    events: list[tuple[str, float]] = []
    table = Table(events, 20.0)
    measure_plateau(_ctx(events, table), 20.0 + 0.5 * CHANGE_MARGIN_S * 200.0, 6.0, 0.5,
                    200.0, 30.0, sleep_through_change=True)
    assert [k for k, _ in events][:3] == ["status", "set_rate", "wait_at_rate"], events
