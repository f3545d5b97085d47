"""UI mechanics against the fake runner: API rules, roles, live push, history, certificates."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import httpx
import pytest

from tests.ui.conftest import ENGINEER_PASSWORD, FakeStation
from tests.ui.stationkit import renew_token, station_client

_clients: dict[str, httpx.Client] = {}


def _post(url: str, json: Any = None) -> httpx.Response:
    """POST as the station's page does (session cookie + CSRF token), one session per station."""
    base, _, path = url.partition("/api/")
    if base not in _clients:
        _clients[base] = station_client(base)
    return _clients[base].post("/api/" + path, json=json)


def _wait_idle(station: FakeStation, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while station.controller.busy():
        assert time.monotonic() < deadline, "run did not finish"
        time.sleep(0.02)


def _collect_events(url: str, stop: threading.Event, out: list[dict[str, Any]]) -> None:
    with httpx.Client(timeout=10) as client, client.stream("GET", url + "/api/events") as r:
        for line in r.iter_lines():
            if line.startswith("data: "):
                out.append(json.loads(line[6:]))
            if stop.is_set():
                return


def test_bad_serial_is_refused_with_the_reason(fake_station: FakeStation) -> None:
    r = _post(fake_station.url + "/api/start", json={"serials": {"1": "hello world"}})
    assert r.status_code == 422
    body = r.json()
    assert body["socket"] == 1
    assert "not a GYR-130 serial" in body["error"] and "SIM-0001" in body["error"]
    assert fake_station.runner.started == []  # nothing reached the engine


def test_validate_trims_scanner_whitespace(fake_station: FakeStation) -> None:
    r = _post(fake_station.url + "/api/validate", json={"socket": 2, "serial": " AB-1234\r"})
    assert r.status_code == 200 and r.json()["serial"] == "AB-1234"
    r = _post(fake_station.url + "/api/validate", json={"socket": 9, "serial": "AB-1234"})
    assert r.status_code == 422 and "socket 9 does not exist" in r.json()["error"]


def test_second_start_while_running_is_refused(fake_station: FakeStation) -> None:
    url = fake_station.url
    r1 = _post(url + "/api/start", json={"serials": {"1": "SIM-0001"}})
    assert r1.status_code == 200
    r2 = _post(url + "/api/start", json={"serials": {"1": "SIM-0002"}})
    assert r2.status_code == 409
    assert "already in progress" in r2.json()["error"] and "SIM-0001" in r2.json()["error"]
    assert len(fake_station.runner.started) == 1
    _wait_idle(fake_station)
    r3 = _post(url + "/api/start", json={"serials": {"1": "SIM-0002"}})
    assert r3.status_code == 200  # free again once the first run ended
    _wait_idle(fake_station)


def test_duplicate_serial_in_two_sockets_is_refused(fake_station: FakeStation) -> None:
    r = _post(
        fake_station.url + "/api/start", json={"serials": {"1": "AB-1111", "2": "AB-1111"}}
    )
    assert r.status_code == 409 and "same serial" in r.json()["error"]


def test_events_push_progress_then_verdict_with_certificate(fake_station: FakeStation) -> None:
    url = fake_station.url
    events: list[dict[str, Any]] = []
    stop = threading.Event()
    reader = threading.Thread(target=_collect_events, args=(url, stop, events), daemon=True)
    reader.start()
    deadline = time.monotonic() + 5
    while not events and time.monotonic() < deadline:
        time.sleep(0.01)
    assert events and events[0]["type"] == "snapshot" and events[0]["run"] is None
    r = _post(url + "/api/start", json={"serials": {"1": "SIM-0001", "2": "BAD-0001"}})
    assert r.status_code == 200, r.text
    _wait_idle(fake_station)
    time.sleep(0.2)
    stop.set()
    kinds = [e["type"] for e in events]
    assert "progress" in kinds and "samples" in kinds
    steps = [e["step_index"] for e in events if e["type"] == "progress"]
    assert steps == sorted(steps) and len(set(steps)) >= 3  # progress advanced, in order
    finished = [e for e in events if e["type"] == "finished"]
    assert len(finished) == 1 and kinds.index("finished") > kinds.index("progress")
    results = {r["serial"]: r for r in finished[0]["last"]["results"]}
    assert results["SIM-0001"]["verdict"] == "PASS"
    assert results["BAD-0001"]["verdict"] == "FAIL"
    assert results["BAD-0001"]["failed"][0]["name"] == "raw_bias_dps"
    pdf = httpx.get(url + results["SIM-0001"]["certificate_url"])
    assert pdf.status_code == 200 and pdf.content.startswith(b"%PDF")
    assert pdf.headers["content-type"] == "application/pdf"


def test_snapshot_mid_run_shows_the_run(fake_station: FakeStation) -> None:
    url = fake_station.url
    assert _post(url + "/api/start", json={"serials": {"2": "SIM-0007"}}).status_code == 200
    time.sleep(0.3)
    state = httpx.get(url + "/api/state").json()
    assert state["run"] is not None and state["run"]["serials"] == {"2": "SIM-0007"}
    assert state["run"]["progress"]["step_index"] >= 1
    assert len(state["chart"]["2"]["t_s"]) > 0
    _wait_idle(fake_station)
    state = httpx.get(url + "/api/state").json()
    assert state["run"] is None and state["last"]["results"][0]["serial"] == "SIM-0007"


def test_abort_ends_aborted_after_cleanup(fake_station: FakeStation) -> None:
    url = fake_station.url
    assert _post(url + "/api/abort").status_code == 409  # nothing to abort
    assert _post(url + "/api/start", json={"serials": {"1": "SIM-0003"}}).status_code == 200
    time.sleep(0.2)
    assert _post(url + "/api/abort").status_code == 200
    _wait_idle(fake_station)
    last = httpx.get(url + "/api/state").json()["last"]
    assert last["results"][0]["verdict"] == "ABORTED"
    assert last["safe_state"] == {"all": True, "rate_table": True, "chamber": True, "supply": True}
    assert fake_station.runner.safe_state_calls == 1


def test_operator_cannot_select_engineer_can_after_password(fake_station: FakeStation) -> None:
    url = fake_station.url
    with station_client(url) as client:
        assert client.get("/api/choices").status_code == 403
        r = client.post("/api/select", json={"procedure": "/cfg/short.yaml"})
        assert r.status_code == 403 and "engineer" in r.json()["error"]
        assert client.post("/api/login", json={"password": "wrong-one"}).status_code == 401
        assert client.get("/api/whoami").json()["role"] == "operator"
        ok = renew_token(client, client.post("/api/login", json={"password": ENGINEER_PASSWORD}))
        assert ok.status_code == 200
        assert client.get("/api/whoami").json()["role"] == "engineer"
        choices = client.get("/api/choices").json()
        assert {p["name"] for p in choices["procedures"]} == {"eol-full", "eol-short"}
        r = client.post(
            "/api/select", json={"procedure": "/cfg/short.yaml", "product": "/cfg/gyr200.yaml"}
        )
        assert r.status_code == 200 and r.json()["selection"]["procedure_name"] == "eol-short"
        bad = client.post("/api/select", json={"procedure": "/etc/passwd"})
        assert bad.status_code == 422 and "unknown procedure" in bad.json()["error"]
        renew_token(client, client.post("/api/logout"))
        assert client.get("/api/choices").status_code == 403
    # The new product's pattern now applies to every serial, also server-side.
    r = _post(url + "/api/start", json={"serials": {"1": "SIM-0001"}})
    assert r.status_code == 422 and "GYR-200" in r.json()["error"]
    r = _post(url + "/api/start", json={"serials": {"1": "G2-123456"}})
    assert r.status_code == 200
    assert fake_station.runner.started[-1].procedure_path == "/cfg/short.yaml"
    _wait_idle(fake_station)


def test_review_filters_and_yield(fake_station: FakeStation) -> None:
    url = fake_station.url
    for serials in ({"1": "SIM-0001", "2": "BAD-0002"}, {"1": "SIM-0004"}):
        assert _post(url + "/api/start", json={"serials": serials}).status_code == 200
        _wait_idle(fake_station)
    data = httpx.get(url + "/api/runs").json()
    assert data["summary"]["counts"]["PASS"] == 2 and data["summary"]["counts"]["FAIL"] == 1
    assert data["summary"]["yield"] == pytest.approx(2 / 3)
    fails = httpx.get(url + "/api/runs", params={"verdict": "FAIL"}).json()
    assert [r["serial"] for r in fails["runs"]] == ["BAD-0002"]
    assert fails["runs"][0]["certificate_url"].endswith("/certificate.pdf")
    one = httpx.get(url + "/api/runs", params={"serial": "0004"}).json()
    assert [r["serial"] for r in one["runs"]] == ["SIM-0004"]
    none = httpx.get(url + "/api/runs", params={"until": "2000-01-01"}).json()
    assert none["runs"] == [] and none["summary"]["yield"] is None
    bad_date = httpx.get(url + "/api/runs", params={"since": "yesterday"})
    assert bad_date.status_code == 422 and "YYYY-MM-DD" in bad_date.json()["error"]
    bad = httpx.get(url + "/api/runs", params={"verdict": "MAYBE"})
    assert bad.status_code == 422 and "PASS, FAIL" in bad.json()["error"]


def test_certificate_route_refuses_paths_outside_the_runs(fake_station: FakeStation) -> None:
    for key in ("..", "..%2F..%2Fetc", "nope"):
        r = httpx.get(fake_station.url + f"/runs/{key}/certificate.pdf")
        assert r.status_code == 404


def test_pages_are_small_and_self_hosted(fake_station: FakeStation) -> None:
    for page in ("/", "/review"):
        csp = httpx.get(fake_station.url + page).headers["content-security-policy"]
        assert "default-src 'self'" in csp
    total = 0
    for path in ("/", "/static/style.css", "/static/operator.js", "/static/chart.js"):
        r = httpx.get(fake_station.url + path)
        assert r.status_code == 200
        assert "http://" not in r.text.replace("http://localhost", "") and "https://" not in r.text
        total += len(r.content)
    assert total < 100_000


def test_instrument_lights_follow_the_probe(fake_station: FakeStation) -> None:
    from station.ui.instruments import InstrumentLight

    lights = httpx.get(fake_station.url + "/api/state").json()["instruments"]
    assert [x["faulted"] for x in lights] == [False, False, False]
    assert lights[1]["in_calibration"] is False  # chamber overdue
    fake_station.runner.lights[0] = InstrumentLight(
        "rate table", True, True, True, "2027-06-30", "fault code 2"
    )
    fake_station.controller.refresh_instruments()
    table = httpx.get(fake_station.url + "/api/state").json()["instruments"][0]
    assert table["faulted"] is True and table["detail"] == "fault code 2"


def test_start_refused_by_the_engine_keeps_the_last_verdict(fake_station: FakeStation) -> None:
    url = fake_station.url
    assert _post(url + "/api/start", json={"serials": {"1": "SIM-0008"}}).status_code == 200
    _wait_idle(fake_station)
    r = _post(url + "/api/start", json={"serials": {"1": "NO-0001"}})
    assert r.status_code == 422 and "refused by the engine" in r.json()["error"]
    state = httpx.get(url + "/api/state").json()
    assert state["run"] is None
    assert state["last"]["results"][0]["serial"] == "SIM-0008"
    assert _post(url + "/api/start", json={"serials": {"1": "SIM-0009"}}).status_code == 200
    _wait_idle(fake_station)
