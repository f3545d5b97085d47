"""A test engineer's procedure file with three mistakes is told about all three at once,
each as file:line: field: what is wrong and what is allowed (issue 26, finding 14)."""

from __future__ import annotations

from pathlib import Path

import pytest

from station.cli import main

REPO = Path(__file__).resolve().parents[2]

THREE_MISTAKES = f"""\
name: three-mistakes
version: "1.0"
product: {REPO / "config/products/gyr130.yaml"}
output_rate_hz: 100
conditions:
  temperatures_c: [25.0, 45.0]
  supplies_v: [4.75, 5.25]
chamber: {{ramp_c_per_min: 5.0, safe_temp_c: 25.0, colour: red}}
steps:
  - step: power_identify
    timeout_s: -5
  - for_each: condition
    steps:
      - step: bias
        dwel_s: 30
  - step: fit
    source: rate_table
"""


def test_three_mistakes_in_one_procedure_are_three_lines(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "three.yaml"
    path.write_text(THREE_MISTAKES)
    code = main(["run", "--sim", "--procedure", str(path), "--dut", "SIM-0001",
                 "--out", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if f"{path}:" in ln]
    assert code == 2
    assert [ln.split(f"{path}:")[1].split(":")[0] for ln in lines] == ["11", "15", "8"], err
    assert "chamber.colour: unknown field" in err
    assert "dwel_s" in err and "timeout_s" in err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
