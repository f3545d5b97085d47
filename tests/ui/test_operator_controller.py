"""The controller's side of the operator screen: plain words attached to the engine's
events, dispositions, chart time from the run's start, prompts kept for a reload, and START
refused while an instrument the run needs is down."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from station.ui.controller import Controller, RunRefusedError
from station.ui.hub import Hub
from station.ui.instruments import InstrumentLight
from station.ui.runner_adapter import StartRequest
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


# ---------------------------------------------------------------- over the API


def _client(tmp_path: Path, **security: Any) -> Any:
    from starlette.testclient import TestClient

    from station.ui.app import create_app
    from station.ui.history import History
    from station.ui.requests import Security

    runner = FakeRunner(tmp_path / "runs", step_s=0.02)
    app = create_app(Controller(runner, Hub()), History(tmp_path / "runs"),
                     security=Security(**security))
    client = TestClient(app, base_url="http://127.0.0.1:8080")
    return client, runner


def test_messages_in_the_browsers_language_unless_the_station_sets_one(tmp_path: Path) -> None:
    client, _ = _client(tmp_path)
    r = client.get("/api/messages", headers={"Accept-Language": "de-DE,de;q=0.9,en;q=0.8"})
    assert r.json()["language"] == "de" and r.json()["messages"]["btn.abort"] == "ABBRUCH"
    assert client.get("/api/messages?lang=fr-FR,en").json()["language"] == "en"
    fixed, _ = _client(tmp_path / "fixed", language="en")
    r = fixed.get("/api/messages?lang=de-DE")
    assert r.json()["language"] == "en" and r.json()["messages"]["btn.abort"] == "ABORT"


def test_engineer_login_offered_only_with_a_password(tmp_path: Path) -> None:
    from tests.ui.conftest import _HASH

    bare, _ = _client(tmp_path)
    assert bare.get("/api/session").json()["engineer_login"] is False
    with_password, _ = _client(tmp_path / "pw", engineer_password_hash=_HASH)
    assert with_password.get("/api/session").json()["engineer_login"] is True


def test_work_order_and_lot_bounded_and_carried(tmp_path: Path) -> None:
    client, runner = _client(tmp_path)
    client.headers["X-CSRF-Token"] = client.get("/api/session").json()["csrf"]
    long = client.post("/api/start", json={"serials": {"1": "SIM-0001"}, "lot": "L" * 65})
    assert long.status_code == 422 and "lot" in long.json()["error"]
    r = client.post(
        "/api/start",
        json={"serials": {"1": "SIM-0001"}, "work_order": " WO-9 ", "lot": "L-1"},
    )
    assert r.status_code == 200, r.text
    runner.wait()
    assert (runner.started[0].work_order, runner.started[0].lot) == ("WO-9", "L-1")


def test_station_yaml_language_must_have_a_catalog(tmp_path: Path) -> None:
    from pydantic import ValidationError

    from station.errors import UserError
    from station.settings import UiSettings
    from station.station_file import load_settings
    from station.ui.launch import security_of
    from tests.ui.test_ui_security import _station_yaml

    with pytest.raises(ValidationError):
        UiSettings(language="German")
    sec, _ = security_of(load_settings(_station_yaml(tmp_path, {"language": "de"})), "127.0.0.1")
    assert sec.language == "de"
    french = load_settings(_station_yaml(tmp_path, {"language": "fr"}))
    with pytest.raises(UserError, match="ui.language 'fr' has no message catalog"):
        security_of(french, "127.0.0.1")


def test_product_dispositions_from_the_product_file() -> None:
    from pydantic import ValidationError

    from procedures.loading.config import Dispositions, load_product

    repo = Path(__file__).resolve().parents[2]
    product, _ = load_product(repo / "config" / "products" / "gyr130.yaml")
    assert product.dispositions is not None
    assert product.dispositions.FAIL == "Red bin: do not ship"
    with pytest.raises(ValidationError):
        Dispositions.model_validate({"SCRAP": "no such verdict"})


def test_engine_runner_forwards_prompts_and_step_types() -> None:
    """EngineRunner turns the engine's ProgressEvents into the UI's events: the step type
    with each progress event and planned step, and a prompt with its sockets, then its end."""
    from types import SimpleNamespace

    from procedures.loading.config import load_procedure
    from procedures.runtime.progress import ProgressBus, ProgressEvent
    from station.ui.runner_adapter import EngineRunner

    repo = Path(__file__).resolve().parents[2]
    procedure, _ = load_procedure(repo / "config" / "procedures" / "eol-stop-method.yaml")
    bus = ProgressBus()

    def run(serials: dict[int, str]) -> Any:
        bus.publish(ProgressEvent("step", step="thermal", condition="T45_V5.25"))
        bus.publish(ProgressEvent("prompt", message="Turn socket 2's fixture by hand",
                                  sockets={2: "RUNNING"}))
        bus.publish(ProgressEvent("prompt_done"))
        return SimpleNamespace(folders={})

    uut = SimpleNamespace(procedure=procedure, progress=bus, run=run, context=None,
                          state=lambda: {})
    runner = EngineRunner.__new__(EngineRunner)
    runner.endpoints, runner.control, runner.sample_interval_s = None, None, 0.05
    events: list[dict[str, Any]] = []
    runner._run(uut, {2: "SIM-0002"}, events.append)
    steps = next(e for e in events if e["type"] == "steps")
    assert steps["items"][0] == {"step": "connect", "condition": ""}
    assert {"step": "thermal", "condition": "T45_V5.25"} in steps["items"]
    thermal = next(e for e in events if e["type"] == "progress" and e["step_type"] == "thermal")
    assert thermal["condition"] == "T45_V5.25"
    kinds = [e["type"] for e in events]
    assert kinds.index("prompt") < kinds.index("prompt_done") < kinds.index("finished")
    prompt = next(e for e in events if e["type"] == "prompt")
    assert prompt == {"type": "prompt", "message": "Turn socket 2's fixture by hand",
                      "sockets": [2]}
