"""Full and read-only `--out` for a real `station run --sim` process: refused before the run in
one line (exit 2) when the folder cannot be written or has too little free space; a disk that
fills during the run ends it ERROR naming the file, with the bench made safe (the bench's own
truth) and the record kept; never exit 1 (FAIL) or 139 (a crash).

The output folders are small tmpfs mounts made by the test (root only; skipped otherwise)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

from procedures.runtime.rawdata import read_raw
from procedures.runtime.record import Verdict, read_record

ROOT = Path(__file__).resolve().parents[2]
PROCEDURE = ROOT / "config/procedures/eol-rate-table.yaml"


@pytest.fixture
def tmpfs(tmp_path: Path):  # type: ignore[no-untyped-def]
    """Mount a 2 MB tmpfs (options given by the test); unmounted in teardown."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mounts: list[Path] = []

    def mount(name: str, options: str = "size=2m") -> Path:
        mnt = tmp_path / name
        mnt.mkdir()
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(mnt)],
                           capture_output=True, text=True)
        if r.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
        mounts.append(mnt)
        return mnt

    yield mount
    for mnt in mounts:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def station_yaml(folder: Path, **extra: Any) -> Path:
    """config/station.yaml with its files in `folder` (signing keys, database)."""
    st = yaml.safe_load((ROOT / "config/station.yaml").read_text(encoding="utf-8"))
    st.update(procedure=str(PROCEDURE), output_folder=str(folder / "runs"),
              results_db=str(folder / "results.sqlite"), **extra)
    path = folder / "station.yaml"
    path.write_text(yaml.safe_dump(st), encoding="utf-8")
    return path


def station(*args: str, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "station", *args], capture_output=True,
                          text=True, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                          timeout=timeout)


def one_line_error(r: subprocess.CompletedProcess[str], *words: str) -> str:
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("station "), r.stderr
    for w in words:
        assert w in lines[0], r.stderr
    # refused before a bench was started or any instrument touched
    assert "simulated bench running" not in r.stdout
    return lines[0]


def test_an_output_folder_without_the_minimum_free_space_is_refused(
    tmp_path: Path, tmpfs: Any
) -> None:
    out = tmpfs("out")  # 2 MB; the default minimum is 200 MB
    r = station("run", "--sim", "--dut", "SIM-0001", "--station", str(station_yaml(tmp_path)),
                "--out", str(out))
    one_line_error(r, str(out), "MB free", "min_free_space_mb")
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("command", ["run", "demo"])
def test_a_read_only_output_folder_is_refused(tmp_path: Path, tmpfs: Any, command: str) -> None:
    out = tmpfs("out", "size=2m,ro")
    args = ["--dut", "SIM-0001"] if command == "run" else []
    r = station(command, *(["--sim"] if command == "run" else []), *args,
                "--station", str(station_yaml(tmp_path, min_free_space_mb=0)), "--out", str(out))
    one_line_error(r, str(out), "cannot be written", "Read-only file system")


class TruthWatch:
    """Reads the simulated bench's truth over its control channel until the bench stops (the
    bench is the run's own child process; its state file names the channel). In lockstep the
    world moves only when the station asks, so the last truth read is the bench as the
    station left it."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.proc = proc
        self.last: dict[str, Any] | None = None
        self.error = ""  # why the truth stopped coming (for a failing test's message)
        self.stdout: list[str] = []
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        from drivers.sim.control_client import ControlClient

        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.stdout.append(line)
            m = re.search(r"simulated bench running .*\(pid (\d+)\)", line)
            if m:
                break
        else:
            return
        argv = Path(f"/proc/{m.group(1)}/cmdline").read_bytes().split(b"\0")
        state = Path(argv[argv.index(b"--state") + 1].decode())
        control = json.loads(state.read_text(encoding="utf-8"))["control"]
        reader = threading.Thread(target=self._drain, daemon=True)
        reader.start()
        try:
            with ControlClient(control, timeout_s=2.0) as client:
                while self.proc.poll() is None:
                    self.last = client.truth()
                    time.sleep(0.02)
        except Exception as exc:  # the bench stopped: the last truth stands
            self.error = repr(exc)
        reader.join(30)

    def _drain(self) -> None:
        assert self.proc.stdout is not None
        self.stdout.extend(self.proc.stdout)


def test_a_disk_that_fills_during_the_run_ends_it_error_safe_and_kept(
    tmp_path: Path, tmpfs: Any
) -> None:
    out = tmpfs("out")  # 2 MB: a part's raw.h5 reaches ~16 MB, so the disk fills mid-run
    config = station_yaml(tmp_path, min_free_space_mb=0.5)
    err_path = tmp_path / "stderr.txt"
    with err_path.open("w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "station", "run", "--sim", "--dut", "SIM-0001", "--station",
             str(config), "--out", str(out)],
            stdout=subprocess.PIPE, stderr=err, text=True, cwd=ROOT,
            env=dict(os.environ, PYTHONPATH=str(ROOT)),
        )
    watch = TruthWatch(proc)  # reads stdout
    try:
        proc.wait(timeout=300)
    finally:
        proc.kill()
    watch.thread.join(30)
    stderr = err_path.read_text()
    stdout = "".join(watch.stdout)
    assert proc.returncode == 2, (proc.returncode, stdout, stderr[-3000:])  # never 1 or 139
    assert "Traceback" not in stderr
    (folder,) = [p for p in out.iterdir() if p.is_dir()]
    raw = folder / "raw.h5"
    verdict_line = next(line for line in stdout.splitlines() if line.startswith("socket 1"))
    assert f"ERROR - cannot write {raw}: No space left on device" in verdict_line
    rec = read_record(folder)  # kept in its own folder
    assert rec.verdict is Verdict.ERROR and str(raw) in rec.reason
    assert set((rec.analysis.safe_state or {}).values()) == {"safe"}
    assert len(read_raw(raw)["samples"]["time_s"]) > 0  # what was written before is kept
    # the bench's own truth, as the station left it
    truth = watch.last
    assert truth is not None, watch.error
    last_event_s = max(e.station_time_s for e in rec.events)
    assert truth["time_s"] >= last_event_s - 1.0, (truth["time_s"], last_event_s)
    assert truth["safe"]["all"], truth["safe"]
    assert truth["table"]["enabled"] is False and truth["supply"]["output"] is False
