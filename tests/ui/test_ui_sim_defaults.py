"""`station ui --sim` as the README shows it (issue 26 (3) and (7)): the station file's
sockets, lockstep like `station run --sim` unless a --speed is given, and a --speed said
when it overrides the sim config's."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from station.ui.server import free_port

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]


def _ui(tmp_path: Path, *args: str) -> tuple[str, dict]:
    """Start `station ui --sim ARGS`, return its first lines and the screen's state."""
    port = free_port()
    log = tmp_path / f"ui-{port}.log"
    cmd = [sys.executable, "-m", "station", "ui", "--sim", "--port", str(port),
           "--out", str(tmp_path / "runs"), *args]
    with open(log, "wb") as out:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT,
                                env=dict(os.environ, PYTHONPATH=str(ROOT)))
    try:
        deadline = time.monotonic() + 90
        while True:
            assert proc.poll() is None, log.read_text()
            try:
                state = httpx.get(f"http://127.0.0.1:{port}/api/state", timeout=2).json()
                return log.read_text(), state
            except httpx.HTTPError:
                assert time.monotonic() < deadline, log.read_text()
                time.sleep(0.1)
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def test_the_screen_shows_the_station_files_sockets_in_lockstep(tmp_path: Path) -> None:
    # was one socket at 100x: config/station.yaml says sockets: 8
    text, state = _ui(tmp_path)
    assert state["station"]["sockets"] == list(range(1, 9)), state["station"]
    assert "simulated bench running in lockstep (pid " in text, text


def test_a_speed_given_is_said_over_the_sim_configs(tmp_path: Path) -> None:
    text, state = _ui(tmp_path, "--sim-config", "config/sim/eight_sockets.yaml", "--speed", "100")
    assert state["station"]["sockets"] == list(range(1, 9))
    assert "simulated bench running at 100x (pid " in text, text
    assert "--speed 100 overrides the sim config's speed: 25" in text, text
