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
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from procedures.runtime.record import RunRecord, read_record  # noqa: E402
from station.sim_run import run_simulated  # noqa: E402

HERE = Path(__file__).resolve().parent
SHIPPED = [ROOT / "config/procedures/eol-ramp.yaml",
           ROOT / "config/procedures/eol-rate-table.yaml",
           ROOT / "config/procedures/eol-stop-method.yaml"]
SERIAL = "SIM-0001"


def certificate_headings(folder: Path) -> list[str]:
    """The certificate's section headings (its H2 paragraphs), in order."""
    from reportlab.platypus import Flowable, Paragraph

    from reports.cert_inputs import load_inputs
    from reports.certificate import build_story

    out: list[str] = []

    def walk(items: list[Flowable]) -> None:
        for item in items:
            if isinstance(item, Paragraph) and item.style.name == "h2":
                out.append(item.getPlainText())
            inner = getattr(item, "_content", None)
            if isinstance(inner, list):
                walk(inner)

    walk(build_story(load_inputs(folder)))
    return out


def summary(rec: RunRecord, folder: Path) -> dict[str, Any]:
    """What must stay the same between the old and the new form of a procedure."""
    measured = sorted({(m.name, m.condition or "") for m in rec.measurements
                       if m.value is not None})
    cal = rec.calibration.model_dump(exclude_none=True) if rec.calibration else {}
    # the keys as record.json holds them (record format 2 types the sections; the JSON keys
    # are the same as format 1's)
    analysis = rec.analysis.model_dump(mode="json")
    verification = rec.verification.model_dump(mode="json") if rec.verification else {}
    return {
        "verdict": str(rec.verdict),
        "reason": rec.reason,
        "measurements": [list(x) for x in measured],
        "calibration_keys": sorted(cal),
        "analysis_keys": sorted(analysis),
        "analysis_condition_keys": {
            k: sorted(v) for k, v in analysis.items()
            if k in ("rate_table", "stop_method", "stability", "positions")
            and isinstance(v, dict)
        },
        "conditions": [c.name for c in rec.conditions],
        "verification_keys": sorted(verification),
        "certificate_headings": certificate_headings(folder),
    }


SPEED = 50.0  # slow enough for a loaded machine: a lost-frame ERROR makes no baseline


def run(procedure: Path, out: Path) -> dict[str, Any]:
    result, _ = run_simulated([{"socket": 1, "serial": SERIAL}], procedure_path=procedure,
                              out=out, speed=SPEED, certificate=True)
    folder = result.folders[1]
    return summary(read_record(folder), folder)


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
