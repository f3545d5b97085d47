"""The controller's side of the operator screen: plain words attached to the engine's
events, dispositions, chart time from the run's start, prompts kept for a reload, and START
refused while an instrument the run needs is down."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from station.ui.controller import Controller, RunRefusedError
from station.ui.hub import Hub
from station.ui.runner_adapter import InstrumentLight, StartRequest
from tests.ui.fake_runner import FakeRunner


class Held(FakeRunner):
    """A runner that starts nothing: the test plays the engine through the sink."""

    def start(self, request: StartRequest, sink: Any) -> str:
        self.started.append(request)
        self.sink = sink
        return "held-1"


@pytest.fixture
def held(tmp_path: Path) -> tuple[Controller, Held]:
    runner = Held(tmp_path / "runs")
    return Controller(runner, Hub()), runner


def test_progress_and_steps_get_plain_words(held: tuple[Controller, Held]) -> None:
    controller, runner = held
    controller.start({1: "SIM-0001"}, operator="ana", work_order="WO-1", lot="L-2")
    assert (runner.started[0].work_order, runner.started[0].lot) == ("WO-1", "L-2")
    runner.sink({"type": "steps", "steps": ["connect", "thermal T45_V5.25"]})
    runner.sink({"type": "progress", "step": "thermal T45_V5.25", "step_index": 1,
                 "step_count": 2, "condition": "T45_V5.25", "fraction": 0.5,
                 "remaining_s": 180.0})
    run = controller.snapshot()["run"]
    assert run["work_order"] == "WO-1" and run["lot"] == "L-2"
    assert [w["key"] for w in run["progress"]["words"]] == ["step.thermal.heat", "cond.supply"]
    assert run["progress"]["words"][0]["params"] == {"temp_c": "45"}
    assert run["step_words"][1][0]["key"] == "step.thermal.heat"
    assert run["step_words"][0] == [{"key": "step.connect", "params": {}}]


def test_chart_time_counts_from_the_run_start(held: tuple[Controller, Held]) -> None:
    controller, runner = held
    controller.start({1: "SIM-0001"})
    runner.sink({"type": "samples", "socket": 1, "t_s": [2949.0, 2950.0],
                 "rate_dps": [0.0, 1.0], "temp_c": [25.0, 25.1]})
    runner.sink({"type": "samples", "socket": 1, "t_s": [3891.0],
                 "rate_dps": [2.0], "temp_c": [25.2]})
    runner.sink({"type": "finished", "results": [], "safe_state": None})
    chart = controller.snapshot()["chart"]["1"]["t_s"]
    assert chart[0] == 0.0 and chart[-1] == pytest.approx(942.0)


def test_prompt_kept_for_a_reload_and_cleared(held: tuple[Controller, Held]) -> None:
    controller, runner = held
    controller.start({1: "SIM-0001", 2: "SIM-0002"})
    runner.sink({"type": "prompt", "message": "Turn socket 2's fixture by hand", "sockets": [2]})
    assert controller.snapshot()["run"]["prompt"] == {
        "message": "Turn socket 2's fixture by hand", "sockets": [2]}
    runner.sink({"type": "prompt_done"})
    assert controller.snapshot()["run"]["prompt"] is None


def test_result_gets_disposition_and_failure_words(held: tuple[Controller, Held]) -> None:
    controller, runner = held
    controller.start({1: "BAD-0001"})
    failed = {"name": "raw_bias_dps", "value": 14.2, "units": "deg/s", "low": -10.0,
              "high": 10.0, "condition": "T25_V5"}
    runner.sink({"type": "finished", "safe_state": None, "results": [
        {"socket": 1, "serial": "BAD-0001", "verdict": "FAIL", "reason": "", "failed": [failed],
         "run_folder": None}]})
    result = controller.snapshot()["last"]["results"][0]
    assert result["disposition"] == "Red bin: do not ship"
    assert result["failed"][0]["words"]["key"] == "fail.too_high"
    assert result["failed"][0]["name"] == "raw_bias_dps"  # the engineering name stays


def test_start_refused_while_an_instrument_is_down(held: tuple[Controller, Held]) -> None:
    controller, runner = held
    runner.lights[2] = InstrumentLight("supply", False, None, False, detail="no answer")
    controller.refresh_instruments()
    with pytest.raises(RunRefusedError, match="supply is not reachable"):
        controller.start({1: "SIM-0001"})
    assert runner.started == []
    runner.lights[2] = InstrumentLight("supply", True, None, True, detail="output fault")
    controller.refresh_instruments()
    with pytest.raises(RunRefusedError, match="supply reports output fault"):
        controller.start({1: "SIM-0001"})
    # a light that came back since the last probe: Start looks again and goes ahead
    runner.lights[2] = InstrumentLight("supply", True, None, False)
    assert controller.start({1: "SIM-0001"}) == "held-1"


def test_a_fixture_down_matters_only_for_its_socket(held: tuple[Controller, Held]) -> None:
    controller, runner = held
    runner.lights.append(InstrumentLight("fixture 2", False, None, False, socket=2))
    controller.refresh_instruments()
    with pytest.raises(RunRefusedError, match="fixture 2 is not reachable"):
        controller.start({1: "SIM-0001", 2: "SIM-0002"})
    assert controller.start({1: "SIM-0001", 2: ""}) == "held-1"
