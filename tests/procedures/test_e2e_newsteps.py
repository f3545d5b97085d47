"""A procedure written only in YAML (tests/data/newsteps) with warm-up, turn-on
repeatability, the stop method at three temperatures and a second-order temperature fit,
run on the simulated bench against its truth; the certificate shows each result."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from procedures.runtime.record import Verdict, read_record
from reports.certificate import render_certificate
from tests.reports.conftest import pdf_text

from .conftest import run_on_bench

DATA = Path(__file__).resolve().parents[1] / "data" / "newsteps"
PART = {
    "socket": 1,
    "serial": "SIM-0801",
    "turn_on_bias_sigma_dps": 0.05,
    "bias_temp_coeff2_dps_per_c2": -3e-4,
    "scale_temp_coeff2_per_c2": -2e-6,
    "effects": {"warmup_drift": {"amplitude_dps": 0.15, "tau_s": 40.0}},
    # a quiet part: bias instability (slow wander of about 0.01 deg/s) would move the time the
    # fit enters a 0.01 deg/s band by tens of seconds, beyond the fit's own uncertainty
    "bias_instability_deg_per_h": 2.0,
    "rrw_deg_per_h_per_sqrt_h": 0.5,
}
TURN_ONS = 5


def test_turn_on_warm_up_and_second_order_fit_on_the_bench(tmp_path: Path) -> None:
    run = run_on_bench(
        tmp_path / "runs",
        [PART],
        speed=100,
        procedure=DATA / "turn_on_order2_stop.yaml",
        # no self-heating: the warm-up is then the part's warmup_drift alone (one exponential)
        sim_extra={"part_physics": {"self_heat_c_per_w": 0.0}},
    )
    folder = run.result.folders[1]
    rec = read_record(folder)
    assert rec.verdict is Verdict.PASS, rec.reason
    truth = run.final_truth["sockets"]["1"]
    by_name = {m.name: m for m in rec.measurements}

    # turn-on repeatability: the biases move with the offsets the bench drew at each power-on
    tor = rec.analysis.turn_on_repeatability["run"]
    # the warm-up step's power-on is the last one: the turn-ons are the ones before it
    offsets = np.array(truth["turn_on_history_dps"][-TURN_ONS - 1 : -1])
    biases = np.array(tor.biases_dps)
    assert biases.size == TURN_ONS
    assert np.std(biases - offsets) < 0.01
    rep = by_name["turn_on_bias_repeatability_dps"]
    assert rep.value is not None and rep.uncertainty_k2 is not None
    assert abs(rep.value - np.std(offsets, ddof=1)) < 0.01
    assert tor.resolved is True

    # warm-up: the bench's exponential enters the 0.01 deg/s band at tau ln(A / band)
    warm = by_name["warm_up_time_s"]
    expected_s = 40.0 * math.log(0.15 / 0.01)
    assert warm.value is not None and abs(warm.value - expected_s) < 0.25 * expected_s
    assert rec.analysis.warm_up["run"].settled_in_record is True

    # second-order fit: the curvature is found, programmed and read back
    cal = rec.calibration
    assert cal is not None and not cal.model_extra  # every key a declared field
    assert cal.fit_order == 2
    b2 = cal.bias_temp_coeff2_dps_per_c2
    assert b2 is not None
    assert abs(b2.value - PART["bias_temp_coeff2_dps_per_c2"]) <= 1.5 * b2.uncertainty_k2
    assert abs(b2.value) > b2.uncertainty_k2  # resolved, not noise
    s2 = cal.scale_temp_coeff2_per_c2
    assert s2 is not None
    assert abs(s2.value - PART["scale_temp_coeff2_per_c2"]) <= 1.5 * s2.uncertainty_k2
    assert cal.readback_ok and cal.readback is not None
    assert cal.readback["bias_tc2_dps_per_c2"] == truth["calibration"]["bias_tc2_dps_per_c2"]
    assert math.isclose(truth["calibration"]["bias_tc2_dps_per_c2"], b2.value, rel_tol=1e-6)
    assert rec.analysis.temperature_fit is not None
    assert len(rec.analysis.temperature_fit.points) == 6
    assert rec.verification is not None and rec.verification.max_error_pct is not None
    assert rec.verification.max_error_pct < 0.1

    text = pdf_text(render_certificate(folder))
    # the results table shows both new measurements with their values (the long name wraps in
    # its column: "turn_on_bias_repeatability" above the value, "_dps" below it)
    assert "turn_on_bias_repeatability" in text and f"{rep.value:.5g}" in text
    assert f"{warm.value:.5g}" in text
    for shown in ("warm_up_time_s",
                  "Temperature fit of bias and scale", "Second-order fit in temperature",
                  "bias_temp_coeff2_dps_per_c2", "scale_temp_coeff2_per_c2",
                  "Bias against die temperature", "T45_V5.25"):
        assert shown in text, shown
