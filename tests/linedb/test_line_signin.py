"""Sign-in and roles on the line dashboard: the operator screen's session, CSRF, Host and
lockout rules, the users file, and HTTPS beyond loopback (station/line/access.py, users.py)."""

from __future__ import annotations

import argparse
import io
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml
from fastapi.testclient import TestClient

from station.cli.line import _line_access
from station.cli.main import main
from station.db.connect import dispose_all
from station.errors import UserError
from station.line.app import create_line_app
from station.line.users import load_line_users
from station.results_db import ResultsDB
from station.ui.auth import hash_password
from station.ui.server import serve_in_thread
from tests.linedb.linekit import (
    LINE_BASE,
    LINE_NAMES,
    LINE_PASSWORDS,
    REPO,
    line_app,
    line_client,
    line_runs,
)

DATA = ["/api/stations", "/api/yields", "/api/chart", "/api/runs", "/api/capability"]
UNKNOWN = "/api/no-such-thing"  # 401 signed out, 404 signed in
# what each role may read; the rest it is refused (403)
ALLOWED = {
    "viewer": {"/api/stations", "/api/yields", "/api/chart", "/api/runs"},
    "quality": {*DATA, "/certificate/{run}"},
    "engineer": {*DATA, "/certificate/{run}", "/api/runs?simulated=include"},
}
EVERY = sorted(set().union(*ALLOWED.values()))
SIGNED_OUT = [*EVERY, UNKNOWN]


@pytest.fixture(scope="module")
def line(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Any, str]]:
    folder = tmp_path_factory.mktemp("signin")
    runs = line_runs(8, ["EOL-A"], root=folder / "runs")
    db = ResultsDB(folder / "line.sqlite")
    db.add_records([(r.folder, r.record) for r in runs])
    first = runs[0]
    first.folder.mkdir(parents=True)
    (first.folder / "certificate.pdf").write_bytes(b"%PDF-1.4 test\n")
    yield line_app(db.engine), first.record.run_id
    dispose_all()


def _path(template: str, run: str) -> str:
    return template.replace("{run}", run)


def test_page_is_public_and_shows_the_sign_in_form(line: tuple[Any, str]) -> None:
    r = TestClient(line[0], base_url=LINE_BASE).get("/")
    assert r.status_code == 200 and 'id="signin"' in r.text and 'id="dashboard" hidden' in r.text


@pytest.mark.parametrize("path", SIGNED_OUT)
@pytest.mark.parametrize("session", [False, True], ids=["no-cookie", "not-signed-in"])
def test_signed_out_everything_is_refused(line: tuple[Any, str], path: str, session: bool) -> None:
    app, run = line
    client = line_client(app, None) if session else TestClient(app, base_url=LINE_BASE)
    r = client.get(_path(path, run))
    assert r.status_code == 401 and "sign in" in r.json()["error"]


@pytest.mark.parametrize("role", list(ALLOWED))
def test_each_role_reads_its_panels_and_is_refused_the_rest(line: tuple[Any, str],
                                                            role: str) -> None:
    app, run = line
    client = line_client(app, role)
    for path in EVERY:
        r = client.get(_path(path, run))
        if path in ALLOWED[role]:
            assert r.status_code == 200, (role, path, r.text)
        else:
            assert r.status_code == 403, (role, path, r.text)
            assert f"{role} is signed in" in r.json()["error"]
    assert client.get(_path("/certificate/{run}", run)).status_code == (
        403 if role == "viewer" else 200)
    assert client.get(UNKNOWN).status_code == 404


def test_session_and_cookie_rules(line: tuple[Any, str]) -> None:
    app, _ = line
    client = TestClient(app, base_url=LINE_BASE)
    r = client.get("/api/session")
    cookie = r.headers["set-cookie"].lower()
    assert r.json()["role"] == "" and "line_session=" in cookie
    assert "httponly" in cookie and "samesite=strict" in cookie and "secure" not in cookie
    before = client.cookies["line_session"]
    creds = {"name": LINE_NAMES["quality"], "password": LINE_PASSWORDS["quality"]}
    assert client.post("/api/signin", json=creds).status_code == 403  # no CSRF token
    client.headers["X-CSRF-Token"] = r.json()["csrf"]
    refused = client.post("/api/signin", json=creds, headers={"Origin": "http://evil.example"})
    assert refused.status_code == 403 and "another site" in refused.json()["error"]
    r = client.post("/api/signin", json=creds)
    assert r.status_code == 200 and r.json()["role"] == "quality"
    assert client.cookies["line_session"] != before  # new tokens: the old cookie is worth nothing
    stale = TestClient(app, base_url=LINE_BASE, cookies={"line_session": before})
    assert stale.get("/api/yields").status_code == 401
    client.headers["X-CSRF-Token"] = r.json()["csrf"]
    assert client.get("/api/capability").status_code == 200
    assert client.post("/api/signout").status_code == 200
    assert client.get("/api/yields").status_code == 401


def test_no_cross_origin_reads_and_host_checked(line: tuple[Any, str]) -> None:
    app, _ = line
    client = line_client(app, "engineer")
    r = client.get("/api/yields", headers={"Origin": "http://evil.example"})
    assert r.status_code == 200 and "access-control-allow-origin" not in r.headers
    rebound = client.get("/api/yields", headers={"Host": "evil.example"})
    assert rebound.status_code == 421 and "host name" in rebound.json()["error"]


def test_failed_sign_ins_lock_the_client_out(tmp_path: Path) -> None:
    app = line_app(ResultsDB(tmp_path / "l.sqlite").engine)
    client = line_client(app, None)
    wrong = {"name": LINE_NAMES["engineer"], "password": "not-it"}
    statuses = [client.post("/api/signin", json=wrong).status_code for _ in range(4)]
    assert statuses == [401, 401, 401, 401]
    right = {"name": LINE_NAMES["engineer"], "password": LINE_PASSWORDS["engineer"]}
    r = client.post("/api/signin", json=right)
    assert r.status_code == 429 and "too many failed sign-ins" in r.json()["error"]
    assert client.get("/api/yields").status_code == 401
    other = line_client(app, "engineer")  # another client is not locked out by this one
    assert other.get("/api/yields").status_code == 200
    dispose_all()


# --------------------------------------------------------------------------- users file


def _users_file(folder: Path, users: list[dict[str, str]]) -> Path:
    path = folder / "line-users.yaml"
    path.write_text(yaml.safe_dump({"users": users}), encoding="utf-8")
    return path


def test_users_file_loads_and_checks_passwords(tmp_path: Path) -> None:
    stored = hash_password("shift-lead-1", n=2**8)
    users = load_line_users(_users_file(tmp_path, [
        {"name": "Ana Silva", "role": "quality", "password_hash": stored}]))
    ana = users.check("ana silva", "shift-lead-1")
    assert ana is not None and ana.role == "quality"
    assert users.check("Ana Silva", "wrong-one") is None
    assert users.check("Nobody", "shift-lead-1") is None


@pytest.mark.parametrize(("entry", "says"), [
    ({"name": "A", "role": "admin", "password_hash": "H"}, "not one of viewer, quality"),
    ({"name": "A", "role": "viewer", "password_hash": "plain"}, "station line --hash-password"),
    ({"name": "A", "role": "viewer"}, "give exactly name, role and password_hash"),
])
def test_users_file_errors_say_what_to_fix(tmp_path: Path, entry: dict[str, str],
                                           says: str) -> None:
    if entry.get("password_hash") == "H":
        entry["password_hash"] = hash_password("secret-1", n=2**8)
    with pytest.raises(UserError, match=says):
        load_line_users(_users_file(tmp_path, [entry]))


def test_users_file_refuses_a_name_twice(tmp_path: Path) -> None:
    h = hash_password("secret-1", n=2**8)
    twice = [{"name": "Bo", "role": "viewer", "password_hash": h},
             {"name": "bo", "role": "engineer", "password_hash": h}]
    with pytest.raises(UserError, match="appears twice"):
        load_line_users(_users_file(tmp_path, twice))


def test_the_docs_users_file_loads(tmp_path: Path) -> None:
    doc = (REPO / "docs" / "line-database.md").read_text(encoding="utf-8")
    blocks = [b for b in re.findall(r"```yaml\n(.*?)```", doc, re.S) if "password_hash" in b]
    assert len(blocks) == 1
    path = tmp_path / "line-users.yaml"
    path.write_text(blocks[0], encoding="utf-8")
    users = load_line_users(path)
    assert [(u.name, u.role) for u in users.users] == [("Ana Silva", "quality"),
                                                       ("Line Lead", "viewer")]


def test_hash_password_prints_an_entry_the_file_takes(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr("sys.stdin", io.StringIO("line-secret-9\n"))
    assert main(["line", "--hash-password"]) == 0
    text = capsys.readouterr().out.replace("<user name>", "Cai").replace("viewer  #", "engineer #")
    path = tmp_path / "users.yaml"
    path.write_text(text, encoding="utf-8")
    user = load_line_users(path).check("Cai", "line-secret-9")
    assert user is not None and user.role == "engineer"


# ------------------------------------------------------------------- command line, HTTPS


def _users(tmp_path: Path) -> Path:
    return _users_file(tmp_path, [
        {"name": "Vera", "role": "viewer", "password_hash": hash_password("pw-vera", n=2**8)}])


def test_cli_refuses_beyond_loopback_without_tls(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    db = tmp_path / "line.sqlite"
    code = main(["line", "--db", str(db), "--users", str(_users(tmp_path)), "--host", "0.0.0.0"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "without HTTPS" in err and "--tls-cert and --tls-key" in err
    assert main(["line", "--db", str(db), "--tls-cert", str(db)]) == 2  # no --users
    assert "give --users FILE" in capsys.readouterr().err


def test_cli_with_a_certificate_serves_https_with_secure_cookies(tmp_path: Path) -> None:
    from tests.ui.test_ui_security import _self_signed

    tls = _self_signed(tmp_path)
    args = argparse.Namespace(users=_users(tmp_path), tls_cert=tls.certificate,
                              tls_key=tls.key, host="0.0.0.0", allowed_host=["line-pc"])
    access, got = _line_access(args)
    assert got == tls and access.https and "line-pc" in access.hosts
    app = create_line_app(ResultsDB(tmp_path / "l.sqlite").engine, None, access)
    r = TestClient(app, base_url="https://line-pc").get("/api/session")
    assert r.status_code == 200 and "secure" in r.headers["set-cookie"].lower()
    server = serve_in_thread(app, tls=tls)  # on loopback here; served as `station line` does
    try:
        with httpx.Client(base_url=server.url, verify=False, timeout=10) as client:
            assert server.url.startswith("https://")
            r = client.get("/api/session")
            assert r.status_code == 200 and "secure" in r.headers["set-cookie"].lower()
            assert client.get("/api/yields").status_code == 401
    finally:
        server.stop()
    dispose_all()
