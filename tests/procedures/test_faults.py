"""Each fault the bench can inject ends in ERROR (or FAIL) with its reason in the record, the
bench in a safe state (from the bench's own truth), and what was measured before it kept."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from procedures.runtime.rawdata import read_raw
from procedures.runtime.record import Verdict, read_record

from .conftest import DATA, run_on_bench

FAULTS = {
    # id: (step at whose start it is injected, fault kind, params, words the reason must hold)
    "modbus_lost": ("rate_table", "modbus_drop", {"target": "table"}, ["rate table"]),
    "table_fault": ("rate_table", "table_fault", {"code": "following_error"}, ["following error"]),
    "chamber_stuck": ("thermal", "chamber_stuck", {}, ["chamber", "did not reach"]),
    "supply_current_limit": ("bias", "supply_short", {"socket": 1}, ["current-limiting"]),
    "corrupted_stream": (
        "rate_table",
        "stream_corrupt",
        {"socket": 1, "byte_error_rate": 0.002},
        ["stream corrupted"],
    ),
    "absent_part": ("power_identify", "part_absent", {"socket": 1}, ["no part in the socket"]),
}


@pytest.mark.parametrize("fault_id", sorted(FAULTS))
def test_fault_ends_in_error_safe_and_keeps_data(fault_id: str, tmp_path: Path) -> None:
    step, kind, params, words = FAULTS[fault_id]

    def inject(control: Any) -> None:
        control.fault(kind, **params)

    # faults.yaml goes to 35 C first, so a stuck chamber is caught at the first condition
    procedure = DATA / ("faults.yaml" if kind == "chamber_stuck" else "short.yaml")
    run = run_on_bench(
        tmp_path / "runs",
        [{"socket": 1, "serial": "SIM-0401"}],
        speed=150,
        procedure=procedure,
        inject=(step, inject),
    )
    assert run.injected_at is not None
    rec = read_record(run.result.folders[1])
    assert rec.verdict in (Verdict.ERROR, Verdict.FAIL)
    assert all(w in rec.reason for w in words), rec.reason
    assert run.result.exit_code == 2 if rec.verdict is Verdict.ERROR else 1
    assert run.final_truth["safe"]["all"], run.final_truth["safe"]
    assert rec.events[-1].step == "finish" and rec.finished_utc
    if step not in ("power_identify", "thermal"):
        # everything measured before the fault is in the record and in raw.h5
        names = {m.name for m in rec.measurements}
        assert "supply_current_a" in names
        raw = read_raw(run.result.folders[1] / "raw.h5")
        assert raw["samples"]["time_s"].size > 1000
        assert "stabilise" in set(raw["segments"]["kind"])
        if step == "rate_table":
            assert "raw_bias_dps" in names


def test_part_dropping_out_does_not_stop_the_others(tmp_path: Path) -> None:
    def silence_two(control: Any) -> None:
        control.fault("part_silent", socket=2)

    parts = [{"socket": 1, "serial": "SIM-0411"}, {"socket": 2, "serial": "SIM-0412"}]
    run = run_on_bench(tmp_path / "runs", parts, speed=150, inject=("rate_table", silence_two))
    one, two = (read_record(run.result.folders[s]) for s in (1, 2))
    assert two.verdict is Verdict.ERROR and "stopped" in two.reason, two.reason
    assert one.verdict is Verdict.PASS, one.reason
    assert one.calibration is not None and one.verification is not None
    assert two.calibration is None  # dropped before the fit, with what it had measured kept
    assert "raw_bias_dps" in {m.name for m in two.measurements}
    assert run.final_truth["safe"]["all"]
