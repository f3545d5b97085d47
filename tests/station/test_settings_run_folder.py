from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from procedures.runtime.record import Dut, FileRef, RunRecord, Verdict, read_record, write_record
from station.errors import UserError
from station.run_folder import (
    LOCK_FILE,
    create_run_folder,
    recover_crashed_runs,
    release,
    validate_serial,
)

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    "serial", ["../../x", "..", "a/b", "/etc", "a\\b", "", ".hidden", "x" * 65,
               "a..b", "SIM..0001", "x" * 63 + ".."]
)
def test_unsafe_serials_refused(serial: str) -> None:
    with pytest.raises(UserError, match="not allowed"):
        validate_serial(serial)


@pytest.mark.parametrize("serial", ["x" * 64, "a.b", "A-1_2.3", "7"])
def test_safe_serials_at_the_edges_kept(serial: str) -> None:
    assert validate_serial(serial) == serial


def test_pattern_checked() -> None:
    assert validate_serial("SIM-0001", r"^SIM-[0-9]{4}$") == "SIM-0001"
    with pytest.raises(UserError, match="does not match the product's serial pattern"):
        validate_serial("SIM-01", r"^SIM-[0-9]{4}$")


def test_folder_inside_out_and_unique(tmp_path: Path) -> None:
    a = create_run_folder(tmp_path, "SIM-0001")
    b = create_run_folder(tmp_path, "SIM-0001")
    assert a != b and a.parent == tmp_path.resolve() and b.parent == tmp_path.resolve()
    assert a.name.endswith("_SIM-0001") and (a / LOCK_FILE).exists()
    release(a)
    assert not (a / LOCK_FILE).exists()


def _record(verdict: Verdict) -> RunRecord:
    ref = FileRef(path="p", sha256="0" * 64)
    return RunRecord(
        run_id="r",
        verdict=verdict,
        started_utc="2026-01-01T00:00:00Z",
        dut=Dut(serial="SIM-0001"),
        product=ref,
        procedure=ref,
    )


def test_crashed_run_marked_error(tmp_path: Path) -> None:
    dead = create_run_folder(tmp_path, "SIM-0001")
    write_record(dead, _record(Verdict.RUNNING))
    # a lock naming a process that has exited
    proc = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        capture_output=True,
        text=True,
        check=True,
    )
    lock = json.loads((dead / LOCK_FILE).read_text())
    lock["pid"] = int(proc.stdout)
    (dead / LOCK_FILE).write_text(json.dumps(lock))
    alive = create_run_folder(tmp_path, "SIM-0002")  # our own pid: still running
    write_record(alive, _record(Verdict.RUNNING))
    done = create_run_folder(tmp_path, "SIM-0003")
    write_record(done, _record(Verdict.PASS))
    assert recover_crashed_runs(tmp_path) == [dead]
    rec = read_record(dead)
    assert rec.verdict is Verdict.ERROR and "stopped during the run" in rec.reason
    assert read_record(alive).verdict is Verdict.RUNNING
    assert read_record(done).verdict is Verdict.PASS
    assert not (dead / LOCK_FILE).exists()


def test_schema_command_writes_valid_json(tmp_path: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run(
        [sys.executable, "-m", "station", "schema", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
    )
    assert out.returncode == 0, out.stderr
    schema = json.loads((tmp_path / "procedure.schema.json").read_text())
    assert "conditions" in schema["required"]
    assert schema["$defs"]["Step_thermal"]["additionalProperties"] is False
    assert "stability_timeout_s" in schema["$defs"]["Step_thermal"]["properties"]
    kinds = schema["$defs"]["StepList"]["items"]["oneOf"]
    assert {"$ref": "#/$defs/Step_bias"} in kinds and len(kinds) >= 12
    assert (tmp_path / "station.schema.json").exists()
