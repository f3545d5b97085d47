"""An unsafe chamber safe temperature is refused before anything is written or touched."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from station.errors import UserError
from station.station_file import load_settings
from station.uut import UutRunner

ROOT = Path(__file__).resolve().parents[2]
PROCEDURE = ROOT / "config" / "procedures" / "eol-rate-table.yaml"
PRODUCT = ROOT / "config" / "products" / "gyr130.yaml"


def _procedure(tmp_path: Path, safe_temp_c: float) -> Path:
    data = yaml.safe_load(PROCEDURE.read_text(encoding="utf-8"))
    data.setdefault("chamber", {})["safe_temp_c"] = safe_temp_c
    data["product"] = str(PRODUCT)
    path = tmp_path / "proc.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


@pytest.mark.parametrize("safe_temp_c", [45.0, 5.0])  # 300 and -20 the schema refuses
def test_safe_temperature_outside_the_handling_range_is_refused(
    tmp_path: Path, safe_temp_c: float
) -> None:
    out = tmp_path / "runs"
    runner = UutRunner(
        load_settings(), procedure_path=_procedure(tmp_path, safe_temp_c), out=out,
        certificate=False,
    )
    with pytest.raises(UserError) as info:
        runner.validate({1: "SIM-0001"})
    message = str(info.value)
    assert "\n" not in message and "safe_temp_c" in message and "handling range" in message
    assert not out.exists() or not any(out.iterdir())


def test_chamber_limits_refuse_a_safe_temperature_beyond_them(tmp_path: Path) -> None:
    runner = UutRunner(
        load_settings(), procedure_path=_procedure(tmp_path, 25.0), out=tmp_path / "runs",
        certificate=False,
    )
    runner.check_safe_settings((-40.0, 125.0))
    with pytest.raises(UserError, match="setpoint limits"):
        runner.check_safe_settings((30.0, 125.0))
