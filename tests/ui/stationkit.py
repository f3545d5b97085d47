"""The real station for browser tests and the screenshot script: `station ui --sim` with a
config folder like config/ whose default procedure is the short test procedure, and a bench
holding one good part and one made to fail."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import httpx

from station.ui.auth import hash_password
from station.ui.server import free_port

ENGINEER_PASSWORD = "line-eng-42"
_HASH = hash_password(ENGINEER_PASSWORD)

SIM_SPEED = 100.0
PASS_SERIAL = "SIM-0001"
FAIL_SERIAL = "SIM-0666"  # raw bias 14 deg/s, outside the product's +/-10 deg/s
REPO = Path(__file__).resolve().parents[2]


def make_station_config(folder: Path, password_hash: str | None = _HASH) -> Path:
    """A config folder like config/, with the short test procedure as the default one."""
    import shutil

    import yaml

    (folder / "procedures").mkdir(parents=True)
    (folder / "products").mkdir()
    for p in (REPO / "config" / "procedures").glob("*.yaml"):
        shutil.copy(p, folder / "procedures" / p.name)
    for p in (REPO / "config" / "products").glob("*.yaml"):
        shutil.copy(p, folder / "products" / p.name)
    short = (Path(__file__).parent / "data" / "ui-short.yaml").read_text(encoding="utf-8")
    short = short.replace("product: ../../../config/products/", "product: ../products/")
    (folder / "procedures" / "ui-short.yaml").write_text(short, encoding="utf-8")
    station = yaml.safe_load((REPO / "config" / "station.yaml").read_text(encoding="utf-8"))
    station.update(
        output_folder="runs", results_db="runs/results.sqlite", procedure="procedures/ui-short.yaml"
    )
    station["instruments"]["fixture"]["sockets"] = 2
    if password_hash:
        station["ui"] = {"engineer_password_hash": password_hash}
    (folder / "station.yaml").write_text(yaml.safe_dump(station), encoding="utf-8")
    sim = {
        "speed": SIM_SPEED,
        "parts": [
            {"socket": 1, "serial": PASS_SERIAL},
            {"socket": 2, "serial": FAIL_SERIAL, "bias_dps": 14.0},
        ],
    }
    (folder / "sim.yaml").write_text(yaml.safe_dump(sim), encoding="utf-8")
    return folder / "station.yaml"


class StationClient(httpx.Client):
    """An httpx client that has already opened its session (usable in a with block)."""

    def __enter__(self) -> StationClient:
        return self


def station_client(url: str, **kwargs: object) -> StationClient:
    """An API client as the station's own page is one: a session cookie and its CSRF token."""
    kwargs.setdefault("timeout", 10)
    client = StationClient(base_url=url, **kwargs)  # type: ignore[arg-type]
    r = client.get("/api/session")
    r.raise_for_status()
    client.headers["X-CSRF-Token"] = r.json()["csrf"]
    return client


def renew_token(client: httpx.Client, response: httpx.Response) -> httpx.Response:
    """After a sign-in, login or logout the session has new tokens: keep the client's in step."""
    if response.status_code == 200 and "csrf" in response.json():
        client.headers["X-CSRF-Token"] = response.json()["csrf"]
    return response


def bench_control_of(ui_log: Path, timeout_s: float = 10.0) -> str:
    """The simulated bench's control endpoint, found as its owner finds it on this machine:
    `station ui` prints the bench's pid; the bench's --state file holds its endpoints. The
    station never publishes it (it answers anyone who reaches it)."""
    import json
    import re

    deadline = time.monotonic() + timeout_s
    while True:
        m = re.search(
            r"simulated bench running (?:at \S+|in lockstep) \(pid (\d+)\)", ui_log.read_text()
        )
        if m or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    if not m:
        raise RuntimeError(f"no bench pid in {ui_log}")
    argv = Path(f"/proc/{m.group(1)}/cmdline").read_bytes().split(b"\0")
    state = Path(argv[argv.index(b"--state") + 1].decode())
    return str(json.loads(state.read_text(encoding="utf-8"))["control"])


@dataclass
class SimStation:
    url: str
    config: Path
    process: subprocess.Popen[bytes]
    bench_control: str  # host:port of the bench's control channel (the twins' truth)

    def truth(self) -> dict:
        from drivers.sim.control_client import ControlClient

        with ControlClient(self.bench_control) as control:
            return control.truth()

    def client(self) -> httpx.Client:
        return station_client(self.url)


def start_ui_process(config: Path, log_path: Path, speed: float = SIM_SPEED) -> SimStation:
    """`station ui --sim` as its own process, as on the line; returns once it answers."""
    port = free_port()
    env = dict(os.environ, PYTHONPATH=str(REPO))
    cmd = [
        sys.executable,
        "-m",
        "station",
        "ui",
        "--sim",
        "--port",
        str(port),
        "--station",
        str(config / "station.yaml"),
        "--sim-config",
        str(config / "sim.yaml"),
        "--speed",
        str(speed),
    ]
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            cmd,
            cwd=str(REPO),
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
        )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while True:
        if proc.poll() is not None:
            raise RuntimeError(
                f"station ui exited ({proc.returncode}): {log_path.read_text()[-2000:]}"
            )
        try:
            httpx.get(url + "/api/state", timeout=2).raise_for_status()
            return SimStation(url, config, proc, bench_control_of(log_path))
        except httpx.HTTPError as exc:
            if time.monotonic() > deadline:
                proc.kill()
                raise RuntimeError(
                    f"station ui did not answer: {log_path.read_text()[-2000:]}"
                ) from exc
            time.sleep(0.1)


def stop_ui_process(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)  # uvicorn shuts down, the bench is stopped
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
