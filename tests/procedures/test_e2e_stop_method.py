"""The article's stop method alone (no rate-table sweep), automatic bias dwell, stop-move
verification after programming; against the bench's truth."""

from __future__ import annotations

from pathlib import Path

from procedures.runtime.record import Verdict, read_record

from .conftest import DATA, run_on_bench


def test_stop_method_procedure_against_truth(tmp_path: Path) -> None:
    run = run_on_bench(
        tmp_path / "runs",
        [{"socket": 1, "serial": "SIM-0701"}],
        speed=150,
        procedure=DATA / "stop_short.yaml",
    )
    rec = read_record(run.result.folders[1])
    assert rec.verdict is Verdict.PASS, rec.reason
    truth = run.final_truth["sockets"]["1"]["parameters"]
    cal = rec.calibration
    assert cal is not None
    assert abs(cal.scale.value - truth["scale"]) <= cal.scale.uncertainty_k2
    assert abs(cal.bias_dps.value - truth["bias_dps"]) <= cal.bias_dps.uncertainty_k2
    # no rate table was swept: every scale came from the stop moves, against the fixture angle
    assert not rec.analysis.rate_table and len(rec.analysis.stop_method) == 4
    sm = next(iter(rec.analysis.stop_method.values()))
    assert sm.reference == "fixture" and len(sm.moves) == 4
    assert sm.reference_angle_deg is not None
    assert abs(sm.reference_angle_deg - run.final_truth["sockets"]["1"]["stop_angle_deg"]) < 1e-3
    # the automatic dwell was chosen from the measured noise and the 0.01 deg/s target
    assert any("automatic dwell" in e.message for e in rec.events)
    ver = rec.verification
    assert ver is not None and ver.method == "stop_method"
    assert ver.max_error_pct is not None and ver.max_error_pct < 0.1
