"""Bad bodies at the UI's JSON API: the malformed corpus and hypothesis-generated bodies.

Whatever a client sends (with a valid session and token, so that the body itself is judged),
the answer is a status below 500 and, when refused, one JSON error line: never a traceback,
never a hang, never a run started by a body that is not a valid request.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from starlette.testclient import TestClient

from station.ui.app import create_app
from station.ui.controller import Controller
from station.ui.history import History
from station.ui.hub import Hub
from station.ui.requests import Security
from tests.ui.conftest import _HASH
from tests.ui.fake_runner import FakeRunner

CORPUS = Path(__file__).resolve().parents[1] / "data" / "malformed" / "api"
BASE = "http://127.0.0.1:8080"
ENDPOINTS = ["start", "validate", "signin", "login", "select", "abort", "signout", "logout"]


class _Station:
    def __init__(self, out: Path) -> None:
        self.out = out
        self.runner = FakeRunner(out, step_s=0.01)
        self.controller = Controller(self.runner, Hub())
        self.app = create_app(
            self.controller, History(out), security=Security(engineer_password_hash=_HASH)
        )
        # The real handlers' errors reach the client as a response, not as an exception.
        self.client = TestClient(self.app, base_url=BASE, raise_server_exceptions=False)
        self.client.headers["X-CSRF-Token"] = self.client.get("/api/session").json()["csrf"]

    def post(self, endpoint: str, body: bytes) -> Any:
        r = self.client.post(
            f"/api/{endpoint}", content=body, headers={"Content-Type": "application/json"}
        )
        if r.status_code == 200 and "csrf" in r.json():  # sign-in, logout: new tokens
            self.client.headers["X-CSRF-Token"] = r.json()["csrf"]
        return r


@pytest.fixture(scope="module")
def station(tmp_path_factory: pytest.TempPathFactory) -> Iterator[_Station]:
    s = _Station(tmp_path_factory.mktemp("fuzz") / "runs")
    yield s
    s.runner.close()


def _one_clear_error(r: Any, where: str) -> str:
    assert 400 <= r.status_code < 500, f"{where}: {r.status_code} {r.text[:300]}"
    body = r.json()
    assert set(body) <= {"error", "socket"}, where
    message = body["error"]
    assert isinstance(message, str) and message.strip(), where
    assert "\n" not in message and len(message) < 600, f"{where}: {message!r}"
    assert "Traceback" not in message and "File \"" not in message, where
    return message


def _corpus() -> list[Path]:
    return sorted(CORPUS.glob("*.json"))


def test_the_corpus_covers_every_state_changing_endpoint() -> None:
    files = _corpus()
    assert len(files) >= 20
    assert {f.name.split("__")[0] for f in files} >= {"start", "validate", "signin", "login"}


@pytest.fixture(scope="module")
def corpus_station(tmp_path_factory: pytest.TempPathFactory) -> Iterator[_Station]:
    s = _Station(tmp_path_factory.mktemp("corpus") / "runs")
    yield s
    s.runner.close()


@pytest.mark.parametrize("path", _corpus(), ids=lambda p: p.stem)
def test_malformed_body_is_refused_with_one_error(corpus_station: _Station, path: Path) -> None:
    station = corpus_station
    endpoint = path.name.split("__")[0]
    started_before = len(station.runner.started)
    t0 = time.monotonic()
    r = station.post(endpoint, path.read_bytes())
    assert time.monotonic() - t0 < 5.0
    _one_clear_error(r, path.name)
    assert len(station.runner.started) == started_before  # nothing started
    assert not station.out.exists() or not any(station.out.iterdir())  # nothing written


# ---------------------------------------------------------------- hypothesis

JSON_SCALARS = (
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**70), max_value=2**70)
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=80)
)
JSON = st.recursive(
    JSON_SCALARS,
    lambda children: st.lists(children, max_size=4)
    | st.dictionaries(st.text(max_size=12), children, max_size=4),
    max_leaves=12,
)
SERIALS = st.dictionaries(
    st.one_of(st.integers(-5, 70).map(str), st.text(max_size=6)),
    st.one_of(st.text(max_size=70), st.from_regex(r"[A-Z]{2,4}-[0-9]{4,8}", fullmatch=True), JSON),
    max_size=5,
)
BODIES = {
    "start": st.one_of(JSON, st.fixed_dictionaries({"serials": SERIALS})),
    "validate": st.one_of(
        JSON, st.fixed_dictionaries({"socket": JSON | st.integers(-3, 70), "serial": JSON})
    ),
    "signin": st.one_of(
        JSON,
        st.fixed_dictionaries({}, optional={"badge": JSON, "name": JSON, "pin": JSON}),
    ),
    "login": st.one_of(JSON, st.fixed_dictionaries({"password": JSON})),
    "select": st.one_of(
        JSON, st.fixed_dictionaries({}, optional={"procedure": JSON, "product": JSON})
    ),
}


def _judge(station: _Station, endpoint: str, body: bytes) -> None:
    r = station.post(endpoint, body)
    assert r.status_code < 500, f"{endpoint} {body[:200]!r}: {r.status_code} {r.text[:300]}"
    if r.status_code >= 400:
        _one_clear_error(r, f"{endpoint} {body[:200]!r}")
    station.runner.wait()  # a valid start runs (the fake engine): let it end


@pytest.mark.parametrize("endpoint", sorted(BODIES))
def test_any_json_body_is_answered_without_a_server_error(
    station: _Station, endpoint: str
) -> None:
    @settings(
        max_examples=60,
        deadline=None,
        suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    )
    @given(body=BODIES[endpoint])
    def check(body: Any) -> None:
        _judge(station, endpoint, json.dumps(body).encode())

    check()


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(endpoint=st.sampled_from(ENDPOINTS), body=st.binary(max_size=200))
def test_any_bytes_are_answered_without_a_server_error(
    station: _Station, endpoint: str, body: bytes
) -> None:
    _judge(station, endpoint, body)
