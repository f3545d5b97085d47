"""A lot of parts indexed in a results database (records only, no raw files): production
runs unless asked to come from the bench simulator."""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path

import numpy as np

from procedures.runtime.record import RunRecord
from station.results_db import ResultsDB
from tests.reports.synth_run import Part, make_record


def make_lot(db_path: Path, n: int, seed: int = 7, product: str = "ADIS16130-EOL",
             start_index: int = 0, simulated: bool = False) -> list[RunRecord]:
    """n parts drawn from the population (bias sigma 4 deg/s, scale sigma 2 %), 35 min apart."""
    rng = np.random.default_rng(seed)
    db = ResultsDB(db_path)
    base = Part().started
    records = []
    for i in range(start_index, start_index + n):
        part = Part(
            serial=f"LOT-{i:05d}",
            bias_dps=float(rng.normal(0.0, 4.0)),
            scale=float(1.0 + rng.normal(0.0, 0.02)),
            bias_temp_coeff_dps_per_c=float(rng.uniform(0.005, 0.01)),
            scale_temp_coeff_per_c=float(rng.uniform(1e-4, 3e-4)),
            arw_deg_per_sqrt_h=float(rng.uniform(0.3, 2.6)),
            started=base + timedelta(minutes=35 * i),
            product=product,
            simulated=simulated,
        )
        record = make_record(part)
        db.add_run(db_path.parent / record.run_id, record)
        records.append(record)
    return records
