"""Make the baseline summaries of the shipped procedures on the simulated bench.

Run once with the code *before* a change to the procedure engine; the summaries written here
(measurement names, calibration and analysis keys, certificate section headings) are what
tests/procedures/test_baseline_records.py compares a run of the new code against.

    .venv/bin/python tests/data/baseline/make_baseline.py [PROCEDURE.yaml ...]

The part is fixed (serial SIM-0001, parameters drawn from its serial), so a run is repeatable
up to the bench's noise; only names and keys are compared, never values.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from procedures.record import RunRecord, read_record  # noqa: E402
from station.uut import run_simulated  # noqa: E402

HERE = Path(__file__).resolve().parent
SHIPPED = [ROOT / "config/procedures/eol-rate-table.yaml",
           ROOT / "config/procedures/eol-stop-method.yaml"]
SERIAL = "SIM-0001"


def certificate_headings(pdf: Path) -> list[str]:
    """Section headings of a certificate: its lines that are a known heading."""
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True,
                          text=True, check=True).stdout
    return [line.strip() for line in text.splitlines() if line.strip() in HEADINGS]


HEADINGS = {"Traceability", "Test conditions", "Results", "Calibration coefficients",
            "Verification", "Plots", "Stop method", "Rate table", "Allan deviation",
            "Thermal stabilisation", "Sign-off"}


def summary(rec: RunRecord, pdf: Path | None) -> dict[str, Any]:
    """What must stay the same between the old and the new form of a procedure."""
    measured = sorted({(m.name, m.condition or "") for m in rec.measurements
                       if m.value is not None})
    cal = rec.calibration.model_dump(exclude_none=True) if rec.calibration else {}
    return {
        "verdict": str(rec.verdict),
        "measurements": [list(x) for x in measured],
        "calibration_keys": sorted(cal),
        "analysis_keys": sorted(rec.analysis),
        "analysis_condition_keys": {
            k: sorted(v) for k, v in rec.analysis.items()
            if k in ("rate_table", "stop_method", "stability", "positions")
            and isinstance(v, dict)
        },
        "conditions": [c.name for c in rec.conditions],
        "verification_keys": sorted(rec.verification or {}),
        "certificate_headings": certificate_headings(pdf) if pdf else [],
    }


SPEED = 50.0  # slow enough for a loaded machine: a lost-frame ERROR makes no baseline


def run(procedure: Path, out: Path) -> dict[str, Any]:
    result, _ = run_simulated([{"socket": 1, "serial": SERIAL}], procedure_path=procedure,
                              out=out, speed=SPEED, certificate=True)
    folder = result.folders[1]
    return summary(read_record(folder), result.certificates.get(1))


def main(paths: list[Path]) -> None:
    for path in paths or SHIPPED:
        with tempfile.TemporaryDirectory() as tmp:
            data = run(path, Path(tmp))
        target = HERE / f"{path.stem}.json"
        target.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
        print(f"{path.name}: {data['verdict']}, {len(data['measurements'])} measurements "
              f"-> {target}")


if __name__ == "__main__":
    main([Path(p) for p in sys.argv[1:]])
