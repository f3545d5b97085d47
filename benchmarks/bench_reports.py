"""Time to render one certificate and a 500-part lot report.

    python3 benchmarks/bench_reports.py [--run-folder PATH] [--parts 500] [--repeat 5]

Without --run-folder a realistic synthetic run folder (4 conditions, ~30k samples) is built
in a temporary folder and the lot is drawn from the synthetic population (6 measurements per
run); with --run-folder (e.g. one from `station demo`) the certificate is that folder's and
the lot is 500 copies of its record with the values spread. Target: under 2 s a certificate.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from datetime import datetime, timedelta
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from procedures.runtime.record import read_record  # noqa: E402
from reports.certificate import certificate_bytes  # noqa: E402
from reports.lot_report import render_lot_report  # noqa: E402
from reports.pdfdoc import page_count  # noqa: E402
from station.results_db import ResultsDB  # noqa: E402
from tests.reports.lot_data import make_lot  # noqa: E402
from tests.reports.synth_run import Part, make_run  # noqa: E402


def timed(fn, repeat: int) -> tuple[float, float, object]:  # type: ignore[no-untyped-def]
    times, result = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), max(times), result


def lot_from_template(db_path: Path, folder: Path, parts: int) -> None:
    """`parts` copies of a real run's record, values spread by 1 % of their limit span."""
    rng = np.random.default_rng(11)
    template = read_record(folder)
    db = ResultsDB(db_path)
    start = datetime.fromisoformat(template.started_utc)
    for i in range(parts):
        ms = []
        for m in template.measurements:
            span = (m.high - m.low) if m.low is not None and m.high is not None else 1.0
            v = None if m.value is None else m.value + float(rng.normal(0, 0.05 * span))
            ms.append(m.model_copy(update={"value": v}))
        rec = template.model_copy(update={
            "run_id": f"{template.run_id}-{i:04d}", "measurements": ms,
            "dut": template.dut.model_copy(update={"serial": f"TPL-{i:04d}"}),
            "started_utc": (start + timedelta(minutes=30 * i)).isoformat()})
        db.add_run(folder, rec)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run-folder", type=Path, help="a real run folder to render")
    ap.add_argument("--parts", type=int, default=500)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        folder = args.run_folder
        if folder is None:
            folder, _ = make_run(root, Part(serial="BENCH-1", bias_dps=12.5))
        med, worst, pdf = timed(lambda: certificate_bytes(folder), args.repeat)
        assert isinstance(pdf, bytes)
        print(f"certificate: median {med:.3f} s, worst {worst:.3f} s over {args.repeat} renders, "
              f"{page_count(pdf)} pages, {len(pdf) / 1024:.0f} KiB  (target < 2 s)")
        db_path = root / "results.sqlite"
        t0 = time.perf_counter()
        if args.run_folder is not None:
            lot_from_template(db_path, args.run_folder, args.parts)
        else:
            make_lot(db_path, args.parts)
        index_s = time.perf_counter() - t0
        print(f"results db: indexed {args.parts} runs in {index_s:.2f} s "
              f"({index_s / args.parts * 1000:.1f} ms per run)")
        db = ResultsDB(db_path)
        med, worst, summary = timed(lambda: render_lot_report(db, root / "lot.pdf"),
                                    max(1, args.repeat // 2))
        print(f"lot report ({args.parts} parts): median {med:.3f} s, worst {worst:.3f} s, "
              f"{summary.pages} pages, yield {summary.yields.yield_fraction * 100:.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
