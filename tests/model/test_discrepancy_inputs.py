"""What a new user feeds `station discrepancy`: spreadsheet CSV exports, bad values, static-only
records and model YAML mistakes are read or refused with file, line, field and what to do."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers_model import TINY, as_trajectory
from synth_gyro import Part, generate

from procedures.model import effects as fx
from procedures.model.data import load_csv, trajectory_from_columns, write_csv
from procedures.model.gyro_model import first_order_model
from procedures.model.model_io import load_model, save_model
from procedures.model.trajectory import Trajectory

ROOT = Path(__file__).resolve().parents[2]
PINNED = ("time_s", "gyro_dps", "ref_rate_dps", "ref_angle_deg", "temp_c", "supply_v")


def _station(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "station", "discrepancy", *args],
                          capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)


def _refused(out: subprocess.CompletedProcess[str], *needles: str) -> None:
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr
    for needle in needles:
        assert needle in out.stderr, out.stderr


@pytest.fixture(scope="module")
def run() -> Trajectory:
    return as_trajectory(generate(Part(), 3, TINY))


@pytest.fixture
def csv_text(run: Trajectory, tmp_path: Path) -> str:
    return write_csv(tmp_path / "plain.csv", run, with_kinds=True).read_text(encoding="utf-8")


def _same(a: Trajectory, b: Trajectory) -> None:
    for c in PINNED:
        assert np.allclose(getattr(a, c), getattr(b, c), rtol=1e-8, atol=0), c
    assert [s.kind for s in a.segments] == [s.kind for s in b.segments]


def _edit(text: str, line: int, column: str, value: str) -> str:
    """`text` with `column` of 1-based `line` set to `value` (comma-separated)."""
    rows = text.splitlines()
    header = rows[0].split(",")
    cells = rows[line - 1].split(",")
    cells[header.index(column)] = value
    rows[line - 1] = ",".join(cells)
    return "\n".join(rows) + "\n"


# ---------------------------------------------------------------- spreadsheet exports


def test_excel_byte_order_mark_is_read(tmp_path: Path, csv_text: str, run: Trajectory) -> None:
    p = tmp_path / "bom.csv"
    p.write_bytes(b"\xef\xbb\xbf" + csv_text.encode("utf-8"))
    plain = tmp_path / "plain2.csv"
    plain.write_text(csv_text, encoding="utf-8")
    _same(load_csv(p), load_csv(plain))


@pytest.mark.parametrize(
    ("delimiter", "decimal_comma", "sep_line"),
    [(";", True, False), (";", False, False), ("\t", False, False), (";", True, True)],
)
def test_semicolon_and_tab_separated_exports_are_read(
    tmp_path: Path, csv_text: str, delimiter: str, decimal_comma: bool, sep_line: bool
) -> None:
    text = csv_text.replace(",", delimiter)
    if decimal_comma:
        text = text.replace(".", ",")
    if sep_line:
        text = f"sep={delimiter}\n" + text
    p = tmp_path / "euro.csv"
    p.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))  # Excel 'CSV UTF-8' has a BOM too
    plain = tmp_path / "plain2.csv"
    plain.write_text(csv_text, encoding="utf-8")
    _same(load_csv(p), load_csv(plain))


def test_semicolon_export_runs_through_the_command(tmp_path: Path, csv_text: str) -> None:
    p = tmp_path / "euro.csv"
    p.write_bytes(b"\xef\xbb\xbf" + csv_text.replace(",", ";").replace(".", ",").encode())
    out = _station(str(p), "--out", str(tmp_path / "o"))
    assert out.returncode == 0, out.stderr
    data = json.loads((tmp_path / "o" / "discrepancy.json").read_text())
    assert data["gap_final_dps"] <= 1.5 * data["noise_floor_dps"]


def test_header_that_is_not_the_pinned_columns_names_line_and_separators(
    tmp_path: Path,
) -> None:
    p = tmp_path / "bad.csv"
    p.write_text("time|gyro|rate\n0|1|2\n", encoding="utf-8")
    with pytest.raises(ValueError, match=r"bad.csv: line 1: columns .* are missing.*';' or tab"):
        load_csv(p)


def test_not_utf8_says_how_to_save(tmp_path: Path, csv_text: str) -> None:
    p = tmp_path / "latin.csv"
    p.write_bytes(csv_text.replace("time_s", "time_s\u00b0", 1).encode("latin-1"))
    with pytest.raises(ValueError, match="latin.csv: not UTF-8 text.*CSV UTF-8"):
        load_csv(p)


# ---------------------------------------------------------------- values


@pytest.mark.parametrize(("column", "value"), [("gyro_dps", "nan"), ("temp_c", "inf"),
                                               ("time_s", "-Infinity"), ("supply_v", "NaN")])
def test_non_finite_value_is_refused_with_file_line_and_column(
    tmp_path: Path, csv_text: str, column: str, value: str
) -> None:
    p = tmp_path / "nan.csv"
    p.write_text(_edit(csv_text, 40, column, value), encoding="utf-8")
    with pytest.raises(ValueError, match=rf"nan.csv: line 40: column {column} is '{value}', "
                                         r"not a finite number; remove the row"):
        load_csv(p)


def test_non_finite_value_through_the_command(tmp_path: Path, csv_text: str) -> None:
    p = tmp_path / "nan.csv"
    p.write_text(_edit(csv_text, 1234, "gyro_dps", "nan"), encoding="utf-8")
    _refused(_station(str(p)), "nan.csv: line 1234: column gyro_dps is 'nan'")


def test_short_row_and_repeated_time_name_the_line(tmp_path: Path, csv_text: str) -> None:
    rows = csv_text.splitlines()
    p = tmp_path / "short.csv"
    p.write_text("\n".join([*rows[:9], "0.36,1.7,0", *rows[10:]]) + "\n", encoding="utf-8")
    with pytest.raises(ValueError, match="short.csv: line 10: column ref_angle_deg is missing"):
        load_csv(p)
    p = tmp_path / "twice.csv"
    p.write_text("\n".join([*rows[:20], rows[11], *rows[20:]]) + "\n", encoding="utf-8")
    with pytest.raises(ValueError, match="twice.csv: line 21: column time_s .* same as on "
                                         "line 12"):
        load_csv(p)


def test_unknown_segment_kind_is_refused_with_the_allowed_kinds(
    tmp_path: Path, csv_text: str
) -> None:
    header = csv_text.splitlines()[0].split(",")
    line = next(i for i, r in enumerate(csv_text.splitlines(), start=1)
                if r.split(",")[header.index("segment_kind")] == "plateau")
    p = tmp_path / "typo.csv"
    p.write_text(_edit(csv_text, line, "segment_kind", "plateu"), encoding="utf-8")
    with pytest.raises(ValueError) as err:
        load_csv(p)
    msg = str(err.value)
    assert msg.startswith(f"{p}: line {line}: column segment_kind is 'plateu'")
    assert "did you mean 'plateau'" in msg and "static, plateau, transition" in msg
    assert "\n" not in msg
    _refused(_station(str(p)), f"line {line}: column segment_kind is 'plateu'")


def test_empty_segment_kind_is_a_transition(tmp_path: Path, csv_text: str) -> None:
    header = csv_text.splitlines()[0].split(",")
    rows = csv_text.splitlines()
    k = header.index("segment_kind")
    blank = [",".join([*r.split(",")[:k], ""]) if r.split(",")[k] == "transition" else r
             for r in rows]
    p = tmp_path / "blank.csv"
    p.write_text("\n".join(blank) + "\n", encoding="utf-8")
    plain = tmp_path / "plain2.csv"
    plain.write_text(csv_text, encoding="utf-8")
    _same(load_csv(p), load_csv(plain))
    assert "transition" in {s.kind for s in load_csv(p).segments}


# ---------------------------------------------------------------- static-only records


def _static_only(run: Trajectory, rate_dps: float = 0.0) -> Trajectory:
    keep = np.zeros(run.n, dtype=bool)
    for s in run.segments:
        if s.kind in ("static", "stabilise"):
            keep |= (run.time_s >= s.start_s) & (run.time_s < s.end_s)
    cols = {c: np.asarray(getattr(run, c))[keep] for c in PINNED}
    return Trajectory(**{**{c: cols[c] for c in PINNED},
                         "ref_rate_dps": np.full(int(keep.sum()), rate_dps),
                         "time_since_power_on_s": cols["time_s"], "segments": ()})


@pytest.mark.parametrize("rate_dps", [0.0, 100.0])
def test_constant_reference_rate_is_refused(
    tmp_path: Path, run: Trajectory, rate_dps: float
) -> None:
    p = write_csv(tmp_path / "staticonly.csv", _static_only(run, rate_dps), with_kinds=False)
    with pytest.raises(ValueError, match=r"staticonly.csv: the reference rate never changes.*"
                                         r"needs rate plateaus or table moves"):
        load_csv(p)
    cols = {c: getattr(_static_only(run, rate_dps), c) for c in PINNED}
    with pytest.raises(ValueError, match="reference rate never changes"):
        trajectory_from_columns(cols, source="x")


def test_static_only_record_through_the_command(tmp_path: Path, run: Trajectory) -> None:
    """It was `math domain error` (fit.py: a negative variance of the unidentifiable
    scale), or a ZeroDivisionError traceback with --model first_order."""
    p = write_csv(tmp_path / "staticonly.csv", _static_only(run), with_kinds=True)
    for model in ("base", "first_order"):
        _refused(_station(str(p), "--model", model, "--out", str(tmp_path / "o")),
                 "staticonly.csv: the reference rate never changes")


# ---------------------------------------------------------------- model YAML


def _model(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "model.yaml"
    p.write_text(text, encoding="utf-8")
    return p


def _model_error(path: Path) -> str:
    with pytest.raises(ValueError) as err:
        load_model(path)
    msg = str(err.value)
    assert "pydantic.dev" not in msg and "<unicode string>" not in msg
    return msg


def test_model_type_error_names_file_line_and_field(tmp_path: Path) -> None:
    p = _model(tmp_path, "name: mine\nbias_dps: 8.6\nscale: one\n")
    msg = _model_error(p)
    assert msg.startswith(f"{p}:3: field scale: Input should be a valid number")
    assert "\n" not in msg
    p = _model(tmp_path, "scale: 1.0\neffects:\n  k2_quadratic:\n    k2_per_dps: [1]\n")
    assert _model_error(p).startswith(f"{p}:4: field effects.k2_quadratic.k2_per_dps: ")
    p = _model(tmp_path, "scale: 1.0\nscale: 2.0\n")
    assert _model_error(p) == f"{p}:2: field 'scale' appears twice (first on line 1); keep only one"


def test_model_type_error_through_the_command(tmp_path: Path, run: Trajectory) -> None:
    p = _model(tmp_path, "bias_dps: 8.6\nscale: one\n")
    data = write_csv(tmp_path / "run.csv", run)
    _refused(_station(str(data), "--model", str(p)), f"{p}:2: field scale:")


@pytest.mark.parametrize(
    ("effect", "param", "value", "allowed"),
    [
        ("sensor_lag", "tau_s", "0", "allowed from"),
        ("sensor_lag", "tau_s", "-0.004", "allowed from"),
        ("warmup_drift", "tau_s", "0.0", "allowed from 5 to 3000 s"),
        ("warmup_drift", "tau_s", "-300", "allowed from 5 to 3000 s"),
        ("g_sensitivity_tilt", "tilt_deg", "0", "above 0 and below 180 deg"),
        ("scale_asymmetry", "asymmetry", "2.5", "above -2 and below 2"),
        ("k2_quadratic", "k2_per_dps", ".nan", "finite number"),
        ("bias_temperature", "bias_temp_coeff_dps_per_c", "-.inf", "finite number"),
    ],
)
def test_bad_effect_parameter_is_refused_with_field_and_allowed_range(
    tmp_path: Path, effect: str, param: str, value: str, allowed: str
) -> None:
    p = _model(tmp_path, f"scale: 1.02\neffects:\n  {effect}:\n    {param}: {value}\n")
    msg = _model_error(p)
    assert msg.startswith(f"{p}:4: field effects.{effect}.{param}: "), msg
    assert allowed in msg and "\n" not in msg


@pytest.mark.parametrize(
    ("text", "line", "field", "says"),
    [
        ("bias_dps: 8.6\n", 1, "scale", "required field is missing"),
        ("bias_dps: 8.6\nscale: 0\n", 2, "scale", "0 is not allowed"),
        ("bias_dps: .nan\nscale: 1\n", 1, "bias_dps", "finite number"),
        ("scale: .inf\n", 1, "scale", "finite number"),
        ("scale: 1\nreference_temperature_c: 20\n", 2, "reference_temperature_c", "25"),
        ("scale: 1\nuncertainties: {bias_dps: -1}\n", 2, "uncertainties.bias_dps",
         "greater than or equal to 0"),
        ("scale: 1\neffects:\n  k2_quadratic: {k2: 1}\n", 3, "effects.k2_quadratic.k2",
         "takes k2_per_dps"),
        ("scale: 1\neffects:\n  k4_quartic: {}\n", 3, "effects.k4_quartic",
         "unknown effect 'k4_quartic'"),
    ],
)
def test_bad_model_value_is_refused_with_line_and_field(
    tmp_path: Path, text: str, line: int, field: str, says: str
) -> None:
    p = _model(tmp_path, text)
    msg = _model_error(p)
    assert msg.startswith(f"{p}:{line}: field {field}: "), msg
    assert says in msg and "\n" not in msg


def test_every_problem_of_a_model_is_listed_in_file_order(tmp_path: Path) -> None:
    p = _model(tmp_path, "bias_dps: 8.6\neffects:\n  sensor_lag: {tau_s: 0}\n"
                         "  k2_quadratic: {k2_per_dps: .nan}\nscale: 0\n")
    lines = _model_error(p).splitlines()
    assert [m.split(": field ")[0] for m in lines] == [f"{p}:3", f"{p}:4", f"{p}:5"]


def test_saved_models_still_load_with_taus_on_the_profiled_bounds(tmp_path: Path) -> None:
    lo = fx.TAU_RANGE_S["sensor_lag"][0]
    hi = fx.TAU_RANGE_S["warmup_drift"][1]
    m = (first_order_model()
         .with_effect("sensor_lag", {"tau_s": lo * (1 - 1e-12)})
         .with_effect("warmup_drift", {"amplitude_dps": 0.1, "tau_s": hi}))
    m = type(m)(**{**m.__dict__, "uncertainties": {"bias_dps": 1e-3,
                                                   "warmup_drift.tau_s": float("inf")}})
    back = load_model(save_model(m, tmp_path / "m.yaml"))
    assert back.effects == m.effects and back.uncertainties == m.uncertainties
    # parameters left out start at their defaults
    p = _model(tmp_path, "scale: 1.0\neffects: {warmup_drift: {amplitude_dps: 0.2}}\n")
    assert load_model(p).effects["warmup_drift"] == {"amplitude_dps": 0.2, "tau_s": 300.0}
