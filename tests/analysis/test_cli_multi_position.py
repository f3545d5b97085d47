"""`station analyze multi-position`: pinned JSON keys, the table, and bad input (exit 2)."""

from __future__ import annotations

import functools
import io
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from station.cli.main import main
from station.cli.multi_position import read_sections
from station.errors import UserError
from tests.analysis.hand_turned import Session, hand_turned_session, random_truth

PINNED = (
    "gyro_bias_dps",
    "gyro_matrix",
    "gyro_g_sensitivity_dps_per_mps2",
)


@functools.cache
def _session(seed: int = 30) -> Session:
    rng = np.random.default_rng(seed)
    return hand_turned_session(rng, random_truth(rng))


@functools.cache
def _csv_text(seed: int, accel: bool) -> str:
    s = _session(seed)
    names = ["gyr_x", "gyr_y", "gyr_z"]
    cols = [s.gyro_dps]
    if accel:
        names += ["acc_x", "acc_y", "acc_z"]
        cols.append(s.accel_mps2)
    out = io.StringIO()
    np.savetxt(out, np.column_stack(cols), delimiter=",", header=",".join(names),
               comments="", fmt="%.10g")
    return out.getvalue()


def _files(
    tmp_path: Path, seed: int, *, accel: bool = True, sections: object = None
) -> tuple[Path, Path]:
    s = _session(seed)
    csv_path = tmp_path / "session.csv"
    csv_path.write_text(_csv_text(seed, accel))
    sec_path = tmp_path / "sections.json"
    if sections is None:
        sections = {k: {"start": a, "end": b} for k, (a, b) in s.sections.items()}
    sec_path.write_text(json.dumps(sections))
    return csv_path, sec_path


def _run(csv_path: Path, sec_path: Path, *extra: str) -> int:
    return main(["analyze", "multi-position", str(csv_path), "--sections", str(sec_path),
                 "--rate-hz", "100", *extra])


def test_json_keys_and_values_match_the_truth(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = _session(30)
    assert _run(*_files(tmp_path, 30), "--json") == 0
    doc = json.loads(capsys.readouterr().out)
    for key in PINNED:
        assert key in doc and key + "_uncertainty_k2" in doc
    b, u_b = np.array(doc["gyro_bias_dps"]), np.array(doc["gyro_bias_dps_uncertainty_k2"])
    m, u_m = np.array(doc["gyro_matrix"]), np.array(doc["gyro_matrix_uncertainty_k2"])
    g = np.array(doc["gyro_g_sensitivity_dps_per_mps2"])
    u_g = np.array(doc["gyro_g_sensitivity_dps_per_mps2_uncertainty_k2"])
    assert b.shape == (3,) and m.shape == (3, 3) and g.shape == (3, 3)
    # a handful of 21 values may fall outside k=2 by chance; most must not, and none far
    z = np.concatenate([
        (b - s.truth.bias_dps) / u_b,
        ((m - s.truth.matrix) / u_m).ravel(),
        ((g - s.truth.g_sensitivity) / u_g).ravel(),
    ])
    assert np.mean(np.abs(z) <= 2) >= 0.8 and np.abs(z).max() < 4
    assert doc["g_sensitivity_estimated"] is True
    assert doc["uncertainty_coverage"] == "k=2"


def test_without_accelerometer_g_keys_are_null_and_it_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = _session(31)
    assert _run(*_files(tmp_path, 31, accel=False), "--json") == 0
    out = capsys.readouterr()
    doc = json.loads(out.out)
    assert doc["gyro_g_sensitivity_dps_per_mps2"] is None
    assert doc["gyro_g_sensitivity_dps_per_mps2_uncertainty_k2"] is None
    assert doc["g_sensitivity_estimated"] is False
    assert "G is not estimated" in out.err
    assert np.allclose(doc["gyro_matrix"], s.truth.matrix, atol=5e-4)
    assert _run(*_files(tmp_path, 31, accel=False)) == 0
    assert "g-sensitivity G: not estimated" in capsys.readouterr().out


def test_table_for_people(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    s = _session(32)
    assert _run(*_files(tmp_path, 32)) == 0
    out = capsys.readouterr().out
    assert "w_hat = M (raw - b - G a)" in out
    row = next(ln for ln in out.splitlines() if ln.strip().startswith("x ") and "+/-" in ln)
    m_xx = float(row.split()[1])
    assert m_xx == pytest.approx(s.truth.matrix[0, 0], abs=5e-4)
    assert "G (deg/s per m/s^2)" in out


def _corrupt_csv(path: Path, line: int, text: str) -> None:
    rows = path.read_text().splitlines()
    rows[line - 1] = text
    path.write_text("\n".join(rows) + "\n")


@pytest.mark.parametrize(
    ("case", "needle"),
    [
        ("missing_section", "section(s) y_rot missing"),
        ("unknown_section", "unknown section 'x_rotation'"),
        ("out_of_range", "section z_a: start"),
        ("bad_index", "x_p.start"),
        ("not_json", "not valid JSON"),
        ("missing_column", "missing column(s) gyr_z"),
        ("partial_accel", "not acc_z"),
        ("nan", "line 11, column gyr_y"),
        ("text", "not a number"),
        ("units", "check the units"),
        ("rate", "--rate-hz must be"),
        ("angle", "--rotation-deg must be"),
        ("wrong_sign", "give the angle as 360 deg"),
        ("no_sections_file", "no such file"),
        ("rate_mismatch", "time_s steps by 0.01 s (100 Hz) but --rate-hz is 200"),
    ],
)
def test_bad_input_exits_2_naming_what_to_fix(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str, needle: str
) -> None:
    s = _session(33)
    spans = {k: {"start": a, "end": b} for k, (a, b) in s.sections.items()}
    extra: list[str] = []
    sections: object = spans
    if case == "missing_section":
        sections = {k: v for k, v in spans.items() if k != "y_rot"}
    elif case == "unknown_section":
        sections = {**spans, "x_rotation": {"start": 0, "end": 10}}
    elif case == "out_of_range":
        sections = {**spans, "z_a": {"start": 0, "end": s.gyro_dps.shape[0] + 1}}
    elif case == "bad_index":
        sections = {**spans, "x_p": {"start": "ten", "end": 100}}
    csv_path, sec_path = _files(tmp_path, 33, sections=sections)
    if case == "not_json":
        sec_path.write_text("{x_p: 1")
    elif case == "missing_column":
        _corrupt_csv(csv_path, 1, "gyr_x,gyr_y,gyro_z,acc_x,acc_y,acc_z")
    elif case == "partial_accel":
        _corrupt_csv(csv_path, 1, "gyr_x,gyr_y,gyr_z,acc_x,acc_y,temp_c")
    elif case == "nan":
        _corrupt_csv(csv_path, 11, "0.1,nan,0.2,0,0,9.8")
    elif case == "text":
        _corrupt_csv(csv_path, 11, "0.1,abc,0.2,0,0,9.8")
    elif case == "units":
        _corrupt_csv(csv_path, 11, "0.1,0.2,0.3,0,0,98066.5")
    elif case == "rate":
        extra = ["--rate-hz", "nan"]
    elif case == "angle":
        extra = ["--rotation-deg", "0"]
    elif case == "wrong_sign":
        extra = ["--rotation-deg", "-360"]
    elif case == "no_sections_file":
        sec_path = tmp_path / "none.json"
    elif case == "rate_mismatch":
        lines = csv_path.read_text().splitlines()
        lines = ["time_s," + lines[0]] + [f"{i / 100:.2f},{ln}" for i, ln in enumerate(lines[1:])]
        csv_path.write_text("\n".join(lines) + "\n")
        extra = ["--rate-hz", "200"]
    assert _run(csv_path, sec_path, *extra) == 2
    err = capsys.readouterr().err
    assert needle in err
    assert "Traceback" not in err


_json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**12, 10**12) | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner,
                                                                max_size=4),
    max_leaves=12,
)


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(doc=st.dictionaries(st.sampled_from(["x_p", "x_a", "y_rot", "z_rot", "x"]), _json_values)
       | _json_values)
def test_any_sections_json_is_read_or_refused_with_the_file_named(
    tmp_path: Path, doc: object
) -> None:
    path = tmp_path / "sections.json"
    path.write_text(json.dumps(doc))
    try:
        spans = read_sections(path)
    except UserError as exc:
        assert str(exc).startswith(str(path))
        assert "\n" not in str(exc) and len(str(exc)) < 1000
    else:
        assert set(spans) == {"x_p", "x_a", "y_p", "y_a", "z_p", "z_a", "x_rot", "y_rot",
                              "z_rot"}


def test_a_time_column_agreeing_with_the_rate_is_accepted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    csv_path, sec_path = _files(tmp_path, 32)
    lines = csv_path.read_text().splitlines()
    lines = ["time_s," + lines[0]] + [f"{i / 100:.2f},{ln}" for i, ln in enumerate(lines[1:])]
    csv_path.write_text("\n".join(lines) + "\n")
    assert _run(csv_path, sec_path, "--json") == 0
    assert json.loads(capsys.readouterr().out)["sample_rate_hz"] == 100
