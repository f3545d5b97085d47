"""Start the simulated bench as its own process and stop it cleanly (a context manager).

    from drivers.sim.launcher import launch_bench

    with launch_bench(config={"parts": [{"socket": 1, "serial": "SIM-0001"}]}, speed=100) as bench:
        bench.endpoints.rate_table      # "127.0.0.1:40123"
        bench.endpoints.duts[1]         # "/dev/pts/7"
        bench.control.truth()

On exit the bench gets SIGTERM and is waited for (killed if it does not stop in time).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from drivers.sim.config import DEFAULT_FAMILIES
from drivers.sim.control_client import ControlClient

REPO_ROOT = Path(__file__).resolve().parents[2]


class BenchStartError(RuntimeError):
    """The bench process did not come up; the message carries its error output."""


@dataclass(frozen=True)
class BenchEndpoints:
    """Where each twin listens (the state file's content)."""

    speed: float
    rate_table: str  # in its driver's address form (host:port for the TCP twins)
    chamber: str  # in its driver's address form
    supply: str  # in its driver's address form (a pty path for today's scpi twin)
    duts: dict[int, str]  # socket -> pty path, fixture protocol
    control: str  # host:port, JSON lines
    pid: int
    raw: dict[str, Any]
    # role -> the instrument family its twin serves (sim config `instruments:`)
    families: dict[str, str] = field(default_factory=lambda: dict(DEFAULT_FAMILIES))
    # the world moves only when the station's clock asks (control cmd advance)
    lockstep: bool = False

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> BenchEndpoints:
        families = dict(DEFAULT_FAMILIES)
        families.update({str(k): str(v) for k, v in (state.get("families") or {}).items()})
        return cls(
            speed=float(state["speed"]),
            rate_table=state["rate_table"],
            chamber=state["chamber"],
            supply=state["supply"],
            duts={int(k): v for k, v in state["duts"].items()},
            control=state["control"],
            pid=int(state.get("pid", 0)),
            raw=dict(state),
            families=families,
            lockstep=bool(state.get("lockstep", False)),
        )

    @staticmethod
    def host_port(endpoint: str) -> tuple[str, int]:
        host, _, port = endpoint.rpartition(":")
        return host, int(port)


@dataclass
class BenchHandle:
    endpoints: BenchEndpoints
    control: ControlClient
    process: subprocess.Popen[bytes]
    state_path: Path

    @property
    def speed(self) -> float:
        return self.endpoints.speed


def _die_with_parent() -> None:
    """Child side: get SIGTERM if the launching process dies without cleaning up (Linux)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        pr_set_pdeathsig = 1
        libc.prctl(pr_set_pdeathsig, signal.SIGTERM)
    except (OSError, AttributeError):
        pass


def _env() -> dict[str, str]:
    env = dict(os.environ)
    parts = [str(REPO_ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    env["PYTHONPATH"] = os.pathsep.join(parts)
    return env


@contextmanager
def launch_bench(
    config: str | Path | Mapping[str, Any] | None = None,
    speed: float | None = None,
    *,
    sockets: int | None = None,
    start_timeout_s: float = 60.0,  # a bound, not a wait: a 2-core machine under load
    stop_timeout_s: float = 10.0,
    extra_args: tuple[str, ...] = (),
    lockstep: bool = False,
) -> Iterator[BenchHandle]:
    """Run `station bench` (python -m station.cli.bench_main) in a subprocess for the block.

    `config` is a sim config file path or a mapping (written to a temp YAML file).
    `lockstep`: the world moves only when the station's clock asks (`LockstepClock`).
    """
    with tempfile.TemporaryDirectory(prefix="simbench-") as tmp:
        tmp_dir = Path(tmp)
        state_path = tmp_dir / "state.json"
        # `station bench` without the other commands' imports (station/cli/bench_main.py)
        cmd = [sys.executable, "-m", "station.cli.bench_main", "--state", str(state_path)]
        if isinstance(config, Mapping):
            cfg_path = tmp_dir / "sim.yaml"
            cfg_path.write_text(yaml.safe_dump(dict(config)), encoding="utf-8")
            cmd += ["--config", str(cfg_path)]
        elif config is not None:
            # the bench runs with cwd=REPO_ROOT: a relative path means the caller's folder
            cmd += ["--config", str(Path(config).expanduser().resolve())]
        if speed is not None:
            cmd += ["--speed", repr(float(speed))]
        if sockets is not None:
            cmd += ["--sockets", str(sockets)]
        if lockstep:
            cmd.append("--lockstep")
        cmd += list(extra_args)
        err_path = tmp_dir / "bench.err"
        with open(err_path, "wb") as err:
            proc = subprocess.Popen(
                cmd,
                cwd=str(REPO_ROOT),
                env=_env(),
                stdout=subprocess.DEVNULL,
                stderr=err,
                stdin=subprocess.DEVNULL,
                preexec_fn=_die_with_parent,
            )
        control: ControlClient | None = None
        try:
            state = _wait_for_state(proc, state_path, err_path, start_timeout_s)
            endpoints = BenchEndpoints.from_state(state)
            control = ControlClient(endpoints.control)
            yield BenchHandle(endpoints, control, proc, state_path)
        finally:
            if control is not None:
                control.close()
            stop_process(proc, stop_timeout_s)


def _wait_for_state(
    proc: subprocess.Popen[bytes], state_path: Path, err_path: Path, timeout_s: float
) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            tail = err_path.read_text(errors="replace")[-2000:]
            raise BenchStartError(f"the bench exited with code {proc.returncode}: {tail.strip()}")
        if state_path.exists():
            return json.loads(state_path.read_text(encoding="utf-8"))
        time.sleep(0.02)
    raise BenchStartError(
        f"the bench wrote no state file within {timeout_s:g} s; "
        f"its error output: {err_path.read_text(errors='replace')[-2000:].strip()}"
    )


def stop_process(proc: subprocess.Popen[bytes], timeout_s: float = 10.0) -> int:
    """SIGTERM, wait, SIGKILL if it will not stop; returns the exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5.0)
    return int(proc.returncode)
