"""Lot report over 50 parts: yield and Cpk from the database match a direct count; simulated
runs are left out unless asked for."""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest

from procedures.runtime.record import Verdict
from reports import lot_stats
from reports.lot_report import render_lot_report
from station.results_db import ResultsDB
from tests.reports.conftest import pdf_pages, pdf_text
from tests.reports.lot_data import make_lot


@pytest.fixture(scope="module")
def lot(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list]:
    path = tmp_path_factory.mktemp("lot") / "results.sqlite"
    return path, make_lot(path, 50)


def _direct_cpk(values: list[float], low: float, high: float) -> float:
    mean = sum(values) / len(values)
    var = sum((v - mean) ** 2 for v in values) / (len(values) - 1)
    return min(high - mean, mean - low) / (3 * var**0.5)


def test_yield_and_cpk_equal_a_direct_computation(lot: tuple[Path, list], tmp_path: Path) -> None:
    path, records = lot
    out = tmp_path / "lot.pdf"
    summary = render_lot_report(ResultsDB(path), out)
    passed = sum(r.verdict == Verdict.PASS for r in records)
    failed = sum(r.verdict == Verdict.FAIL for r in records)
    assert 0 < failed < 50  # the population gives a real mix
    assert summary.yields.yield_fraction == pytest.approx(passed / (passed + failed), abs=0)
    caps = {c.name: c for c in summary.capabilities}
    for name in ("bias_dps", "scale", "arw_deg_per_sqrt_h"):
        values = [m.value for r in records for m in r.measurements if m.name == name]
        m0 = next(m for m in records[-1].measurements if m.name == name)
        assert caps[name].n == 50
        assert caps[name].cpk == pytest.approx(_direct_cpk(values, m0.low, m0.high), rel=1e-12)
    # and the PDF prints those same figures
    text = pdf_text(out)
    assert f"{passed / (passed + failed) * 100:.1f} %" in text
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("bias_dps "))
    assert f"{caps['bias_dps'].cpk:.3g}" in line.split()
    assert pdf_pages(out) == summary.pages >= 2


def test_pareto_counts_failing_runs_per_measurement(lot: tuple[Path, list], tmp_path: Path) -> None:
    path, records = lot
    summary = render_lot_report(ResultsDB(path), tmp_path / "lot.pdf")
    direct: dict[str, int] = {}
    for r in records:
        for name in r.failed_measurements:
            direct[name] = direct.get(name, 0) + 1
    assert dict(summary.pareto) == direct
    counts = [c for _n, c in summary.pareto]
    assert counts == sorted(counts, reverse=True)


def test_filters_reach_the_report_and_bytes_repeat(lot: tuple[Path, list], tmp_path: Path) -> None:
    path, records = lot
    db = ResultsDB(path)
    a, b = tmp_path / "a.pdf", tmp_path / "b.pdf"
    s = render_lot_report(db, a, issued=ISSUED, verdict="PASS", since="2026-11-22")
    render_lot_report(db, b, issued=ISSUED, verdict="PASS", since="2026-11-22")
    assert a.read_bytes() == b.read_bytes()
    expect = [r for r in records if r.verdict == Verdict.PASS and r.started_utc >= "2026-11-22"]
    assert s.yields.runs == len(expect) and s.yields.yield_fraction == 1.0
    assert "verdict = PASS" in pdf_text(a)


def test_empty_selection_still_gives_a_report(lot: tuple[Path, list], tmp_path: Path) -> None:
    path, _ = lot
    s = render_lot_report(ResultsDB(path), tmp_path / "none.pdf", product="NO-SUCH")
    assert s.yields.runs == 0 and s.yields.yield_fraction is None
    assert "No run matches the filters" in pdf_text(tmp_path / "none.pdf")


def test_cpk_definitions() -> None:
    assert lot_stats.cpk(0.0, 1.0, -3.0, 3.0) == pytest.approx(1.0)
    assert lot_stats.cpk(1.0, 1.0, -3.0, 3.0) == pytest.approx(2 / 3)
    assert lot_stats.cpk(1.0, 0.5, None, 4.0) == pytest.approx(2.0)  # upper only
    assert lot_stats.cpk(1.0, 0.5, -2.0, None) == pytest.approx(2.0)  # lower only
    assert lot_stats.cpk(1.0, 0.5, None, None) is None
    assert lot_stats.cpk(1.0, 0.0, 0.0, 2.0) is None  # no spread: undefined, not infinite
    assert np.isclose(lot_stats.cpk(5.0, 1.0, 0.0, 4.0), -1 / 3)  # mean outside: negative


def test_histograms_and_trend_are_in_the_report(lot: tuple[Path, list], tmp_path: Path) -> None:
    path, _ = lot
    render_lot_report(ResultsDB(path), tmp_path / "lot.pdf")
    text = pdf_text(tmp_path / "lot.pdf", layout=False)
    assert "bias_dps (deg/s)" in text and "Bias written to the part" in text
    assert "Scale written to the part" in text and "Failures by measurement" in text
    assert re.search(r"Sigma = sample standard deviation \(n - 1\)", re.sub(r"\s+", " ", text))


def test_capability_is_per_condition_not_pooled() -> None:
    from reports.lot_rows import MeasurementRow

    def row(run: str, cond: str, v: float) -> MeasurementRow:
        return MeasurementRow(run, "S", "2026-01-01T00:00:00+00:00", "PASS", "raw_bias_dps",
                              cond, v, "deg/s", -10.0, 10.0, "PASS")

    rows = [row(f"r{i}", c, v) for i, (c, v) in enumerate(
        [("T25", 1.0), ("T45", 5.0), ("T25", 1.2), ("T45", 5.4), ("T25", 0.8), ("T45", 4.6)])]
    keys = lot_stats.measurement_keys(rows)
    assert keys == [("raw_bias_dps", "T25"), ("raw_bias_dps", "T45")]
    cold = lot_stats.capability("raw_bias_dps", rows, "T25")
    hot = lot_stats.capability("raw_bias_dps", rows, "T45")
    assert cold.n == hot.n == 3
    assert cold.mean == pytest.approx(1.0) and hot.mean == pytest.approx(5.0)
    assert lot_stats.cpk(hot.mean, hot.sigma, hot.low, hot.high) == pytest.approx(
        (10 - 5.0) / (3 * 0.4))
    assert hot.cpk is None and hot.too_few  # three values: no Cpk on the report
    assert hot.label == "raw_bias_dps @ T45"


def test_a_lot_too_small_for_cpk_reads_too_few(tmp_path: Path) -> None:
    """Issue 26 finding 11: a Cpk of 182 was printed from two runs."""
    path = tmp_path / "results.sqlite"
    make_lot(path, lot_stats.MIN_CPK_N - 1)
    summary = render_lot_report(ResultsDB(path), tmp_path / "lot.pdf")
    assert all(c.cpk is None for c in summary.capabilities)
    text = pdf_text(tmp_path / "lot.pdf")
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("bias_dps "))
    assert f"too few (n < {lot_stats.MIN_CPK_N})" in re.sub(r"\s+", " ", line)


ISSUED = datetime(2026, 12, 1, 8, 15, 0, tzinfo=UTC)


def test_issued_is_when_the_report_was_made_not_the_newest_run(lot: tuple[Path, list],
                                                               tmp_path: Path) -> None:
    path, records = lot
    db = ResultsDB(path)
    a, b = tmp_path / "a.pdf", tmp_path / "b.pdf"
    render_lot_report(db, a, issued=ISSUED, product="ADIS16130-EOL")
    render_lot_report(db, b, issued=ISSUED, product="ADIS16130-EOL")
    assert a.read_bytes() == b.read_bytes()  # reproducible with the issue time given
    assert b"D:20261201081500+00'00'" in a.read_bytes()
    text = pdf_text(a)
    assert text.count("Issued 2026-12-01 08:15:00 UTC") == pdf_pages(a) + 1  # footers + page 1
    flat = re.sub(r"\s+", " ", text)
    assert (f"Filters: product = ADIS16130-EOL. Covers the {len(records)} run(s) they select"
            in flat)
    newest = max(r.finished_utc for r in records)
    assert f"newest finished {newest[:10]} {newest[11:19]} UTC" in flat
    # without an issue time: now, not the newest run's finish
    before = datetime.now(UTC).replace(microsecond=0)
    render_lot_report(db, b)
    after = datetime.now(UTC)
    stamp = re.search(r"Issued (\S+ \S+) UTC", pdf_text(b, page=1))
    assert stamp is not None
    issued = datetime.fromisoformat(stamp.group(1)).replace(tzinfo=UTC)
    assert before <= issued <= after


def test_one_run_lot_gives_short_notes_not_pages_of_boxes(tmp_path: Path) -> None:
    path = tmp_path / "one.sqlite"
    make_lot(path, 1)
    out = tmp_path / "one.pdf"
    summary = render_lot_report(ResultsDB(path), out, issued=ISSUED)
    text = re.sub(r"\s+", " ", pdf_text(out, layout=False))
    assert "value(s) in the lot." not in text  # no per-measurement box
    assert text.count("No histogram drawn") == 1
    assert "Not drawn: 1 completed run(s) with a start time" in text
    assert summary.pages == pdf_pages(out) == 1


def test_trend_falls_back_to_run_number_when_all_runs_share_a_start(tmp_path: Path) -> None:
    from reports.lot_report import trend_axis
    from tests.reports.synth_run import Part, make_record

    t0 = datetime(2026, 11, 21, 9, 30, tzinfo=UTC)
    xs, label = trend_axis([t0, t0, t0])
    assert xs == [1.0, 2.0, 3.0] and "run number" in label
    xs, label = trend_axis([t0, t0 + timedelta(minutes=30), t0 + timedelta(hours=2)])
    assert xs == [0.0, 0.5, 2.0] and label.startswith("hours since")
    # end to end: a batch started together (one fixture, several sockets)
    db = ResultsDB(tmp_path / "batch.sqlite")
    for i, bias in enumerate((1.0, 2.0, -1.5)):
        rec = make_record(Part(serial=f"BATCH-{i}", bias_dps=bias, started=t0, simulated=False))
        db.add_run(tmp_path / rec.run_id, rec)
    out = tmp_path / "batch.pdf"
    render_lot_report(db, out, issued=ISSUED)
    text = re.sub(r"\s+", " ", pdf_text(out, layout=False))
    assert "run number (all runs started 2026-11-21 09:30:00 UTC)" in text


def test_simulated_runs_are_left_out_unless_asked_for(tmp_path: Path) -> None:
    path = tmp_path / "results.sqlite"
    real = make_lot(path, 30, seed=3)
    sims = make_lot(path, 10, seed=4, start_index=30, simulated=True)
    db = ResultsDB(path)
    out = tmp_path / "lot.pdf"
    summary = render_lot_report(db, out, issued=ISSUED)
    assert summary.yields.runs == len(real)
    assert {c.n for c in summary.capabilities if c.name == "bias_dps"} == {len(real)}
    text = " ".join(pdf_text(out).split())
    assert f"{len(sims)} simulated run(s) left out" in text and "--include-simulated" in text
    both = render_lot_report(db, tmp_path / "all.pdf", issued=ISSUED, include_simulated=True)
    assert both.yields.runs == len(real) + len(sims)
    assert f"{len(sims)} of {len(real) + len(sims)} runs used the SIMULATED bench" in " ".join(
        pdf_text(tmp_path / "all.pdf").split())
