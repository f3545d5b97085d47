"""The line dashboard's API: what it answers for bad input and an unreachable database."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from station.db.connect import dispose_all
from station.results_db import ResultsDB
from tests.linedb.linekit import line_app, line_client, line_runs


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    db = ResultsDB(tmp_path / "line.sqlite")
    work = line_runs(20, ["EOL-A", "EOL-B"], root=tmp_path / "runs")
    db.add_records([(r.folder, r.record) for r in work])
    with line_client(line_app(db.engine)) as c:
        yield c
    dispose_all()


def test_panels_answer_and_filter(client: TestClient) -> None:
    y = client.get("/api/yields").json()
    assert sum(r["units"] for r in y["station"]) == y["all"][0]["units"] == 20
    only_b = client.get("/api/yields", params={"station": "EOL-B"}).json()
    assert [r["group"] for r in only_b["station"]] == ["EOL-B"]
    s = client.get("/api/stations").json()
    assert [x["station_id"] for x in s["stations"]] == ["EOL-A", "EOL-B"]
    assert s["choices"]["station"] == ["EOL-A", "EOL-B"]
    assert client.get("/api/capability").json()["capability"]


@pytest.mark.parametrize("path,status,words", [
    ("/api/yields?since=nonsense", 422, "not understood"),
    ("/api/yields?product=%01bad", 422, "printable"),
    ("/api/chart?coefficient=x", 422, "choose one of"),
    ("/certificate/not-a-run", 404, "not in the line database"),
    ("/certificate/%2e%2e", 422, "not a run id"),
])
def test_bad_requests_say_what_is_wrong(client: TestClient, path: str, status: int,
                                         words: str) -> None:
    r = client.get(path)
    assert r.status_code == status and words in r.json()["error"]


def test_database_down_is_503(tmp_path: Path) -> None:
    engine = sa.create_engine(f"sqlite:///{tmp_path / 'missing' / 'x.sqlite'}")
    with line_client(line_app(engine)) as c:
        r = c.get("/api/yields")
    assert r.status_code == 503 and "not reachable" in r.json()["error"]
