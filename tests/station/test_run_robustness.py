"""`station run` on bad input from the command line: one-line errors, exit 2, nothing half-made."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from drivers.sim.launcher import BenchStartError, launch_bench
from procedures.runtime.record import Verdict, read_record

ROOT = Path(__file__).resolve().parents[2]
SHORT = ROOT / "tests/procedures/data/short.yaml"


def station(*args: str, cwd: Path = ROOT, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "station", *args],
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
        cwd=cwd,
        timeout=timeout,
    )


def _one_line_error(r: subprocess.CompletedProcess[str], words: str) -> None:
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("station "), r.stderr
    assert words in lines[0], r.stderr


BAD_EFFECT = "parts:\n  - {socket: 1, serial: QA-0001, effects: {no_such_effect: {}}}\n"


def test_launcher_resolves_a_relative_config_against_the_callers_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "cfg").mkdir()
    (tmp_path / "cfg" / "bad.yaml").write_text(BAD_EFFECT)
    monkeypatch.chdir(tmp_path)
    # the bench finds the file (and rejects its content), not "cannot read"
    with (
        pytest.raises(BenchStartError, match="no_such_effect"),
        launch_bench(config="cfg/bad.yaml", speed=100),
    ):
        pass


@pytest.mark.parametrize(
    "sim_config, words",
    [
        (BAD_EFFECT, "unknown effect id 'no_such_effect'"),
        ("parts:\n  - {socket: 1, serial: QA-0001, colour: red}\n", "colour"),
    ],
)
def test_relative_invalid_sim_config_is_one_line_error(
    tmp_path: Path, sim_config: str, words: str
) -> None:
    (tmp_path / "cfg").mkdir()
    (tmp_path / "cfg" / "sim.yaml").write_text(sim_config)
    out = tmp_path / "out"
    r = station(
        "run", "--sim", "--sim-config", "cfg/sim.yaml", "--dut", "QA-0001",
        "--procedure", str(SHORT), "--out", str(out), cwd=tmp_path,
    )  # fmt: skip
    _one_line_error(r, words)
    assert "--sim-config cfg/sim.yaml:2:" in r.stderr  # refused before any bench starts
    assert "cannot read" not in r.stderr
    assert not list(out.glob("*/.running"))


@pytest.mark.parametrize("speed", ["0", "-5"])
def test_bad_speed_is_one_line_error(tmp_path: Path, speed: str) -> None:
    out = tmp_path / "out"
    r = station("run", "--sim", "--speed", speed, "--dut", "QA-0001", "--out", str(out))
    _one_line_error(r, "--speed")
    assert not out.exists()
    r = station("demo", "--speed", speed, "--out", str(out))
    _one_line_error(r, "--speed")


@pytest.mark.parametrize("flag", ["--procedure", "--station", "--product"])
def test_a_named_pipe_given_as_a_file_is_one_line_error(tmp_path: Path, flag: str) -> None:
    """A FIFO where a file is read is refused at once (it hung with no output: opening it
    waited for a writer that never came)."""
    fifo = tmp_path / "procedure.yaml"
    os.mkfifo(fifo)
    r = station("run", "--sim", "--dut", "QA-0001", flag, str(fifo), "--out",
                str(tmp_path / "out"), timeout=60)
    _one_line_error(r, "named pipe (FIFO), not a regular file")
    assert str(fifo) in r.stderr


def test_out_is_a_file_is_one_line_error(tmp_path: Path) -> None:
    out = tmp_path / "results.txt"
    out.write_text("not a folder")
    r = station("run", "--sim", "--dut", "QA-0001", "--procedure", str(SHORT), "--out", str(out))
    _one_line_error(r, "--out")
    assert out.read_text() == "not a folder"


def test_sigterm_aborts_like_ctrl_c(tmp_path: Path) -> None:
    out, tmp = tmp_path / "out", tmp_path / "tmp"
    tmp.mkdir()
    proc = subprocess.Popen(
        [sys.executable, "-m", "station", "run", "--dut", "SIM-0001", "--sim", "--speed", "100",
         "--procedure", str(SHORT), "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(ROOT), TMPDIR=str(tmp)),
        cwd=ROOT,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        seen = ""
        while "bias T25" not in seen:
            line = proc.stdout.readline()
            assert line, seen
            seen += line
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 2, stderr
    assert "making the bench safe" in stderr and "Traceback" not in stderr
    folder = next(out.glob("*_SIM-0001"))
    rec = read_record(folder)
    assert rec.verdict is Verdict.ABORTED and "SIGTERM" in rec.reason
    assert all(v == "safe" for v in (rec.analysis.safe_state or {"-": "missing"}).values())
    assert (folder / "certificate.pdf").is_file()
    assert not (folder / ".running").exists()
    assert not list(tmp.glob("simbench-*"))  # the bench's temp folder is gone


def test_socket_without_fixture_port_leaves_no_folder(tmp_path: Path) -> None:
    sim = tmp_path / "two.yaml"
    sim.write_text("speed: 100\nparts:\n  - {socket: 1, serial: SIM-0001}\n")
    out = tmp_path / "out"
    r = station(
        "run", "--sim", "--sim-config", str(sim), "--dut", "SIM-0001", "--dut", "5=SIM-0005",
        "--procedure", str(SHORT), "--out", str(out),
    )  # fmt: skip
    _one_line_error(r, "socket 5 has no fixture port")
    assert not list(out.glob("*")) if out.exists() else True
    # the next run finds nothing to mark as crashed
    r = station("run", "--dut", "../x", "--out", str(out))
    assert "marked as ERROR" not in r.stderr


def test_part_in_unscanned_socket_refuses_the_run_before_power(tmp_path: Path) -> None:
    sim = tmp_path / "three.yaml"
    sim.write_text(
        "speed: 100\nparts:\n  - {socket: 1, serial: SIM-0001}\n"
        "  - {socket: 2, serial: SIM-0002}\n  - {socket: 3, serial: SIM-0003}\n"
    )
    out = tmp_path / "out"
    r = station(
        "run", "--sim", "--sim-config", str(sim), "--dut", "SIM-0001", "--dut", "2=SIM-0002",
        "--procedure", str(SHORT), "--out", str(out),
    )  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    for serial in ("SIM-0001", "SIM-0002"):
        folder = next(out.glob(f"*_{serial}"))
        rec = read_record(folder)
        assert rec.verdict is Verdict.ERROR
        assert "socket 3 holds a part that was not scanned: scan it or take it out" in rec.reason
        assert "current-limiting" not in rec.reason
        assert not (folder / ".running").exists()
    assert "socket 3 holds a part that was not scanned" in r.stdout


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "config/sim").glob("*.yaml")))
def test_shipped_sim_configs_have_serials_the_product_accepts(name: str) -> None:
    import yaml

    from procedures.loading.config import load_product
    from station.run_folder import validate_serial

    product, _ = load_product(ROOT / "config/products/gyr130.yaml")
    data = yaml.safe_load((ROOT / "config/sim" / name).read_text()) or {}
    for part in data.get("parts", []):
        assert validate_serial(part["serial"], product.serial_pattern) == part["serial"]


def test_run_help_says_what_sim_and_out_do() -> None:
    r = station("run", "--help")
    text = " ".join(r.stdout.split())
    assert "one part per scanned serial" in text
    assert "results database to OUT/results.sqlite" in text


def test_out_moves_the_results_db_unless_it_is_the_stations_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from station.station_file import load_settings
    from station.uut import UutRunner

    text = (ROOT / "config/station.yaml").read_text()
    text = text.replace("output_folder: ../runs", "output_folder: runs")
    text = text.replace("results_db: ../runs/results.sqlite", "results_db: db/results.sqlite")
    (tmp_path / "station.yaml").write_text(text)
    settings = load_settings(tmp_path / "station.yaml")
    other = UutRunner(settings, procedure_path=SHORT, out=tmp_path / "elsewhere")
    assert other._results_db().path == tmp_path / "elsewhere" / "results.sqlite"
    monkeypatch.chdir(tmp_path)  # a relative --out naming the station's own folder
    same = UutRunner(settings, procedure_path=SHORT, out=Path("runs"))
    assert same._results_db().path == tmp_path / "db" / "results.sqlite"


def test_scanned_serials_are_stripped_before_the_sim_config_is_made() -> None:
    from station.cli.run import _duts, _sim_config

    duts = _duts([" QA-0001", "3=QA-0003 "])
    assert duts == {1: "QA-0001", 3: "QA-0003"}
    config, _ = _sim_config(None, duts)
    assert [p["serial"] for p in config["parts"]] == ["QA-0001", "QA-0003"]
