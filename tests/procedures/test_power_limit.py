"""The supply current limit at power-on covers every part that may draw current."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from procedures.steps.power import PowerIdentify, PowerSettings

STEP = PowerIdentify(PowerSettings(settle_s=0.0, supply_v=5.0))


class FakeSupply:
    def __init__(self) -> None:
        self.limit_a: float | None = None

    def output(self, on: bool) -> None:
        pass

    def set_current_limit(self, amps: float) -> None:
        self.limit_a = amps

    def set_voltage(self, volts: float) -> None:
        pass

    def check_errors(self) -> None:
        pass


class _Parts(list[Any]):
    def alive(self) -> list[Any]:
        return list(self)


def _ctx(n_parts: int, unasked: int) -> Any:
    # PartRun.unasked_sockets, a typed field since PartRun.extra went (issue 27)
    parts = [SimpleNamespace(unasked_sockets=unasked) for _ in range(n_parts)]
    return SimpleNamespace(
        instruments=SimpleNamespace(supply=FakeSupply()),
        product=SimpleNamespace(current_limit_a=0.01),
        parts=_Parts(parts),
        wait=SimpleNamespace(sleep=lambda s: None),
    )


def test_limit_is_sized_by_scanned_parts() -> None:
    ctx = _ctx(2, 0)
    STEP.setup(ctx)
    assert abs(ctx.instruments.supply.limit_a - 0.02) < 1e-12


def test_limit_allows_for_sockets_that_could_not_be_asked() -> None:
    ctx = _ctx(2, 1)
    STEP.setup(ctx)
    assert abs(ctx.instruments.supply.limit_a - 0.03) < 1e-12
