"""The malformed-input corpus (tests/data/malformed/<kind>/, written by make_corpus.py): every
file goes through the station's real command line (station run / bench / analyze /
discrepancy) and must be refused with exit code 2, one error line naming the file and the
problem, no traceback, within 5 s, and nothing written (no run folder, no output file)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from station.cli.main import main

REPO = Path(__file__).resolve().parents[1]
CORPUS = REPO / "tests" / "data" / "malformed"
EXPECTED: dict[str, str] = json.loads((CORPUS / "expected.json").read_text(encoding="utf-8"))
KINDS = ("station", "procedure", "product", "sim", "model", "analyze", "discrepancy")
PRODUCT = REPO / "config" / "products" / "gyr130.yaml"
PROCEDURE = REPO / "config" / "procedures" / "eol-rate-table.yaml"
LIMIT_S = 5.0
COMMAND = {"station": "run", "procedure": "run", "product": "run", "sim": "bench",
           "model": "discrepancy", "analyze": "analyze", "discrepancy": "discrepancy"}


def _station_file(work: Path) -> Path:
    path = work / "station.yaml"
    path.write_text(
        "station: {id: EOL-T-01}\n"
        "output_folder: runs\n"
        "results_db: runs/results.sqlite\n"
        f"procedure: {PROCEDURE}\n",
        encoding="utf-8",
    )
    return path


def _data_csv(work: Path) -> Path:
    """A discrepancy CSV that loads (the model file is read first and must fail first)."""
    rows = [f"{i * 0.1:.1f},{i % 20:.1f},{i % 20:.1f},0.0,25.0,5.0" for i in range(40)]
    path = work / "data.csv"
    path.write_text("time_s,gyro_dps,ref_rate_dps,ref_angle_deg,temp_c,supply_v\n"
                    + "\n".join(rows) + "\n", encoding="utf-8")
    return path


def argv_for(kind: str, path: Path, work: Path) -> list[str]:
    """The command line that feeds `path` (of `kind`) to the station."""
    if kind == "station":
        return ["run", "--station", str(path), "--dut", "SIM-0001", "--out", str(work / "out")]
    if kind == "procedure":
        return ["run", "--station", str(_station_file(work)), "--procedure", str(path),
                "--product", str(PRODUCT), "--dut", "SIM-0001"]
    if kind == "product":
        return ["run", "--station", str(_station_file(work)), "--procedure", str(PROCEDURE),
                "--product", str(path), "--dut", "SIM-0001"]
    if kind == "sim":
        return ["bench", "--config", str(path), "--state", str(work / "state.json")]
    if kind == "model":
        return ["discrepancy", str(_data_csv(work)), "--model", str(path),
                "--out", str(work / "disc")]
    if kind == "analyze":
        return ["analyze", "allan", str(path)]
    if kind == "discrepancy":
        return ["discrepancy", str(path), "--out", str(work / "disc")]
    raise AssertionError(kind)


@pytest.fixture(scope="module", autouse=True)
def _warm() -> None:
    """Import what the commands import, so the 5 s is the input's handling, not imports
    (the subprocess test below times a fresh process too)."""
    import drivers.sim.bench  # noqa: F401
    import procedures.model.discrepancy  # noqa: F401
    import station.uut  # noqa: F401


def _files(folder: Path) -> set[Path]:
    return {p for p in folder.rglob("*")}


def test_the_corpus_is_complete() -> None:
    on_disk = {f"{p.parent.name}/{p.name}" for k in KINDS for p in (CORPUS / k).iterdir()}
    assert on_disk == set(EXPECTED), "regenerate with tests/data/malformed/make_corpus.py"
    assert len(EXPECTED) >= 100
    for kind in KINDS:
        assert sum(k.startswith(f"{kind}/") for k in EXPECTED) >= 10, kind


@pytest.mark.timeout(60)
@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_malformed_input_is_refused_in_one_line(
    name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    kind = name.split("/")[0]
    path = CORPUS / name
    argv = argv_for(kind, path, tmp_path)
    before, corpus_before = _files(tmp_path), _files(CORPUS)
    t0 = time.monotonic()
    code = main(argv)
    elapsed = time.monotonic() - t0
    out, err = capsys.readouterr()
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, (out, err)
    assert elapsed < LIMIT_S, f"{name} took {elapsed:.1f} s"
    assert "Traceback" not in err + out
    assert len(lines) == 1, err
    line = lines[0]
    assert line.startswith(f"station {COMMAND[kind]}: error: "), line
    assert path.name in line, line
    assert EXPECTED[name].lower() in line.lower(), (EXPECTED[name], line)
    assert len(line) < 2_000, "the error quotes too much of the input"
    assert _files(tmp_path) == before, "something was written"
    assert _files(CORPUS) == corpus_before


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    "name",
    ["procedure/billion_laughs.yaml", "procedure/safe_temp_300.yaml", "sim/speed_1e-9.yaml",
     "analyze/field_200k.csv", "discrepancy/field_200k.csv", "station/raw_nul.yaml"],
)
def test_through_the_installed_command(name: str, tmp_path: Path) -> None:
    """A few files through a fresh `python -m station` process: exit 2, one line on stderr."""
    kind = name.split("/")[0]
    argv = argv_for(kind, CORPUS / name, tmp_path)
    before = _files(tmp_path)
    done = subprocess.run([sys.executable, "-m", "station", *argv], capture_output=True,
                          text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert (CORPUS / name).name in done.stderr
    assert _files(tmp_path) == before


def test_a_two_megabyte_procedure_name_is_refused_at_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = PROCEDURE.read_text(encoding="utf-8").replace(
        "name: eol-rate-table", "name: " + "N" * 2_000_000, 1
    )
    assert len(text) > 2_000_000
    path = tmp_path / "long-name.yaml"
    path.write_text(text, encoding="utf-8")
    t0 = time.monotonic()
    assert main(argv_for("procedure", path, tmp_path)) == 2
    assert time.monotonic() - t0 < LIMIT_S
    assert "too large" in capsys.readouterr().err


@pytest.mark.parametrize("speed", ["1e-9", "0", "-1", "nan", "inf", "1e6"])
def test_speed_out_of_range_is_refused(
    speed: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "--speed", speed, "--state", str(tmp_path / "s.json")]) == 2
    assert "--speed must be from 0.01 to 10000" in capsys.readouterr().err
    argv = ["run", "--sim", "--station", str(_station_file(tmp_path)), "--dut", "SIM-0001",
            "--speed", speed]
    before = _files(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--speed must be from 0.01 to 10000" in err, err
    assert _files(tmp_path) == before


@pytest.mark.parametrize(
    "option, value",
    [("--reference-angle", "nan"), ("--reference-angle", "-90"), ("--reference-angle", "1e308"),
     ("--reference-angle-uncertainty", "inf"), ("--reference-angle-uncertainty", "-1"),
     ("--full-scale", "nan"), ("--full-scale", "0"), ("--full-scale", "1e308")],
)
def test_analysis_options_out_of_range_are_refused_before_reading(
    option: str, value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    # the CSV is malformed too: the option is judged first, in one line
    csv_path = CORPUS / "analyze" / "nan.csv"
    assert main(["analyze", "stop-method", str(csv_path), option, value]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"station analyze: error: {option} must be"), err
    assert len(err.splitlines()) == 1


@pytest.mark.parametrize("operator", ["A" * 201, "bad\x00name", "two\nlines"])
def test_an_unprintable_or_huge_operator_is_refused(
    operator: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["run", "--station", str(_station_file(tmp_path)), "--dut", "SIM-0001",
            "--operator", operator]
    before = _files(tmp_path)
    assert main(argv) == 2
    assert "--operator must be" in capsys.readouterr().err
    assert _files(tmp_path) == before
