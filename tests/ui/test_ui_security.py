"""The browser station against hostile clients: sessions, CSRF, Host, lockout, headers, HTTPS.

In-process (Starlette's TestClient over the real app and the fake runner): each test builds
the station it needs. What a web page of another site can send is sent here as it would be
(Origin header, no session, no token, a rebinding Host).
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from starlette.testclient import TestClient

from station.ui.app import create_app
from station.ui.auth import Operator, OperatorBook, hash_badge, hash_pin
from station.ui.controller import Controller
from station.ui.guard import allowed_hosts
from station.ui.history import History
from station.ui.hub import Hub
from station.ui.requests import Security
from station.ui.server import Tls, serve_in_thread
from tests.tools import need
from tests.ui.conftest import _HASH, ENGINEER_PASSWORD
from tests.ui.fake_runner import FakeRunner

BASE = "http://127.0.0.1:8080"
ANA_PIN, ANA_BADGE = "4711", "0004455667"
OPERATORS = OperatorBook(
    (
        Operator("Ana Silva", hash_pin(ANA_PIN), hash_badge(ANA_BADGE)),
        Operator("Bo", hash_pin("9999")),
    )
)


class Station:
    def __init__(self, tmp: Path, **security: object) -> None:
        self.runner = FakeRunner(tmp / "runs", step_s=0.02)
        self.controller = Controller(self.runner, Hub())
        sec = Security(engineer_password_hash=_HASH, **security)  # type: ignore[arg-type]
        self.app = create_app(self.controller, History(tmp / "runs"), security=sec)

    def client(self, *, session: bool = True, address: str = "10.0.0.7") -> TestClient:
        """A client of its own (cookie jar); with `session` it has opened one and holds the
        CSRF token as the page does."""
        client = TestClient(self.app, base_url=BASE, client=(address, 50000))
        if session:
            r = client.get("/api/session")
            assert r.status_code == 200, r.text
            client.headers["X-CSRF-Token"] = r.json()["csrf"]
        return client


@pytest.fixture
def station(tmp_path: Path) -> Iterator[Station]:
    s = Station(tmp_path)
    yield s
    s.runner.close()


@pytest.fixture
def signed(tmp_path: Path) -> Iterator[Station]:
    """A station whose operators sign in by badge or name and PIN, sign-in required."""
    s = Station(tmp_path, operators=OPERATORS, require_operator=True)
    yield s
    s.runner.close()


def _renew(client: TestClient, r: httpx.Response) -> httpx.Response:
    if r.status_code == 200:
        client.headers["X-CSRF-Token"] = r.json()["csrf"]
    return r


START = {"serials": {"1": "SIM-0001"}}


# ---------------------------------------------------------------- must-show


def test_cross_origin_post_is_refused(station: Station) -> None:
    client = station.client()
    # A page of another site posting to the station (the browser adds its Origin).
    for origin in ("http://evil.example", "null", "http://127.0.0.1:9999"):
        r = client.post("/api/abort", json={}, headers={"Origin": origin})
        assert r.status_code == 403 and "another site" in r.json()["error"], origin
        r = client.post("/api/start", json=START, headers={"Origin": origin})
        assert r.status_code == 403
    r = client.post("/api/start", json=START, headers={"Referer": "http://evil.example/x"})
    assert r.status_code == 403 and "another site" in r.json()["error"]
    # The classic cross-site form post: no token, form-encoded, foreign Origin.
    r = TestClient(station.app, base_url=BASE).post(
        "/api/abort", data={"x": "1"}, headers={"Origin": "http://evil.example"}
    )
    assert r.status_code == 403
    assert station.runner.started == []
    # The station's own page (same origin) is accepted.
    r = client.post("/api/start", json=START, headers={"Origin": BASE})
    assert r.status_code == 200, r.text
    station.runner.wait()


@pytest.mark.parametrize("host", ["evil.example", "evil.example:8080", "192.168.1.50", "[::2]"])
def test_foreign_host_header_is_refused(station: Station, host: str) -> None:
    client = TestClient(station.app, base_url=BASE)
    for method, path in (("GET", "/"), ("GET", "/api/state"), ("GET", "/api/session")):
        r = client.request(method, path, headers={"Host": host})
        assert r.status_code == 421, (path, r.status_code)
        assert "host name" in r.json()["error"] and "set-cookie" not in r.headers
    ok = station.client()
    r = ok.post("/api/start", json=START, headers={"Host": host})
    assert r.status_code == 421 and station.runner.started == []


def test_allowed_hosts_and_loopback_names_are_served(tmp_path: Path) -> None:
    s = Station(tmp_path, hosts=allowed_hosts("0.0.0.0", ["station-7.line.local"]))
    client = TestClient(s.app, base_url=BASE)
    for host in ("127.0.0.1:8080", "localhost:8080", "[::1]:8080", "Station-7.line.local"):
        assert client.get("/api/state", headers={"Host": host}).status_code == 200, host
    assert client.get("/api/state", headers={"Host": "0.0.0.0:8080"}).status_code == 421


def test_unauthenticated_start_is_refused(station: Station, signed: Station) -> None:
    bare = station.client(session=False)
    r = bare.post("/api/start", json=START)
    assert r.status_code == 401 and "no session" in r.json()["error"]
    r = bare.post("/api/start", json=START, headers={"X-CSRF-Token": "guess"})
    assert r.status_code == 401
    forged = TestClient(station.app, base_url=BASE, cookies={"station_session": "forged"})
    assert forged.post("/api/start", json=START, headers={"X-CSRF-Token": "x"}).status_code == 401
    for path in ("/api/abort", "/api/validate", "/api/select", "/api/login", "/api/signin"):
        assert bare.post(path, json={}).status_code == 401, path
    assert station.runner.started == []
    # With sign-in required a session is not enough: an operator must have signed in.
    client = signed.client()
    r = client.post("/api/start", json=START)
    assert r.status_code == 401 and "sign in" in r.json()["error"]
    assert signed.runner.started == []


def test_one_clients_failed_logins_do_not_lock_out_another(signed: Station) -> None:
    attacker, operator = signed.client(), signed.client()
    codes = [
        attacker.post("/api/signin", json={"name": "Ana Silva", "pin": f"{i:04d}"}).status_code
        for i in range(5)
    ]
    assert codes[:3] == [401, 401, 401] and 429 in codes  # locked after the free tries
    r = attacker.post("/api/signin", json={"name": "Ana Silva", "pin": ANA_PIN})
    assert r.status_code == 429 and "try again in" in r.json()["error"]  # even the right PIN
    # The operator's screen, same address, is not locked out.
    r = _renew(operator, operator.post("/api/signin", json={"name": "Ana Silva", "pin": ANA_PIN}))
    assert r.status_code == 200 and r.json()["operator"] == "Ana Silva"
    # The engineer password is throttled the same way, per client.
    eng_attacker, engineer = signed.client(), signed.client()
    for _ in range(4):
        eng_attacker.post("/api/login", json={"password": "guess-guess"})
    assert eng_attacker.post("/api/login", json={"password": ENGINEER_PASSWORD}).status_code == 429
    assert engineer.post("/api/login", json={"password": ENGINEER_PASSWORD}).status_code == 200


def test_a_client_that_drops_its_session_to_retry_is_stopped(signed: Station) -> None:
    keeper = signed.client(address="10.0.0.9")  # the station's own screen, opened before
    throttle = signed.app.app.state.throttle
    throttle.address_free = 6
    for _ in range(3):  # fresh sessions, 3 free tries each: the address budget runs out
        c = signed.client(address="10.0.0.66")
        for i in range(3):
            c.post("/api/signin", json={"badge": f"99999{i}"})
    fresh = TestClient(signed.app, base_url=BASE, client=("10.0.0.66", 1))
    r = fresh.get("/api/session")  # a session to read and abort with, but no fresh guesses
    assert r.status_code == 200
    fresh.headers["X-CSRF-Token"] = r.json()["csrf"]
    r = fresh.post("/api/signin", json={"badge": ANA_BADGE})
    assert r.status_code == 429 and "too many failed sign-ins" in r.json()["error"]
    r = keeper.post("/api/signin", json={"badge": ANA_BADGE})
    assert r.status_code == 200 and r.json()["operator"] == "Ana Silva"


def test_a_screen_reloaded_during_a_lockout_reads_its_session_and_aborts(
    signed: Station,
) -> None:
    """Finding 9: every loopback client shares one address, so guesses from it must not leave
    the station's own screen, reloaded (no cookie), without a session and unable to ABORT."""
    screen = signed.client(address="127.0.0.1")
    assert _renew(screen, screen.post("/api/signin", json={"badge": ANA_BADGE})).status_code == 200
    signed.runner.step_s = 60.0  # the run lasts until aborted, however slow the guesses are
    assert screen.post("/api/start", json=START).status_code == 200
    signed.app.app.state.throttle.address_free = 3
    for _ in range(3):  # guesses from loopback, each on a fresh session, until the address locks
        guesser = signed.client(address="127.0.0.1")
        for i in range(3):
            guesser.post("/api/signin", json={"badge": f"88888{i}"})
    reloaded = TestClient(signed.app, base_url=BASE, client=("127.0.0.1", 2))
    r = reloaded.get("/api/session")
    assert r.status_code == 200, r.text
    reloaded.headers["X-CSRF-Token"] = r.json()["csrf"]
    assert reloaded.get("/api/session").json()["csrf"] == r.json()["csrf"]  # read again: same
    assert reloaded.post("/api/signin", json={"badge": ANA_BADGE}).status_code == 429
    no_token = reloaded.post("/api/abort", json={}, headers={"X-CSRF-Token": "x"})
    assert no_token.status_code == 403  # CSRF rules still apply
    assert reloaded.post("/api/abort", json={}).status_code == 200
    signed.runner.wait()
    folders = list((signed.runner.out_dir).glob("*/record.json"))
    assert folders and all('"ABORTED"' in f.read_text() for f in folders)


def test_csrf_token_missing_or_wrong_is_refused(station: Station) -> None:
    client = station.client()
    token = client.headers.pop("X-CSRF-Token")
    r = client.post("/api/start", json=START)
    assert r.status_code == 403 and "X-CSRF-Token" in r.json()["error"]
    wrong = token[:-1] + ("B" if token.endswith("A") else "A")  # always differs from token
    r = client.post("/api/start", json=START, headers={"X-CSRF-Token": wrong})
    assert r.status_code == 403
    other = station.client()  # another session's token is not this session's
    foreign_token = other.headers["X-CSRF-Token"]
    r = client.post("/api/start", json=START, headers={"X-CSRF-Token": foreign_token})
    assert r.status_code == 403 and station.runner.started == []
    assert client.post("/api/start", json=START, headers={"X-CSRF-Token": token}).status_code == 200
    station.runner.wait()


def test_sign_in_by_badge_or_pin_and_the_operator_is_recorded(signed: Station) -> None:
    client = signed.client()
    assert client.post("/api/signin", json={"badge": "123456"}).status_code == 401
    assert client.post("/api/signin", json={"name": "Ana Silva"}).status_code == 422  # no PIN
    old_token = client.headers["X-CSRF-Token"]
    r = _renew(client, client.post("/api/signin", json={"badge": ANA_BADGE}))
    assert r.status_code == 200 and r.json()["operator"] == "Ana Silva"
    assert r.json()["csrf"] != old_token  # new tokens after sign-in
    cookie = r.headers["set-cookie"].lower()
    assert "httponly" in cookie and "samesite=strict" in cookie
    r = client.post("/api/start", json=START)
    assert r.status_code == 200 and r.json()["operator"] == "Ana Silva"
    signed.runner.wait()
    assert signed.runner.started[-1].operator == "Ana Silva"
    record = next((signed.runner.out_dir).glob("*/record.json")).read_text()
    assert '"operator": "Ana Silva"' in record or '"operator":"Ana Silva"' in record
    # Signing out: the next start is refused again.
    _renew(client, client.post("/api/signout", json={}))
    assert client.post("/api/start", json=START).status_code == 401
    bo = signed.client()
    r = _renew(bo, bo.post("/api/signin", json={"name": " bo ", "pin": "9999"}))
    assert r.status_code == 200 and r.json()["operator"] == "Bo"


def test_open_station_signs_in_by_name_and_abort_needs_only_a_session(station: Station) -> None:
    client = station.client()
    r = _renew(client, client.post("/api/signin", json={"name": "ana"}))
    assert r.status_code == 200 and r.json()["operator"] == "ana"
    assert client.post("/api/signin", json={"badge": "1234"}).status_code == 422
    assert client.post("/api/start", json=START).json()["operator"] == "ana"
    assert station.client().post("/api/abort", json={}).status_code in (200, 409)
    station.runner.wait()
    assert station.runner.started[-1].operator == "ana"


def test_security_headers_on_every_response(station: Station) -> None:
    client = station.client()
    responses = [
        client.get("/"),
        client.get("/review"),
        client.get("/static/operator.js"),
        client.get("/static/nope.js"),
        client.get("/api/state"),
        client.get("/api/session"),
        client.get("/api/runs", params={"verdict": "MAYBE"}),
        client.get("/runs/nope/certificate.pdf"),
        client.post("/api/start", json={"serials": "x"}),
        client.post("/api/start", json=START, headers={"Origin": "http://evil.example"}),
        client.get("/api/state", headers={"Host": "evil.example"}),
        client.post("/api/start", content=b"x" * 70_000),
        client.put("/api/start", json=START),
    ]
    for r in responses:
        where = f"{r.request.method} {r.request.url.path} -> {r.status_code}"
        assert r.headers.get("x-content-type-options") == "nosniff", where
        assert r.headers.get("x-frame-options") == "DENY", where
        assert "frame-ancestors 'none'" in r.headers.get("content-security-policy", ""), where
    assert responses[-2].status_code == 413
    station.runner.wait()


def test_state_never_publishes_the_bench_control_endpoint(tmp_path: Path) -> None:
    from station.ui.runner_adapter import EngineRunner, StationInfo

    assert not any("control" in f for f in StationInfo.__dataclass_fields__)

    class Control:
        endpoint = "127.0.0.1:47123"

    settings = __import__("station.station_file", fromlist=["load_settings"]).load_settings()
    runner = EngineRunner(settings, out=tmp_path, control=Control())
    assert "47123" not in repr(runner.info)


# ---------------------------------------------------------------- HTTPS beyond loopback


def _self_signed(folder: Path) -> Tls:
    need("openssl")
    cert, key = folder / "cert.pem", folder / "key.pem"
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
         "-subj", "/CN=127.0.0.1", "-keyout", str(key), "-out", str(cert)],
        check=True, capture_output=True, timeout=60,
    )  # fmt: skip
    return Tls(cert, key)


def test_https_serves_with_a_secure_cookie(tmp_path: Path) -> None:
    tls = _self_signed(tmp_path)
    s = Station(tmp_path, https=True)
    server = serve_in_thread(s.app, tls=tls, before_stop=s.controller.hub.close)
    try:
        assert server.url.startswith("https://")
        with httpx.Client(base_url=server.url, verify=False, timeout=10) as client:
            r = client.get("/api/session")
            assert r.status_code == 200 and "secure" in r.headers["set-cookie"].lower()
            client.headers["X-CSRF-Token"] = r.json()["csrf"]
            r = client.post("/api/start", json=START, headers={"Origin": server.url})
            assert r.status_code == 200, r.text
            # A same-looking page over plain http is another origin.
            http_origin = server.url.replace("https://", "http://")
            r = client.post("/api/abort", json={}, headers={"Origin": http_origin})
            assert r.status_code == 403
        s.runner.wait()
    finally:
        s.runner.close()
        server.stop()


def _station_yaml(folder: Path, ui: dict[str, object]) -> Path:
    import yaml

    from tests.ui.stationkit import REPO

    data = yaml.safe_load((REPO / "config" / "station.yaml").read_text(encoding="utf-8"))
    data["procedure"] = str(REPO / "config" / "procedures" / "eol-rate-table.yaml")
    data["output_folder"] = str(folder / "runs")
    data["results_db"] = str(folder / "runs" / "results.sqlite")
    data["ui"] = ui
    path = folder / "station.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def test_security_settings_from_station_yaml(tmp_path: Path) -> None:
    from station.errors import UserError
    from station.station_file import load_settings
    from station.ui.launch import security_of

    plain = load_settings(_station_yaml(tmp_path, {}))
    with pytest.raises(UserError, match="refusing to listen on 0.0.0.0 without HTTPS"):
        security_of(plain, "0.0.0.0")
    sec, tls = security_of(plain, "127.0.0.1")
    assert tls is None and not sec.https and sec.operators.open
    certs = _self_signed(tmp_path)
    ui = {
        "tls_certificate": str(certs.certificate),
        "tls_key": str(certs.key),
        "allowed_hosts": ["Station-7.line.local"],
        "require_operator": True,
        "operators": [{"name": "Ana", "pin_hash": hash_pin("4711")}],
    }
    sec, tls = security_of(load_settings(_station_yaml(tmp_path, ui)), "10.1.2.3")
    assert tls == certs and sec.https and sec.require_operator
    assert {"10.1.2.3", "station-7.line.local", "localhost"} <= sec.hosts
    bad = dict(ui, tls_key=str(certs.certificate))  # not the key of that certificate
    with pytest.raises(UserError, match="cannot be used"):
        security_of(load_settings(_station_yaml(tmp_path, bad)), "10.1.2.3")
    damaged = dict(ui, operators=[{"name": "Ana", "pin_hash": "4711"}])
    with pytest.raises(UserError, match="station ui --hash-pin"):
        security_of(load_settings(_station_yaml(tmp_path, damaged)), "127.0.0.1")


@pytest.mark.parametrize(
    ("ui", "message"),
    [
        ({"require_operator": True}, "require_operator needs"),
        ({"operators": [{"name": "Ana"}]}, "neither pin_hash nor badge_hash"),
        ({"tls_certificate": "c.pem"}, "go together"),
        ({"allowed_hosts": ["evil/..", "x"]}, "not a host name"),
        ({"operators": [{"name": "A\u0000", "pin_hash": "x"}]}, "name"),
        ({"pin": "1234"}, "pin"),
    ],
)
def test_bad_ui_settings_are_one_clear_error(tmp_path: Path, ui: dict, message: str) -> None:
    from common.yaml_input import ConfigError
    from station.station_file import load_settings

    with pytest.raises(ConfigError, match=message):
        load_settings(_station_yaml(tmp_path, ui))


def test_cli_refuses_to_listen_beyond_loopback_without_https(tmp_path: Path) -> None:
    import os
    import sys

    from tests.ui.stationkit import REPO

    path = _station_yaml(tmp_path, {})
    out = subprocess.run(
        [sys.executable, "-m", "station", "ui", "--station", str(path), "--host", "0.0.0.0"],
        capture_output=True, text=True, timeout=60, cwd=REPO,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
    )  # fmt: skip
    assert out.returncode == 2
    assert "without HTTPS" in out.stderr and "ui.tls_certificate" in out.stderr
    assert "Traceback" not in out.stderr
