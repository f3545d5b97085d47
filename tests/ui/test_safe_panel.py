"""The operator screen's safe panel reads the station's own safe-state readback (the run's
report), never the simulator's control channel."""

from __future__ import annotations

from typing import Any

from station.ui.runner_adapter import station_safe_state


class FakeUut:
    def __init__(self, state: dict[str, Any]) -> None:
        self._state = state

    def state(self) -> dict[str, Any]:
        return self._state


def test_unsafe_instrument_is_named_with_its_reason() -> None:
    report = {
        "all_safe": False,
        "instruments": {
            "rate_table": {"safe": False, "detail": "rate -50.000 deg/s, enabled"},
            "supply": {"safe": True, "detail": "output off"},
            "chamber": {"safe": True, "detail": "setpoint 25 C"},
        },
    }
    panel = station_safe_state(FakeUut({"state": "finished", "safe_state": report}))
    assert panel is not None
    assert panel["all"] is False and panel["rate_table"] is False and panel["supply"] is True
    assert panel["unsafe"] == ["rate table: rate -50.000 deg/s, enabled"]


def test_all_safe_and_no_report() -> None:
    report = {"all_safe": True, "instruments": {"supply": {"safe": True, "detail": "off"}}}
    assert station_safe_state(FakeUut({"safe_state": report})) == {
        "all": True, "supply": True, "unsafe": [],
    }
    assert station_safe_state(FakeUut({"state": "idle"})) is None
