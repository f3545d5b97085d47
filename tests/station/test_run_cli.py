"""`station run` / `station demo` from the command line, each in its own process."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from procedures.runtime.rawdata import read_raw
from procedures.runtime.record import Verdict, read_record

ROOT = Path(__file__).resolve().parents[2]
SHORT = ROOT / "tests/procedures/data/short.yaml"


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(ROOT))


def station(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "station", *args],
        capture_output=True,
        text=True,
        env=_env(),
        cwd=ROOT,
        timeout=timeout,
    )


def _tree(path: Path) -> set[str]:
    return {str(p.relative_to(path)) for p in path.rglob("*")}


def test_bad_yaml_names_file_line_field(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(SHORT.read_text().replace("plateau_dwell_s: 4", "plateau_dwell_s: -4"))
    out = tmp_path / "out"
    r = station("run", "--dut", "SIM-0001", "--procedure", str(bad), "--out", str(out))
    assert r.returncode == 2
    line = next(i + 1 for i, t in enumerate(bad.read_text().splitlines()) if "plateau_dwell_s" in t)
    assert f"{bad}:{line}: field steps.1.steps.2.plateau_dwell_s (step rate_table)" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert not out.exists()


@pytest.mark.parametrize(
    "serial, words",
    [
        ("../../x", "not allowed"),
        ("/etc/passwd", "not allowed"),
        ("SIM_0001", "does not match the product's serial pattern"),
    ],
)
def test_bad_serials_refused_nothing_written(tmp_path: Path, serial: str, words: str) -> None:
    out = tmp_path / "a" / "b" / "out"
    before = _tree(tmp_path)
    r = station("run", "--dut", serial, "--sim", "--procedure", str(SHORT), "--out", str(out))
    assert r.returncode == 2
    assert words in r.stderr and "Traceback" not in r.stderr
    assert _tree(tmp_path) == before


def test_wrong_part_in_socket_is_refused(tmp_path: Path) -> None:
    sim = tmp_path / "sim.yaml"
    sim.write_text("speed: 100\nparts:\n  - {socket: 1, serial: SIM-0002}\n")
    out = tmp_path / "out"
    r = station(
        "run",
        "--dut",
        "SIM-0001",
        "--sim",
        "--sim-config",
        str(sim),
        "--procedure",
        str(SHORT),
        "--out",
        str(out),
    )
    assert r.returncode == 2, r.stdout + r.stderr
    (folder,) = list(out.glob("*_SIM-0001"))
    rec = read_record(folder)
    assert rec.verdict is Verdict.ERROR
    assert "'SIM-0002'" in rec.reason and "refused" in rec.reason
    assert rec.dut.part_serial_register == "SIM-0002"
    assert "run folder:" in r.stdout


def _start(args: list[str]) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "station", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
        cwd=ROOT,
    )


def _wait_for(proc: subprocess.Popen[str], pattern: str, timeout: float = 60) -> list[str]:
    lines: list[str] = []
    deadline = time.monotonic() + timeout
    assert proc.stdout is not None
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if re.search(pattern, line):
            return lines
    raise AssertionError(f"{pattern!r} never appeared: {''.join(lines)}")


def test_sigint_aborts_cleanly(tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = _start(
        [
            "run",
            "--dut",
            "SIM-0001",
            "--sim",
            "--speed",
            "100",
            "--procedure",
            str(SHORT),
            "--out",
            str(out),
        ]
    )
    try:
        _wait_for(proc, r"bias T25")
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 2, stderr
    rec = read_record(next(out.glob("*_SIM-0001")))
    assert rec.verdict is Verdict.ABORTED and "Ctrl-C" in rec.reason
    assert all(v == "safe" for v in (rec.analysis.safe_state or {"-": "missing"}).values())
    assert "ABORTED" in stdout


def test_killed_run_keeps_data_and_is_marked_error_next_start(tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = _start(
        [
            "run",
            "--dut",
            "SIM-0001",
            "--sim",
            "--speed",
            "100",
            "--procedure",
            str(SHORT),
            "--out",
            str(out),
        ]
    )
    bench_pid = None
    try:
        lines = _wait_for(proc, r"rate_table T25")
        m = re.search(r"pid (\d+)", "".join(lines))
        bench_pid = int(m.group(1)) if m else None
        time.sleep(0.5)
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
        if bench_pid:  # the station was killed: its bench child is an orphan now
            with contextlib.suppress(ProcessLookupError):
                os.kill(bench_pid, signal.SIGTERM)
    folder = next(out.glob("*_SIM-0001"))
    assert read_record(folder).verdict is Verdict.RUNNING
    raw = read_raw(folder / "raw.h5")
    assert raw["samples"]["time_s"].size > 1000  # measured before the kill, readable
    assert "raw_bias_dps" in {m.name for m in read_record(folder).measurements}
    # the next start of the station marks it ERROR (here: a run refused for its serial)
    r = station("run", "--dut", "../x", "--out", str(out))
    assert r.returncode == 2
    rec = read_record(folder)
    assert rec.verdict is Verdict.ERROR and "stopped during the run" in rec.reason
    assert str(folder) in r.stderr


def test_schema_and_help_list_commands() -> None:
    r = station("--help")
    assert all(c in r.stdout for c in ("run", "demo", "schema"))
