"""`station bench` as a process: state file, clean stop on SIGTERM/SIGINT, bad input."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drivers.sim.control_client import ControlClient, ControlError

REPO = Path(__file__).resolve().parents[2]
STATE_KEYS = {"speed", "rate_table", "chamber", "supply", "duts", "control"}


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO)}


def _start(tmp_path: Path, *args: str) -> tuple[subprocess.Popen[bytes], Path]:
    state = tmp_path / "s.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "station", "bench", "--state", str(state), *args],
        cwd=tmp_path,
        env=_env(),
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 60  # a bound: imports on a loaded 2-core machine
    while not state.exists():
        assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
        assert time.monotonic() < deadline, "no state file within 60 s"
        time.sleep(0.02)
    return proc, state


def _children(pid: int) -> list[int]:
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True)
    return [int(x) for x in out.stdout.split()]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_bench_writes_endpoints_and_stops_cleanly(tmp_path: Path, sig: int) -> None:
    proc, state_path = _start(tmp_path, "--speed", "50", "--sockets", "3")
    state = json.loads(state_path.read_text())
    assert set(state) >= STATE_KEYS
    assert state["speed"] == 50.0
    assert sorted(state["duts"]) == ["1", "2", "3"]
    ptys = [state["supply"], *state["duts"].values()]
    assert all(Path(p).exists() and p.startswith("/dev/pts/") for p in ptys)
    assert len(set(ptys)) == 4
    with ControlClient(state["control"]) as ctl:
        assert ctl.ping()["speed"] == 50.0
    assert _children(proc.pid) == []  # no helper processes
    proc.send_signal(sig)
    assert proc.wait(10) == 0
    assert proc.stderr is not None and b"Traceback" not in proc.stderr.read()
    # every pty closed on both sides: the slave device nodes are gone
    deadline = time.monotonic() + 3.0  # the kernel frees a pty shortly after the last close
    while [p for p in ptys if Path(p).exists()] and time.monotonic() < deadline:
        time.sleep(0.05)
    assert [p for p in ptys if Path(p).exists()] == []
    assert state_path.exists()  # the user's file stays
    with pytest.raises(ControlError, match="is the bench running"):
        ControlClient(state["control"], timeout_s=1.0)


def test_bench_with_bad_config_exits_2_with_one_line(tmp_path: Path) -> None:
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("parts:\n  - {socket: 1, serial: X, scale: 5}\n")
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "station",
            "bench",
            "--config",
            str(cfg),
            "--state",
            str(tmp_path / "s.json"),
        ],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == 2
    assert "parts.0.scale" in out.stderr and str(cfg) in out.stderr
    assert "Traceback" not in out.stderr
    assert not (tmp_path / "s.json").exists()


def test_bench_rejects_bad_speed(tmp_path: Path) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "station", "bench", "--speed", "-3"],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == 2 and "--speed" in out.stderr
