"""Issue 26 finding 15: the hand-turned bench runs the article's whole method.

`station run --sim --station config/station-manual.yaml --dut SIM-0001`, as
docs/manual-stop.md shows it, runs eol-manual-stop at two temperatures x two supplies (the
simulated operator turns the fixture at each condition when prompted), fits the stop-method
scale and the bias, programs the part and verifies it with the fixture turned by hand again.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from procedures.loading.config import load_procedure
from procedures.steps.manual_stop import VerifyManualStop
from procedures.steps.registry import step_type
from tests.tools import need

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "manual-stop.md"
COMMAND = "station run --sim --station config/station-manual.yaml --dut SIM-0001"


def test_eol_manual_stop_is_the_2x2_with_fit_program_and_verify() -> None:
    procedure, _ = load_procedure(REPO / "config" / "procedures" / "eol-manual-stop.yaml")
    assert len(procedure.planned_conditions()) == 4
    assert len(set(procedure.conditions.temperatures_c)) == 2
    assert len(set(procedure.conditions.supplies_v)) == 2
    types = [e.type_name for e in procedure.entries()]
    assert types.index("manual_stop") < types.index("fit") < types.index("program") \
        < types.index("verify_manual_stop")
    assert procedure.settings_of("fit").source == "stop_method"
    assert step_type("verify_manual_stop") is VerifyManualStop
    assert COMMAND in DOC.read_text(encoding="utf-8")


def _station_command() -> list[str]:
    installed = Path(sys.executable).parent / "station"
    return [str(installed)] if installed.exists() else [sys.executable, "-m", "station"]


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_the_documented_manual_run_fits_programs_and_verifies(tmp_path: Path) -> None:
    # the command exactly as the doc gives it, from a copy of config/ (its runs go there)
    shutil.copytree(REPO / "config", tmp_path / "config",
                    ignore=shutil.ignore_patterns("signing", "*.sqlite"))
    proc = subprocess.run(
        _station_command() + COMMAND.split()[1:], cwd=tmp_path, capture_output=True,
        text=True, timeout=560,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "SIM-0001: PASS" in proc.stdout
    prompts = [ln for ln in proc.stdout.splitlines() if ln.startswith(">>> OPERATOR")]
    assert len(prompts) >= 4 * 4 + 4  # four moves at each of four conditions, four to verify
    folder = next((tmp_path / "runs").glob("*_SIM-0001"))
    record = json.loads((folder / "record.json").read_text(encoding="utf-8"))
    assert record["verdict"] == "PASS"
    # the 2 x 2, each condition's scale from the hand-turned stop method
    stops = record["analysis"]["stop_method"]
    assert len(stops) == 4 and all(s["method"] == "manual_stop" for s in stops.values())
    assert {round(c["supply_v"], 2) for c in record["conditions"]} == {4.75, 5.25}
    assert len({round(c["temperature_c"]) for c in record["conditions"]}) == 2
    # the fit, from the stop method, with its coefficients judged
    assert record["analysis"]["fit"]["source"] == "stop_method"
    cal = record["calibration"]
    for key in ("bias_dps", "bias_temp_coeff_dps_per_c", "bias_supply_coeff_dps_per_v",
                "scale", "scale_temp_coeff_per_c", "scale_supply_coeff_per_v"):
        assert cal[key]["uncertainty_k2"] > 0, key
    # programmed: written and read back
    assert cal["readback_ok"] is True and cal["readback"]
    # verified by hand on the compensated output
    judged = {m["name"]: m for m in record["measurements"]}
    assert judged["residual_scale_error"]["outcome"] in ("PASS", "MARGINAL")
    assert judged["residual_bias_dps"]["outcome"] in ("PASS", "MARGINAL")
    assert record["verification"]["method"] == "manual_stop"
    assert abs(record["verification"]["residuals"][0]["error_pct"]) < 0.05
    need("pdftotext")
    text = subprocess.run(["pdftotext", "-layout", str(folder / "certificate.pdf"), "-"],
                          capture_output=True, text=True, check=True).stdout
    assert "Calibration written to the part" in text
    assert "Verification after correction" in text and "verify@stop" in text
    assert "read-back PASSED" in " ".join(text.split())
