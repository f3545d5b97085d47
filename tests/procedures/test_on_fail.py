"""Fail-fast on the bench: a part beyond a `stop_part` limit stops at once; a part failing a
`continue` limit is measured to the end but, like every failed part, never programmed."""

from __future__ import annotations

from pathlib import Path

from procedures.runtime.record import Outcome, Verdict, read_record

from .conftest import DATA, run_on_bench


def test_a_failing_part_stops_early_and_no_failed_part_is_programmed(tmp_path: Path) -> None:
    parts = [
        {"socket": 1, "serial": "SIM-0901", "bias_dps": 20.0},  # raw bias limit: +/-10, stop
        {"socket": 2, "serial": "SIM-0902", "scale": 1.1},  # raw scale error limit 0.08
        {"socket": 3, "serial": "SIM-0903"},
    ]
    run = run_on_bench(tmp_path / "runs", parts, speed=80, procedure=DATA / "stop_part.yaml")
    res = run.result
    assert res.verdicts == {1: Verdict.FAIL, 2: Verdict.FAIL, 3: Verdict.PASS}, res.reasons

    stopped = read_record(res.folders[1])
    first = "T25_V4.75"
    assert stopped.reason == f"failed raw_bias_dps@{first} (on_fail: stop_part)"
    assert stopped.failed_measurements == [f"raw_bias_dps@{first}"]
    names = {m.name for m in stopped.measurements}
    assert "raw_scale_error" not in names  # no rate-table step ran for it
    assert [m.condition for m in stopped.measurements if m.name == "raw_bias_dps"] == [first]
    assert stopped.calibration is None  # never fitted, never programmed
    assert not [m for m in stopped.measurements if m.outcome is Outcome.NOT_MEASURED]

    measured = read_record(res.folders[2])
    scale_fails = [m for m in measured.measurements
                   if m.name == "raw_scale_error" and m.outcome is Outcome.FAIL]
    assert len(scale_fails) == 4  # measured at every condition (on_fail: continue)
    failed = ", ".join(f"raw_scale_error@{m.condition}" for m in scale_fails)
    assert measured.reason == f"not programmed: failed {failed}"
    assert measured.analysis.programming is not None
    assert measured.analysis.programming.programmed is False
    assert measured.calibration is not None and measured.calibration.readback is None

    good = read_record(res.folders[3])
    assert good.calibration is not None and good.calibration.readback_ok is True
    assert good.analysis.programming is None  # programmed: nothing to say why not
