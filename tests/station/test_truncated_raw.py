"""A truncated raw.h5, at ten sizes, given to every command that reads it: `station report`,
`station discrepancy`, `station verify` and the `replay` part driver. Each ends within 5 s with
one line (before, HDF5's SWMR reader retried the damaged metadata for minutes: report and
discrepancy hung, and a replay part hung a `station run --sim` for 600 s, deaf to SIGTERM).

The commands run in this process (the 5 s are the command's own, not an interpreter's start on
a loaded machine), each in a thread that is given up on after the bound; one `station run
--sim` with a replay part runs as its own process."""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from station.certify import finish_run_folder
from station.cli.main import build_parser, main
from station.settings import LoadedSettings
from station.station_file import load_settings
from tests.reports.synth_run import Part, make_run
from tests.reports.test_signing import station_file

ROOT = Path(__file__).resolve().parents[2]
BOUND_S = 5.0
# bytes kept of raw.h5: inside the signature, the superblock, the first object headers, the
# data, and short of the end by one byte
SIZES = ["0", "7", "40", "100", "1000", "10000", "100000", "25%", "50%", "-1"]


@pytest.fixture(scope="module")
def settings(tmp_path_factory: pytest.TempPathFactory) -> LoadedSettings:
    return load_settings(station_file(tmp_path_factory.mktemp("station")))


@pytest.fixture(scope="module")
def sealed(tmp_path_factory: pytest.TempPathFactory, settings: LoadedSettings) -> Path:
    folder, _ = make_run(tmp_path_factory.mktemp("runs"), Part(serial="SIM-TRUNC-1", seed=3))
    finish_run_folder(folder, settings, certificate=False)  # sealed, as a run leaves it
    build_parser()  # the command modules imported once, outside the bound
    import drivers.replay_part  # noqa: F401
    import station.cli.discrepancy  # noqa: F401
    return folder


def truncated(sealed: Path, tmp_path: Path, size: str) -> Path:
    folder = Path(shutil.copytree(sealed, tmp_path / sealed.name))
    raw = folder / "raw.h5"
    full = raw.stat().st_size
    keep = full * int(size[:-1]) // 100 if size.endswith("%") else (
        full + int(size) if size.startswith("-") else int(size))
    with raw.open("r+b") as fh:
        fh.truncate(keep)
    return folder


def bounded(fn, *args: object) -> tuple[object, str, str, float]:  # type: ignore[no-untyped-def]
    """fn(*args) in a thread, its stdout and stderr, and its wall time; fails past BOUND_S."""
    out, err = io.StringIO(), io.StringIO()
    box: dict[str, object] = {}

    def target() -> None:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                box["result"] = fn(*args)
            except BaseException as exc:  # returned to the test
                box["result"] = exc

    t0 = time.monotonic()
    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(BOUND_S)
    wall = time.monotonic() - t0
    assert not thread.is_alive(), f"still running after {BOUND_S:g} s"
    return box["result"], out.getvalue(), err.getvalue(), wall


def one_line(text: str) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, text
    assert len(lines[0]) < 600, lines[0]
    return lines[0]


@pytest.mark.parametrize("size", SIZES)
def test_report_refuses_it(sealed: Path, settings: LoadedSettings, tmp_path: Path,
                           size: str) -> None:
    folder = truncated(sealed, tmp_path, size)
    code, out, err, _ = bounded(main, ["report", str(folder), "--station",
                                       str(settings.source.path)])
    assert code == 2 and out == ""
    assert "raw.h5" in one_line(err)


@pytest.mark.parametrize("size", SIZES)
def test_report_unverified_reads_it_at_once(
        sealed: Path, settings: LoadedSettings, tmp_path: Path, size: str,
        caplog: pytest.LogCaptureFixture) -> None:
    """--unverified renders anyway: the damaged raw.h5 is read at once and named (it hung for
    120 s), the certificate drawn without its charts and marked UNVERIFIED."""
    folder = truncated(sealed, tmp_path, size)
    code, _, err, _ = bounded(main, ["report", str(folder), "--unverified", "--station",
                                     str(settings.source.path)])
    assert code == 0, err
    unreadable = [r.getMessage() for r in caplog.records if "raw data unreadable" in r.getMessage()]
    assert len(unreadable) == 1 and f"{folder / 'raw.h5'}: " in unreadable[0]
    assert (folder / "certificate-UNVERIFIED.pdf").is_file()


@pytest.mark.parametrize("size", SIZES)
def test_verify_calls_it_altered(sealed: Path, settings: LoadedSettings, tmp_path: Path,
                                 size: str) -> None:
    folder = truncated(sealed, tmp_path, size)
    code, out, _, _ = bounded(main, ["verify", str(folder), "--station",
                                     str(settings.source.path)])
    assert code == 1 and f"{folder}: ALTERED: raw.h5" in out


@pytest.mark.parametrize("size", SIZES)
def test_discrepancy_refuses_it(sealed: Path, tmp_path: Path, size: str) -> None:
    folder = truncated(sealed, tmp_path, size)
    code, out, err, _ = bounded(main, ["discrepancy", str(folder), "--model", "first_order",
                                       "--out", str(tmp_path / "disc")])
    assert code == 2, (out, err)
    line = one_line(err)
    assert line.startswith("station discrepancy: error: ") and "raw.h5" in line
    assert not (tmp_path / "disc").exists() or not any((tmp_path / "disc").iterdir())


@pytest.mark.parametrize("size", SIZES)
def test_the_replay_part_refuses_it(sealed: Path, tmp_path: Path, size: str) -> None:
    from drivers.replay_part import factory
    from drivers.replay_source import RecordingError

    folder = truncated(sealed, tmp_path, size)
    exc, _, _, _ = bounded(factory, {"address": str(folder), "socket": 1})
    assert isinstance(exc, RecordingError), exc
    text = str(exc)
    assert "\n" not in text and len(text) < 600 and "raw.h5" in text


def test_station_run_with_a_replay_of_it_is_refused_in_one_line(
        sealed: Path, tmp_path: Path) -> None:
    """The replay as a live part of `station run --sim`: refused before the run (exit 2)."""
    folder = truncated(sealed, tmp_path, "10000")
    st = yaml.safe_load((ROOT / "config/station.yaml").read_text(encoding="utf-8"))
    st.update(procedure=str(ROOT / "config/procedures/eol-rate-table.yaml"),
              output_folder=str(tmp_path / "runs"), results_db=str(tmp_path / "r.sqlite"),
              min_free_space_mb=0)
    st["instruments"]["fixture"] = {"driver": "replay", "sockets": 1, "path": str(folder)}
    config = tmp_path / "station.yaml"
    config.write_text(yaml.safe_dump(st), encoding="utf-8")
    r = subprocess.run(
        [sys.executable, "-m", "station", "run", "--sim", "--dut", "SIM-0007", "--station",
         str(config)], capture_output=True, text=True, cwd=ROOT,
        env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    line = one_line(r.stderr)
    assert "raw.h5: raw data file cannot be read (truncated" in line and "replay" in line
    assert not list((tmp_path / "runs").glob("*/record.json"))
