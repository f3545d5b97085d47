"""QA findings on the simulated bench: torn 32-bit writes, unknown device ids, ready line."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from drivers.rate_table_map import Reg
from drivers.sim.modbus_twins import splits_pair

from .conftest import i32, modbus_client, regs32

REPO = Path(__file__).resolve().parents[2]
DEV = {"device_id": 1}


def test_splits_pair() -> None:
    assert not splits_pair(Reg.RATE_CMD, 2)
    assert not splits_pair(Reg.CONTROL, 10)
    assert not splits_pair(Reg.CONTROL, 2)
    assert splits_pair(Reg.RATE_CMD, 1)
    assert splits_pair(Reg.RATE_CMD + 1, 1)
    assert splits_pair(Reg.POS_CMD + 1, 2)  # low word of POS_CMD, high word of RATE_CMD
    assert splits_pair(Reg.MODE, 2)


def test_bench_half_pair_writes_unknown_ids_and_ready_line(tmp_path: Path) -> None:
    state = tmp_path / "s.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "station", "bench", "--state", str(state), "--speed", "50"],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().decode()  # blocks until ready (or exit: empty)
        assert line.startswith("bench ready"), line
        assert str(state) in line
        import json

        endpoints = json.loads(state.read_text())
        for key in ("rate_table", "chamber", "supply", "control"):
            assert endpoints[key] in line
        client = modbus_client(endpoints["rate_table"])
        try:
            ok = client.write_registers(Reg.RATE_CMD, regs32(12_345), **DEV)
            assert not ok.isError()
            for addr, values in (
                (Reg.RATE_CMD, [1]),  # high word only
                (Reg.RATE_CMD + 1, [0xFFFF]),  # low word only
                (Reg.POS_CMD + 1, [0, 1]),  # straddles two pairs
            ):
                r = client.write_registers(addr, values, **DEV)
                assert r.isError() and r.exception_code in (2, 3), (addr, r)
            r = client.write_register(Reg.RATE_CMD + 1, 7, **DEV)
            assert r.isError() and r.exception_code in (2, 3)
            regs = client.read_holding_registers(Reg.RATE_CMD, count=2, **DEV).registers
            assert i32(*regs) == 12_345  # not torn
            r = client.read_holding_registers(Reg.STATUS, count=1, device_id=7)
            assert r.isError() and r.exception_code == 11  # gateway target failed to respond
            r = client.read_holding_registers(Reg.STATUS, count=1, **DEV)
            assert not r.isError()  # the connection and device 1 still serve
        finally:
            client.close()
        chamber = modbus_client(endpoints["chamber"])
        try:
            r = chamber.read_holding_registers(100, count=1, device_id=9)
            assert r.isError() and r.exception_code == 11
        finally:
            chamber.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0
    err = proc.stderr.read().decode() if proc.stderr else ""
    assert "Traceback" not in err and "KeyError" not in err, err
