"""How results-schema1.sqlite was made: today's (pre-SQLAlchemy) results_db.py of commit
f9d8c3e, saved as OLD_MODULE, indexing 12 synthetic runs (3 serials retested, one run marked
ERROR). Kept for the record; the test uses the committed file.

    git show f9d8c3e:station/results_db.py > /tmp/old_results_db.py
    .venv/bin/python tests/linedb/data/make_schema1.py /tmp/old_results_db.py
"""

from __future__ import annotations

import importlib.util
import sys
from datetime import timedelta
from pathlib import Path

import numpy as np

from tests.reports.synth_run import Part, make_record


def main(old_module: str) -> None:
    spec = importlib.util.spec_from_file_location("old_results_db", old_module)
    assert spec is not None and spec.loader is not None
    old = importlib.util.module_from_spec(spec)
    sys.modules["old_results_db"] = old
    spec.loader.exec_module(old)
    out = Path(__file__).parent / "results-schema1.sqlite"
    out.unlink(missing_ok=True)
    db = old.ResultsDB(out)
    rng = np.random.default_rng(3)
    base = Part().started
    rec = None
    for i in range(12):
        part = Part(serial=f"V1-{i % 9:03d}", bias_dps=float(rng.normal(0, 4)),
                    scale=float(1 + rng.normal(0, 0.02)), started=base + timedelta(minutes=30 * i))
        rec = make_record(part)
        db.add_run(Path("/runs") / rec.run_id, rec)
    assert rec is not None
    db.mark_error(rec.run_id, "station stopped during the run")


if __name__ == "__main__":
    main(sys.argv[1])
