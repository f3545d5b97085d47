"""Issue 26 finding 12: the stop-vs-table consistency judgement.

The per-condition |E_n| limit is derived from the product's per-part false-reject rate and
the procedure's number of judgements (Sidak), and a part that fails only that judgement has
the condition's stop moves measured once more before its verdict, recorded as such.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
import yaml

from common.yaml_input import ConfigError
from procedures.analysis.consistency import (
    part_false_reject_rate,
    per_condition_limit,
    per_condition_rate,
)
from procedures.loading.config import load_procedure, load_product, product_for_procedure
from procedures.runtime.record import Outcome, Verdict, read_record
from reports.cert_inputs import load_inputs
from reports.cert_remeasured import remeasured
from station.sim_run import run_simulated
from tests.tools import need

ROOT = Path(__file__).resolve().parents[2]
GYR130 = ROOT / "config" / "products" / "gyr130.yaml"
RATE_TABLE_PROC = ROOT / "config" / "procedures" / "eol-rate-table.yaml"


# ------------------------------------------------------------ the threshold derivation


def test_per_condition_limit_holds_the_part_rate_over_all_its_conditions() -> None:
    # 0.1 % of good parts over four conditions: 2.5e-4 per condition, |E_n| <= 3.662
    assert per_condition_rate(0.001, 4) == pytest.approx(1 - 0.999 ** 0.25, rel=1e-12)
    assert per_condition_limit(0.001, 4) == pytest.approx(3.6622, abs=1e-3)
    # one condition: the two-tailed normal quantile (0.27 % -> 3.0)
    assert per_condition_limit(0.0026998, 1) == pytest.approx(3.0, abs=1e-4)
    # the inverse: the old fixed 3 rejected 1.08 % of good parts over the 2 x 2
    assert part_false_reject_rate(3.0, 4) == pytest.approx(0.010766, rel=1e-3)
    for rate, n in ((0.001, 4), (0.01, 8), (1e-5, 32)):
        assert part_false_reject_rate(per_condition_limit(rate, n), n) == pytest.approx(rate)
    # more conditions: a wider limit for the same per-part rate
    assert per_condition_limit(0.001, 8) > per_condition_limit(0.001, 4)


def test_a_rate_outside_zero_and_one_is_refused() -> None:
    with pytest.raises(ValueError):
        per_condition_rate(0.0, 4)
    with pytest.raises(ValueError):
        per_condition_rate(0.001, 0)


def test_gyr130_derives_its_consistency_limit_for_the_procedure() -> None:
    product, _ = load_product(GYR130)
    assert product.consistency is not None
    assert product.limits.stop_table_consistency is None  # derived, not fixed
    procedure, _ = load_procedure(RATE_TABLE_PROC)
    limit = product_for_procedure(product, procedure).limits.stop_table_consistency
    assert limit is not None
    k = per_condition_limit(product.consistency.false_reject_rate, 4)
    assert (limit.low, limit.high) == (pytest.approx(-k), pytest.approx(k))
    assert limit.high > 3.0  # wider than the fixed 3 that rejected ~1 % of good parts
    assert part_false_reject_rate(limit.high, 4) == pytest.approx(0.001)
    assert limit.marginal_high is not None and 2.0 < limit.marginal_high < limit.high


def _product_text(**changes: object) -> str:
    data = yaml.safe_load(GYR130.read_text(encoding="utf-8"))
    for key, value in changes.items():
        if key == "limits":
            data["limits"].update(value)  # type: ignore[arg-type]
        elif value is None:
            data.pop(key, None)
        else:
            data[key] = value
    return yaml.safe_dump(data, sort_keys=False)


def test_both_a_rate_and_a_fixed_limit_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "both.yaml"
    path.write_text(_product_text(limits={"stop_table_consistency": {"low": -3, "high": 3}}),
                    encoding="utf-8")
    with pytest.raises(ConfigError, match="consistency"):
        load_product(path)


# ------------------------------------------------------------ the second measurement

ONE_CONDITION = """
name: consistency-one-condition
version: "1.0"
product: {product}
output_rate_hz: 100
conditions: {{temperatures_c: [25.0], supplies_v: [5.0], order: as_listed}}
chamber: {{ramp_c_per_min: 5.0, safe_temp_c: 25.0}}
steps:
  - step: power_identify
  - for_each: condition
    steps:
      - step: thermal
        window_s: 30
        slope_c_per_min: 0.3
        band_c: 0.3
        stability_timeout_s: 2400
      - step: bias
        dwell_s: 10
      - step: rate_table
        rates_dps: [50, -50, 200, -200]
        plateau_dwell_s: 4
      - step: stop_method
        static_s: 5
"""


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_part_failing_only_consistency_is_measured_once_more_and_recorded(
    tmp_path: Path,
) -> None:
    # a limit no honest E_n meets (|E_n| <= 0.001): the first judgement fails, alone
    product = tmp_path / "tight.yaml"
    product.write_text(_product_text(
        consistency=None, limits={"stop_table_consistency": {"low": -0.001, "high": 0.001}}),
        encoding="utf-8")
    proc = tmp_path / "one.yaml"
    proc.write_text(ONE_CONDITION.format(product=product), encoding="utf-8")
    result, _ = run_simulated([{"socket": 1, "serial": "SIM-8101"}], procedure_path=proc,
                              out=tmp_path / "runs", certificate=True)
    folder = result.folders[1]
    rec = read_record(folder)
    cond = "T25_V5"
    judged = [m for m in rec.measurements if m.name == "stop_table_consistency"]
    assert len(judged) == 1, "the second judgement stands alone on the record"
    second = judged[0]
    assert second.condition is not None and second.condition.startswith("T25")
    cond = second.condition
    assert "measured again" in second.description
    again = rec.analysis.remeasured
    assert len(again) == 1, "measured once more, not again and again"
    entry = again[0]
    assert entry.measurement == "stop_table_consistency" and entry.condition == cond
    assert entry.first is not None and entry.second is not None
    assert entry.first.outcome == "FAIL"
    assert entry.first.value is not None and abs(entry.first.value) > 0.001
    assert entry.second.value == second.value
    assert entry.first.value != second.value  # a new measurement, not a copy
    # one second measurement, said on the record
    moves = [e for e in rec.events if "measured once more" in e.message]
    assert len(moves) == 1
    # the verdict is the second judgement's
    if second.outcome is Outcome.FAIL:
        assert rec.verdict is Verdict.FAIL
        assert rec.failed_measurements == [f"stop_table_consistency@{cond}"]
    else:
        assert rec.verdict is Verdict.PASS
    # the certificate says so
    lines = [p.getPlainText() for p in remeasured(load_inputs(folder))]
    assert len(lines) == 1 and "Measured again: stop_table_consistency" in lines[0]
    need("pdftotext")
    text = subprocess.run(["pdftotext", str(folder / "certificate.pdf"), "-"],
                          capture_output=True, text=True, check=True).stdout
    assert "Measured again" in " ".join(text.split())


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_part_with_another_failure_is_not_measured_again(tmp_path: Path) -> None:
    """Only a lone consistency failure earns the second measurement: with the bias also
    failing (a limit no part meets) the part is FAIL on its first judgement."""
    product = tmp_path / "tight2.yaml"
    product.write_text(_product_text(
        consistency=None, limits={"stop_table_consistency": {"low": -0.001, "high": 0.001},
                                  "raw_bias_dps": {"low": 50.0, "high": 60.0}}),
        encoding="utf-8")
    proc = tmp_path / "one.yaml"
    proc.write_text(ONE_CONDITION.format(product=product), encoding="utf-8")
    result, _ = run_simulated([{"socket": 1, "serial": "SIM-8101"}], procedure_path=proc,
                              out=tmp_path / "runs")
    rec = read_record(result.folders[1])
    assert rec.analysis.remeasured == []
    assert rec.verdict is Verdict.FAIL
    assert any(f.startswith("stop_table_consistency@") for f in rec.failed_measurements)
    assert not any("measured once more" in e.message for e in rec.events)
