"""QA findings on `station analyze`: each test fails without its fix."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from procedures.analysis.stop_method import analyze_stop_method
from station.cli.main import main
from tests.analysis.synth import article_record, gyro_noise, raised_cosine


def _write(path: Path, columns: dict[str, np.ndarray]) -> Path:
    names = list(columns)
    rows = np.column_stack([columns[n] for n in names])
    np.savetxt(path, rows, delimiter=",", header=",".join(names), comments="", fmt="%.9g")
    return path


def test_disagreeing_moves_are_flagged_and_uncertainty_widened(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t, y = article_record(np.random.default_rng(5), out_deg=95.1, back_deg=-63.43)
    csv_path = _write(tmp_path / "r.csv", {"time_s": t, "rate_dps": y})
    assert main(["analyze", "stop-method", str(csv_path), "--json"]) == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    corrs = [m["scale_correction"] for m in doc["moves"]]
    assert corrs == pytest.approx([0.946, 1.419], abs=2e-3)
    assert doc["moves_consistent"] is False
    assert doc["birge_ratio"] > 10
    assert any("MOVES DISAGREE" in w for w in doc["warnings"])
    assert "MOVES DISAGREE" in captured.err
    # honest: the mean's uncertainty covers the scatter of the moves
    assert doc["u_scale_correction"] > 0.5 * abs(corrs[0] - corrs[1]) / 2
    assert main(["analyze", "stop-method", str(csv_path)]) == 0
    assert "MOVES DISAGREE" in capsys.readouterr().out


def test_agreeing_moves_are_consistent() -> None:
    t, y = article_record(np.random.default_rng(6), out_deg=95.2, back_deg=-95.2)
    r = analyze_stop_method(t, y)
    assert r.moves_consistent is True
    assert not any("DISAGREE" in w for w in r.warnings)


def test_over_range_checked_against_rated_range_by_default(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t = np.arange(0.0, 21.0, 0.01)
    # 0.5 s moves of 95 deg: peaks near 380 deg/s, beyond the +/-250 rated range
    y = 8.6 + raised_cosine(t, 4.5, 0.5, 95.1) + raised_cosine(t, 12.5, 0.5, -95.3)
    y = y + 0.02 * np.random.default_rng(7).standard_normal(t.size)
    csv_path = _write(tmp_path / "r.csv", {"time_s": t, "rate_dps": y})
    assert main(["analyze", "stop-method", str(csv_path), "--json"]) == 2
    err = capsys.readouterr().err
    assert "over-range" in err and "--full-scale" in err
    # overriding the full scale for a wider-range part accepts the moves
    assert main(["analyze", "stop-method", str(csv_path), "--json", "--full-scale", "500"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["n_over_range"] == 0


def test_json_names_its_uncertainty_coverage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t, y = article_record(np.random.default_rng(8))
    csv_path = _write(tmp_path / "r.csv", {"time_s": t, "rate_dps": y})
    assert main(["analyze", "stop-method", str(csv_path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["uncertainty_coverage"] == "k=1 (standard)"
    assert doc["u_scale_correction_k2"] == pytest.approx(2 * doc["u_scale_correction"])
    assert {"bias_dps", "bias_correction_dps", "moves", "scale_correction"} <= doc.keys()


def test_non_monotonic_time_error_prints_plain_numbers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t = np.arange(0.0, 20.0, 0.01)
    t[500], t[501] = t[501], t[500]
    csv_path = _write(tmp_path / "r.csv", {"time_s": t, "rate_dps": np.ones_like(t)})
    assert main(["analyze", "stop-method", str(csv_path)]) == 2
    err = capsys.readouterr().err
    assert "np.float64" not in err
    assert "(5.01 then 5)" in err


def test_allan_unresolved_terms_are_null_with_upper_bounds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(9)
    y = 8.6 + gyro_noise(rng, 6_000, 100.0, arw_deg_per_sqrt_h=0.6)  # white only, 60 s
    csv_path = _write(tmp_path / "a.csv", {"time_s": np.arange(y.size) / 100.0, "rate_dps": y})
    assert main(["analyze", "allan", str(csv_path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["flat_region_s"] is None and doc["rrw_region_s"] is None
    assert doc["bias_instability_deg_per_h"] is None
    assert doc["bias_instability_resolved"] is False
    assert doc["bias_instability_upper_bound_deg_per_h"] > 0
    assert doc["rrw_deg_per_h_per_sqrt_h"] is None
    assert doc["rrw_upper_bound_deg_per_h_per_sqrt_h"] > 0
    assert doc["record_static"] is True and doc["warnings"] == []
    assert main(["analyze", "allan", str(csv_path)]) == 0
    out = capsys.readouterr().out
    assert "rate random walk    not resolved in this record: at most" in out


def test_allan_warns_on_a_record_with_moves(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t, y = article_record(np.random.default_rng(10))
    csv_path = _write(tmp_path / "m.csv", {"time_s": t, "rate_dps": y})
    assert main(["analyze", "allan", str(csv_path), "--json"]) == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert doc["record_static"] is False
    assert "not static" in captured.err and "static record" in captured.err
    assert any("not static" in w for w in doc["warnings"])
    assert main(["analyze", "allan", str(csv_path)]) == 0
    assert "WARNING: the record is not static" in capsys.readouterr().out


def test_allan_gap_message_names_the_gap_and_median_step(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t = np.concatenate([np.arange(0.0, 10.0, 0.01), np.arange(20.0, 30.0, 0.01)])
    y = 8.6 + 0.01 * np.random.default_rng(11).standard_normal(t.size)
    csv_path = _write(tmp_path / "g.csv", {"time_s": t, "rate_dps": y})
    assert main(["analyze", "allan", str(csv_path)]) == 2
    err = capsys.readouterr().err
    assert "step of 10.01 s from t = 9.99 s to t = 20 s" in err
    assert "median step is 0.01 s" in err
