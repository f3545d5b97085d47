"""Tamper evidence and signed certificates: manifest, `station verify`, PAdES signatures
checked by poppler's own pdfsig, embedded fonts, certificate numbers, approvals."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

from procedures.runtime.record import read_record
from station.certify import finish_run_folder
from station.cli.main import main
from station.manifest import MANIFEST_FILE
from station.pdf_signing import unsigned_revision
from station.settings import LoadedSettings
from station.signing_keys import load_or_create_identity
from station.station_file import load_settings
from tests.reports.conftest import pdf_pages, pdf_text
from tests.reports.synth_run import Part, make_run
from tests.tools import need

REPO = Path(__file__).resolve().parents[2]


def station(*args: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(args))
    return code, out.getvalue(), err.getvalue()


def station_file(folder: Path) -> Path:
    """A station file of its own: its key, certificate and counter under `folder`."""
    text = (REPO / "config" / "station.yaml").read_text(encoding="utf-8")
    text = text.replace("procedure: procedures/", f"procedure: {REPO}/config/procedures/")
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "station.yaml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def settings(tmp_path_factory: pytest.TempPathFactory) -> LoadedSettings:
    return load_settings(station_file(tmp_path_factory.mktemp("station")))


@pytest.fixture(scope="module")
def _issued(tmp_path_factory: pytest.TempPathFactory, settings: LoadedSettings) -> Path:
    folder, _ = make_run(tmp_path_factory.mktemp("runs"), Part(serial="SIM-SIGN-1", seed=7))
    assert finish_run_folder(folder, settings, certificate=True) is not None
    return folder


@pytest.fixture
def issued(_issued: Path, tmp_path: Path) -> Path:
    """A sealed run folder with a signed certificate, a copy of its own."""
    return Path(shutil.copytree(_issued, tmp_path / _issued.name))


def verify(folder: Path, settings: LoadedSettings) -> tuple[int, str, str]:
    return station("verify", str(folder), "--station", str(settings.source.path))


def flip_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))


def test_key_is_private_and_its_fingerprint_is_in_the_manifest(
        issued: Path, settings: LoadedSettings) -> None:
    key = settings.resolve(settings.settings.signing.key)
    assert stat.S_IMODE(key.stat().st_mode) == 0o600
    identity = load_or_create_identity(key, settings.resolve(settings.settings.signing.certificate),
                                       "unused")
    manifest = json.loads((issued / MANIFEST_FILE).read_text(encoding="utf-8"))
    assert manifest["body"]["signer"]["fingerprint_sha256"] == identity.fingerprint
    assert set(manifest["body"]["files"]) >= {"record.json", "raw.h5", "certificate.pdf"}


def test_intact_folder_verifies(issued: Path, settings: LoadedSettings) -> None:
    code, out, _ = verify(issued, settings)
    assert code == 0 and "intact" in out


@pytest.mark.parametrize("name", ["record.json", "raw.h5", "certificate.pdf"])
def test_one_changed_byte_is_caught_naming_the_file(
        issued: Path, settings: LoadedSettings, name: str) -> None:
    flip_byte(issued / name)
    code, out, _ = verify(issued, settings)
    assert code == 1
    assert f"ALTERED: {name}" in out and f"{name} was changed" in out


def test_manifest_resigned_with_another_key_is_caught(
        issued: Path, settings: LoadedSettings, tmp_path: Path) -> None:
    from station.manifest import seal

    record = issued / "record.json"
    record.write_text(record.read_text(encoding="utf-8").replace('"PASS"', '"FAIL"', 1),
                      encoding="utf-8")
    forger = load_or_create_identity(tmp_path / "k.pem", tmp_path / "c.pem", "EOL-SIM-01")
    seal(issued, forger, "run")  # hashes now match the forged record
    code, out, _ = verify(issued, settings)
    assert code == 1 and "not this station's" in out


def test_removed_manifest_is_altered_and_non_run_folder_is_2(
        issued: Path, settings: LoadedSettings, tmp_path: Path) -> None:
    (issued / MANIFEST_FILE).unlink()
    assert verify(issued, settings)[0] == 1
    (tmp_path / "empty").mkdir()
    assert verify(tmp_path / "empty", settings)[0] == 2
    assert verify(tmp_path / "no-such-folder", settings)[0] == 2


def test_pdfsig_says_valid_and_every_font_is_embedded(issued: Path) -> None:
    need("pdfsig")
    need("pdffonts")
    sig = subprocess.run(["pdfsig", str(issued / "certificate.pdf")], capture_output=True,
                         text=True).stdout
    assert sig.count("Signature #") == 1
    assert "Signature Validation: Signature is Valid." in sig
    fonts = subprocess.run(["pdffonts", str(issued / "certificate.pdf")], capture_output=True,
                           text=True, check=True).stdout.splitlines()[2:]
    assert fonts, "no fonts listed"
    for line in fonts:
        assert line.split()[-5] == "yes", line  # the emb column


def test_certificate_number_is_the_station_sequence_and_survives_a_rerender(
        issued: Path, settings: LoadedSettings, tmp_path: Path) -> None:
    number = read_record(issued).certificate_number
    assert number.startswith("EOL-SIM-01-") and number != read_record(issued).run_id
    folder, _ = make_run(tmp_path / "more", Part(serial="SIM-SIGN-2", seed=8))
    finish_run_folder(folder, settings, certificate=False)
    following = read_record(folder).certificate_number
    assert int(following.rsplit("-", 1)[1]) == int(number.rsplit("-", 1)[1]) + 1
    before = unsigned_revision((issued / "certificate.pdf").read_bytes())
    code, _, err = station("report", str(issued), "--station", str(settings.source.path))
    assert code == 0, err
    assert read_record(issued).certificate_number == number
    assert unsigned_revision((issued / "certificate.pdf").read_bytes()) == before
    assert number in pdf_text(issued / "certificate.pdf", page=1)
    assert verify(issued, settings)[0] == 0


def test_report_refuses_an_altered_record_and_marks_it_when_asked(
        issued: Path, settings: LoadedSettings) -> None:
    record = issued / "record.json"
    record.write_text(record.read_text(encoding="utf-8").replace('"PASS"', '"FAIL"', 1),
                      encoding="utf-8")
    cert_before = (issued / "certificate.pdf").read_bytes()
    code, _, err = station("report", str(issued), "--station", str(settings.source.path))
    assert code == 2 and "record.json" in err and "--unverified" in err
    assert (issued / "certificate.pdf").read_bytes() == cert_before
    code, out, err = station("report", str(issued), "--unverified",
                             "--station", str(settings.source.path))
    assert code == 0, err
    marked = Path(out.strip())
    assert marked.name == "certificate-UNVERIFIED.pdf"
    pages = pdf_pages(marked)
    assert pages > 1
    for page in range(1, pages + 1):
        assert "UNVERIFIED" in pdf_text(marked, page=page)
    assert verify(issued, settings)[0] == 1  # still altered: nothing was re-sealed


def test_approval_adds_a_second_signature_and_is_sealed(
        issued: Path, settings: LoadedSettings) -> None:
    need("pdfsig")
    code, _, err = station("approve", str(issued), "--by", "Q. Engineer",
                           "--station", str(settings.source.path))
    assert code == 0, err
    sig = subprocess.run(["pdfsig", str(issued / "certificate.pdf")], capture_output=True,
                         text=True).stdout
    assert sig.count("Signature #") == 2
    assert sig.count("Signature Validation: Signature is Valid.") == 2
    assert "Approval-1" in sig
    approvals = json.loads((issued / "approvals.json").read_text(encoding="utf-8"))
    assert [a["by"] for a in approvals["approvals"]] == ["Q. Engineer"]
    assert verify(issued, settings)[0] == 0
    flip_byte(issued / "approvals.json")
    code, out, _ = verify(issued, settings)
    assert code == 1 and "approvals.json" in out
    code, _, err = station("approve", str(issued), "--by", "Someone",
                           "--station", str(settings.source.path))
    assert code == 2 and "cannot be approved" in err


def test_certificate_numbers_never_repeat_across_threads(tmp_path: Path) -> None:
    from concurrent.futures import ThreadPoolExecutor

    from station.certify import next_certificate_number

    counter = tmp_path / "counter.json"
    with ThreadPoolExecutor(max_workers=8) as pool:
        numbers = list(pool.map(lambda _: next_certificate_number(counter, "ST-1"), range(40)))
    assert len(set(numbers)) == 40
    assert sorted(int(n.rsplit("-", 1)[1]) for n in numbers) == list(range(1, 41))
