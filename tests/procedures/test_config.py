from __future__ import annotations

from pathlib import Path

import pytest

from common.yaml_input import ConfigError
from procedures.loading.config import load_procedure, load_product
from station.station_file import load_settings

CONFIG = Path(__file__).resolve().parents[2] / "config"


def test_shipped_files_load() -> None:
    proc, loaded = load_procedure(CONFIG / "procedures" / "eol-rate-table.yaml")
    types = [e.type_name for e in proc.entries()]
    assert types == ["power_identify", "thermal", "bias", "rate_table", "stop_method", "fit",
                     "program", "verify"]
    assert proc.needs_table
    assert len(loaded.sha256) == 64
    stop, _ = load_procedure(CONFIG / "procedures" / "eol-stop-method.yaml")
    assert "rate_table" not in [e.type_name for e in stop.entries()]
    assert stop.settings_of("fit").source == "stop_method"
    assert stop.settings_of("stop_method").reference == "fixture"
    product, _ = load_product(CONFIG / "products" / "gyr130.yaml")
    assert product.limits.residual_scale_error is not None
    assert product.limits.residual_scale_error.high == pytest.approx(0.0005)
    settings = load_settings(CONFIG / "station.yaml")
    assert settings.output_folder.name == "runs"


def _bad(tmp_path: Path, old: str, new: str) -> str:
    text = (CONFIG / "procedures" / "eol-rate-table.yaml").read_text()
    assert old in text
    path = tmp_path / "bad.yaml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(ConfigError) as info:
        load_procedure(path)
    return str(info.value)


def _line_of(tmp_path: Path, needle: str) -> int:
    lines = (tmp_path / "bad.yaml").read_text().splitlines()
    return next(i + 1 for i, line in enumerate(lines) if needle in line)


def test_error_names_file_line_field_and_allowed(tmp_path: Path) -> None:
    msg = _bad(tmp_path, "slope_c_per_min: 0.1", "slope_c_per_min: -1")
    line = _line_of(tmp_path, "slope_c_per_min: -1")
    assert msg.startswith(
        f"{tmp_path / 'bad.yaml'}:{line}: field steps.1.steps.0.slope_c_per_min (step thermal)"
    )
    assert "greater than 0" in msg


def test_unknown_field_lists_allowed(tmp_path: Path) -> None:
    msg = _bad(tmp_path, "plateau_dwell_s: 8", "plateu_dwell_s: 8")
    line = _line_of(tmp_path, "plateu_dwell_s")
    assert f":{line}: field steps.1.steps.2.plateu_dwell_s (step rate_table): unknown field" in msg
    assert "plateau_dwell_s" in msg.split("allowed here:")[1]


def test_enum_choice_says_what_is_allowed(tmp_path: Path) -> None:
    msg = _bad(tmp_path, "reference: encoder", "reference: laser")
    assert "steps.1.steps.3.reference (step stop_method)" in msg
    assert "'encoder' or 'fixture'" in msg


def test_list_item_error_points_at_item_line(tmp_path: Path) -> None:
    msg = _bad(tmp_path, "supplies_v: [4.75, 5.25]", "supplies_v:\n    - 4.75\n    - five")
    line = _line_of(tmp_path, "- five")
    assert f":{line}: field conditions.supplies_v.1" in msg


def test_duplicate_key_refused(tmp_path: Path) -> None:
    msg = _bad(tmp_path, "        repeats: 1\n", "        repeats: 1\n        repeats: 2\n")
    assert "appears twice" in msg


def test_fit_source_must_be_measured_before_the_fit(tmp_path: Path) -> None:
    msg = _bad(tmp_path, "    source: rate_table", "    source: both\n    rate_table_x: 1")
    assert "rate_table_x" in msg
    text = (CONFIG / "procedures" / "eol-stop-method.yaml").read_text()
    path = tmp_path / "stop.yaml"
    path.write_text(text.replace("source: stop_method", "source: rate_table"))
    with pytest.raises(ConfigError) as info:
        load_procedure(path)
    line = next(i + 1 for i, t in enumerate(text.splitlines()) if "step: fit" in t)
    assert f"stop.yaml:{line}: steps.2: step fit needs scale_table from an earlier step " \
        "(rate_table)" in str(info.value)


def test_not_yaml_and_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "x.yaml"
    path.write_text("name: a\nconditions: [1, 2\n")
    with pytest.raises(ConfigError, match=r"x\.yaml:\d+: not valid YAML"):
        load_procedure(path)
    with pytest.raises(ConfigError, match="file not found"):
        load_procedure(tmp_path / "nope.yaml")


def test_product_limit_order_checked(tmp_path: Path) -> None:
    text = (CONFIG / "products" / "gyr130.yaml").read_text()
    path = tmp_path / "p.yaml"
    path.write_text(text.replace("marginal_high: 8.0", "marginal_high: 12.0", 1))
    with pytest.raises(ConfigError, match=r"limits\.raw_bias_dps: .*must not exceed high"):
        load_product(path)
    path.write_text(text.replace("'^[A-Z]{2,4}-[0-9]{4}$'", "'^[A-Z'"))
    with pytest.raises(ConfigError, match="serial_pattern: .*not a valid regular expression"):
        load_product(path)


def test_station_settings_errors(tmp_path: Path) -> None:
    text = (CONFIG / "station.yaml").read_text()
    path = tmp_path / "station.yaml"
    path.write_text(text.replace("calibration_due: 2027-06-30", "calibration_due: soon"))
    with pytest.raises(ConfigError, match=r"instruments\.rate_table\.calibration_due"):
        load_settings(path)
    path.write_text(text)
    settings = load_settings(path)
    assert settings.output_folder == (tmp_path / "../runs").resolve()
