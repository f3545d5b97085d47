from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from station.cli.main import main
from tests.analysis.synth import article_record, gyro_noise

REPO = Path(__file__).resolve().parents[2]
STOP_KEYS = {"bias_dps", "bias_correction_dps", "moves", "scale_correction"}
MOVE_KEYS = {"start_s", "end_s", "measured_angle_deg", "scale_correction"}
ALLAN_KEYS = {"tau_s", "adev_dps", "arw_deg_per_sqrt_h", "bias_instability_deg_per_h"}


def _write(path: Path, columns: dict[str, np.ndarray]) -> Path:
    names = list(columns)
    rows = np.column_stack([columns[n] for n in names])
    np.savetxt(path, rows, delimiter=",", header=",".join(names), comments="", fmt="%.9g")
    return path


def test_article_worked_example_through_the_station_cli(tmp_path: Path) -> None:
    t, y = article_record(np.random.default_rng(0))
    csv_path = _write(tmp_path / "fig4.csv", {"time_s": t, "rate_dps": y})
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    out = subprocess.run(
        [sys.executable, "-m", "station", "analyze", "stop-method", str(csv_path),
         "--reference-angle", "90", "--json"],
        capture_output=True, text=True, cwd=REPO, env=env, timeout=60,
    )
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    assert doc.keys() >= STOP_KEYS
    assert all(m.keys() >= MOVE_KEYS for m in doc["moves"])
    assert round(doc["bias_correction_dps"], 1) == -8.6
    assert [round(m["scale_correction"], 3) for m in doc["moves"]] == [0.946, 0.944]
    assert [round(m["measured_angle_deg"], 1) for m in doc["moves"]] == [95.1, -95.3]
    assert round(doc["scale_correction"], 3) == 0.945


def test_stop_method_table_is_readable(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    t, y = article_record(np.random.default_rng(1))
    csv_path = _write(tmp_path / "r.csv", {"time_s": t, "rate_dps": y})
    assert main(["analyze", "stop-method", str(csv_path)]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("bias correction"))
    assert round(float(line.split()[2]), 1) == -8.6
    assert "scale correction    0.945" in out


def test_clipped_moves_give_no_scale_and_exit_non_zero(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t, y = article_record(np.random.default_rng(2))
    status = (np.abs(y) > 40).astype(int)  # both moves over-range
    csv_path = _write(tmp_path / "r.csv", {"time_s": t, "rate_dps": y, "status": status})
    assert main(["analyze", "stop-method", str(csv_path), "--json"]) == 2
    err = capsys.readouterr().err
    assert "over-range" in err and "rotate more slowly" in err


def test_allan_json_keys_and_values(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(3)
    y = 8.6 + gyro_noise(rng, 60_000, 100.0, arw_deg_per_sqrt_h=0.6)
    csv_path = _write(tmp_path / "a.csv", {"time_s": np.arange(y.size) / 100.0, "rate_dps": y})
    assert main(["analyze", "allan", str(csv_path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc.keys() >= ALLAN_KEYS
    assert len(doc["tau_s"]) == len(doc["adev_dps"]) >= 10
    assert doc["arw_deg_per_sqrt_h"] == pytest.approx(0.6, rel=0.05)
    assert main(["analyze", "allan", str(csv_path)]) == 0
    assert "angle random walk" in capsys.readouterr().out


def _bad(tmp_path: Path, kind: str) -> Path:
    t = np.arange(0.0, 20.0, 0.01)
    y = 8.6 + np.zeros_like(t)
    p = tmp_path / f"{kind}.csv"
    if kind == "missing_column":
        return _write(p, {"time_s": t, "gyro": y})
    if kind == "non_monotonic":
        t = t.copy()
        t[500], t[501] = t[501], t[500]
    if kind == "short":
        t, y = t[:5], y[:5]
    if kind == "nan":
        y = y.copy()
        y[100] = np.nan
    if kind == "text":
        p.write_text("time_s,rate_dps\n0,1\n0.01,abc\n")
        return p
    return _write(p, {"time_s": t, "rate_dps": y})


@pytest.mark.parametrize(
    ("kind", "needle"),
    [
        ("missing_column", "missing column(s) rate_dps"),
        ("non_monotonic", "not increasing"),
        ("short", "too short"),
        ("nan", "NaN"),
        ("text", "not a number"),
    ],
)
@pytest.mark.parametrize("command", ["stop-method", "allan"])
def test_bad_input_exits_non_zero_naming_the_problem(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], kind: str, needle: str, command: str
) -> None:
    path = _bad(tmp_path, kind)
    assert main(["analyze", command, str(path)]) == 2
    err = capsys.readouterr().err
    assert needle in err
    assert "Traceback" not in err


def test_missing_file(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["analyze", "allan", str(tmp_path / "none.csv")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_uneven_sampling_is_refused_for_allan(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t = np.arange(0.0, 20.0, 0.01)
    t = np.delete(t, np.arange(300, 320))  # a lost block of samples
    path = _write(tmp_path / "gap.csv", {"time_s": t, "rate_dps": np.ones_like(t)})
    assert main(["analyze", "allan", str(path)]) == 2
    assert "not evenly spaced" in capsys.readouterr().err


def test_stop_method_trims_motion_at_the_start_with_a_warning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A hand-cut record that begins in the tail of a move is used from the end of that move,
    with a warning, as the station's stop step does; the result is the clean record's."""
    t, y = article_record(np.random.default_rng(8))
    tail = t < 1.0
    moving = y.copy()
    moving[tail] += 40.0 * (1.0 - t[tail])  # decelerating from 40 deg/s to rest in 1 s
    clean_csv = _write(tmp_path / "clean.csv", {"time_s": t[~tail], "rate_dps": y[~tail]})
    cut_csv = _write(tmp_path / "cut.csv", {"time_s": t, "rate_dps": moving})
    assert main(["analyze", "stop-method", str(clean_csv), "--json"]) == 0
    clean = json.loads(capsys.readouterr().out)
    assert main(["analyze", "stop-method", str(cut_csv), "--json"]) == 0
    out = capsys.readouterr()
    doc = json.loads(out.out)
    assert "warning: the record began in motion" in out.err
    assert any("began in motion" in w for w in doc["warnings"])
    assert len(doc["moves"]) == 2
    assert doc["scale_correction"] == pytest.approx(clean["scale_correction"], abs=2e-4)
    assert doc["bias_dps"] == pytest.approx(clean["bias_dps"], abs=0.01)
    # with no move after the leading motion the record is still refused, naming why
    early = t < 4.0
    short_csv = _write(tmp_path / "short.csv", {"time_s": t[early], "rate_dps": moving[early]})
    assert main(["analyze", "stop-method", str(short_csv)]) == 2
    assert "at rest" in capsys.readouterr().err
