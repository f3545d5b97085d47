"""The review screen's approval: only a signed-in quality engineer approves; the approval
adds a second signature to the certificate and is recorded and sealed."""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from station.certify import finish_run_folder
from station.station_file import load_settings
from station.ui.app import create_app
from station.ui.auth import Operator, OperatorBook, hash_pin
from station.ui.controller import Controller
from station.ui.history import History
from station.ui.hub import Hub
from station.ui.requests import Security
from tests.reports.synth_run import Part, make_run
from tests.reports.test_signing import station_file
from tests.tools import need
from tests.ui.fake_runner import FakeRunner

BASE = "http://127.0.0.1:8080"
OPERATORS = OperatorBook((Operator("Ana Silva", hash_pin("4711")),
                          Operator("Quinn", hash_pin("8642"), role="quality")))


@pytest.fixture
def review(tmp_path: Path) -> Iterator[tuple[TestClient, Path]]:
    settings = load_settings(station_file(tmp_path / "station"))
    folder, _ = make_run(tmp_path / "runs", Part(serial="SIM-APP-1", seed=5))
    finish_run_folder(folder, settings, certificate=True)
    runner = FakeRunner(tmp_path / "runs", step_s=0.02)
    sec = Security(operators=OPERATORS, settings=settings)
    app = create_app(Controller(runner, Hub()), History(tmp_path / "runs"), security=sec)
    client = TestClient(app, base_url=BASE, client=("127.0.0.1", 50000))
    client.headers["X-CSRF-Token"] = client.get("/api/session").json()["csrf"]
    yield client, folder
    runner.close()


def sign_in(client: TestClient, name: str, pin: str) -> None:
    r = client.post("/api/signin", json={"name": name, "pin": pin})
    assert r.status_code == 200, r.text
    client.headers["X-CSRF-Token"] = r.json()["csrf"]


def test_operator_cannot_approve_quality_can(review: tuple[TestClient, Path]) -> None:
    client, folder = review
    key = folder.name
    assert client.get(f"/api/runs/{key}/integrity").json()["status"] == "intact"
    sign_in(client, "Ana Silva", "4711")
    r = client.post(f"/api/runs/{key}/approve", json={})
    assert r.status_code == 403 and "quality" in r.json()["error"]
    assert not (folder / "approvals.json").exists()
    client.post("/api/signout", json={})
    client.headers["X-CSRF-Token"] = client.get("/api/session").json()["csrf"]
    sign_in(client, "Quinn", "8642")
    r = client.post(f"/api/runs/{key}/approve", json={})
    assert r.status_code == 200, r.text
    state = client.get(f"/api/runs/{key}/integrity").json()
    assert state["status"] == "intact"
    assert [a["by"] for a in state["approvals"]] == ["Quinn"]
    need("pdfsig")
    sig = subprocess.run(["pdfsig", str(folder / "certificate.pdf")], capture_output=True,
                         text=True).stdout
    assert sig.count("Signature is Valid.") == 2


def test_altered_folder_shows_altered_and_cannot_be_approved(
        review: tuple[TestClient, Path]) -> None:
    client, folder = review
    (folder / "record.json").write_text("{}", encoding="utf-8")
    state = client.get(f"/api/runs/{folder.name}/integrity").json()
    assert state["status"] == "altered" and state["altered_files"] == ["record.json"]
    sign_in(client, "Quinn", "8642")
    r = client.post(f"/api/runs/{folder.name}/approve", json={})
    assert r.status_code >= 400 and "cannot be approved" in r.json()["error"]


def test_review_screen_approve_button_in_a_browser(tmp_path: Path, page: object) -> None:
    """The review screen in chromium: the run shows intact; a quality engineer's Approve
    click records the approval, which the row then shows."""
    from playwright.sync_api import Page, expect

    from station.ui.server import serve_in_thread

    assert isinstance(page, Page)
    settings = load_settings(station_file(tmp_path / "station"))
    folder, _ = make_run(tmp_path / "runs", Part(serial="SIM-APP-2", seed=6))
    finish_run_folder(folder, settings, certificate=True)
    runner = FakeRunner(tmp_path / "runs", step_s=0.02)
    controller = Controller(runner, Hub())
    app = create_app(controller, History(tmp_path / "runs"),
                     security=Security(operators=OPERATORS, settings=settings))
    server = serve_in_thread(app, before_stop=controller.hub.close)
    try:
        page.goto(server.url + "/review")
        expect(page.locator(".record-cell .integrity-intact")).to_have_text("intact")
        expect(page.locator("button.approve")).to_have_count(0)  # nobody signed in
        page.evaluate("""async () => {
            const s = await (await fetch('/api/session')).json();
            await fetch('/api/signin', {method: 'POST', headers: {'Content-Type':
              'application/json', 'X-CSRF-Token': s.csrf}, body: JSON.stringify(
              {name: 'Quinn', pin: '8642'})});
        }""")
        page.reload()
        page.click("button.approve")
        expect(page.locator(".record-cell .approval")).to_contain_text("approved by Quinn")
        assert (folder / "approvals.json").is_file()
    finally:
        server.stop()
        runner.close()
