"""The dashboard's certificate link of a run `station archive` packed: the PDF comes from
inside RUN.tar.xz (the database's folder `ARCHIVE#RUN`), byte for byte; an archive that is
gone or damaged says where the certificate was looked for."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from procedures.runtime.record import CERTIFICATE_FILE, write_record
from station.db.connect import dispose_all
from station.results_db import ResultsDB
from station.run_archive import archive_ref, write_archive
from tests.linedb.linekit import line_app, line_client, line_runs

PDF = b"%PDF-1.4\n% archived test certificate\n" + bytes(range(256)) * 64 + b"\n%%EOF\n"


@pytest.fixture
def archived(tmp_path: Path) -> Iterator[tuple[TestClient, str, Path]]:
    db = ResultsDB(tmp_path / "line.sqlite")
    run = line_runs(1, ["EOL-A"], root=tmp_path / "runs")[0]
    run.folder.mkdir(parents=True)
    write_record(run.folder, run.record)
    (run.folder / CERTIFICATE_FILE).write_bytes(PDF)
    (run.folder / "raw.h5").write_bytes(b"raw" * 1000)
    db.add_run(run.folder, run.record)
    archive = tmp_path / "archive" / f"{run.folder.name}.tar.xz"
    archive.parent.mkdir()
    write_archive(run.folder, archive)
    db.relocate(run.record.run_id, archive_ref(archive, run.folder.name))
    for f in run.folder.iterdir():
        f.unlink()
    run.folder.rmdir()
    with line_client(line_app(db.engine)) as client:
        yield client, run.record.run_id, archive
    dispose_all()


def test_the_certificate_opens_from_inside_the_archive(
        archived: tuple[TestClient, str, Path]) -> None:
    client, run_id, _ = archived
    r = client.get(f"/certificate/{run_id}")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/pdf"
    assert r.content == PDF
    assert f"{run_id}-{CERTIFICATE_FILE}" in r.headers["content-disposition"]


@pytest.mark.parametrize("damage", ["gone", "truncated"])
def test_an_unreachable_archive_says_where_it_looked(
        archived: tuple[TestClient, str, Path], damage: str) -> None:
    client, run_id, archive = archived
    if damage == "gone":
        archive.unlink()
    else:
        archive.write_bytes(archive.read_bytes()[:200])
    r = client.get(f"/certificate/{run_id}")
    assert r.status_code == 404
    assert f"{CERTIFICATE_FILE} in the archive {archive}" in r.json()["error"]
