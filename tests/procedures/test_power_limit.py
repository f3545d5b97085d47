"""The supply current limit at power-on covers every part that may draw current."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from procedures.steps.power import UNASKED_SOCKETS, PowerIdentify


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


def _ctx(n_parts: int, unasked: int) -> Any:
    parts = [SimpleNamespace(extra={UNASKED_SOCKETS: unasked}) for _ in range(n_parts)]
    return SimpleNamespace(
        bench=SimpleNamespace(supply=FakeSupply()),
        product=SimpleNamespace(current_limit_a=0.01),
        procedure=SimpleNamespace(power=SimpleNamespace(settle_s=0.0)),
        parts=parts,
        alive=lambda: parts,
        sleep=lambda s: None,
    )


def test_limit_is_sized_by_scanned_parts() -> None:
    ctx = _ctx(2, 0)
    PowerIdentify().setup(ctx)
    assert abs(ctx.bench.supply.limit_a - 0.02) < 1e-12


def test_limit_allows_for_sockets_that_could_not_be_asked() -> None:
    ctx = _ctx(2, 1)
    PowerIdentify().setup(ctx)
    assert abs(ctx.bench.supply.limit_a - 0.03) < 1e-12
