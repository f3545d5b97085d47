"""`station discrepancy --simulate` refuses what it cannot simulate at once, with one line
saying what to do, before any data are analysed (no bench is started here)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from fake_run_folder import write_run_folder
from helpers_model import TINY
from synth_gyro import Part, generate

from procedures.runtime.record import FileRef, read_record, write_record
from station.cli import main as cli
from station.discrepancy_simulate import record_procedure
from station.errors import UserError

PROCEDURE = Path(__file__).resolve().parent / "data" / "eol-simulate.yaml"


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("runs") / "20260101T000000Z_SYN-0001"
    return write_run_folder(folder, generate(Part(), 3, TINY), latched_counts_per_rev=1 << 20)


def _error(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    assert cli.main(["discrepancy", *args]) == 2
    return capsys.readouterr().err


def test_simulate_needs_a_run_folder_not_a_csv(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    csv = tmp_path / "run.csv"
    csv.write_text("time_s,gyro_dps,ref_rate_dps,ref_angle_deg,temp_c,supply_v\n")
    err = _error(capsys, str(csv), "--simulate")
    assert "--simulate needs a station run folder" in err
    assert not (tmp_path / "run_discrepancy").exists()  # nothing created


def test_simulate_options_without_simulate_are_refused(
    run_folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    err = _error(capsys, str(run_folder), "--sim-speed", "50")
    assert "go with --simulate" in err


def test_a_procedure_that_is_not_there_is_named_before_the_analysis(
    run_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    err = _error(capsys, str(run_folder), "--simulate", "--out", str(out))
    assert "the procedure the run used (x) is not there any more" in err
    assert "--procedure PATH" in err
    err = _error(capsys, str(run_folder), "--simulate", "--procedure", str(tmp_path / "no.yaml"))
    assert "no such file" in err
    assert not out.exists()


def test_bad_bench_speed_is_refused(run_folder: Path, capsys: pytest.CaptureFixture[str]) -> None:
    err = _error(capsys, str(run_folder), "--simulate", "--procedure", str(PROCEDURE),
                 "--sim-speed", "0")
    assert "--sim-speed must be from" in err


def test_record_procedure_notes_a_changed_file(run_folder: Path, tmp_path: Path) -> None:
    copy = tmp_path / "proc.yaml"
    copy.write_bytes(PROCEDURE.read_bytes())
    rec = read_record(run_folder)
    digest = hashlib.sha256(copy.read_bytes()).hexdigest()
    write_record(run_folder, rec.model_copy(update={
        "procedure": FileRef(path=str(copy), sha256=digest)}))
    try:
        assert record_procedure(run_folder, None) == (copy, None)
        copy.write_text(copy.read_text() + "\n# edited\n")
        path, note = record_procedure(run_folder, None)
        assert path == copy and note is not None and "differs from the one the run used" in note
    finally:
        write_record(run_folder, rec)
    with pytest.raises(UserError, match="not there any more"):
        record_procedure(run_folder, None)


def test_a_bench_slow_to_start_is_started_again_then_refused_in_one_line(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """On a loaded machine a bench can take longer than the launcher waits for its state
    file: the twin run starts it again (3 attempts in all), then says what happened."""
    from drivers.sim.launcher import BenchStartError
    from station import discrepancy_simulate, sim_run

    calls = []

    def slow_bench(*_args: object, **_kwargs: object) -> None:
        calls.append(1)
        raise BenchStartError("the bench wrote no state file within 20 s")

    monkeypatch.setattr(sim_run, "run_simulated", slow_bench)
    with pytest.raises(UserError, match="did not start in 3 attempts"):
        discrepancy_simulate.run_twin({"socket": 1}, PROCEDURE, tmp_path, None)
    assert len(calls) == discrepancy_simulate.BENCH_START_ATTEMPTS == 3
