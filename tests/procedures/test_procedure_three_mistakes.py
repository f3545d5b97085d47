"""Issue 26 finding 14 (part): three mistakes in one procedure file are reported as three
lines, each with its file and line, not only the first."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from common.yaml_input import ConfigError
from procedures.loading.config import load_procedure

REPO = Path(__file__).resolve().parents[2]

THREE = f"""name: three-mistakes
version: "1.0"
product: {REPO / "config" / "products" / "gyr130.yaml"}
output_rate_hz: 100
conditions:
  temperatures_c: [25.0]
  supplies_v: [5.0]
  ordr: as_listed
steps:
  - step: power_identify
  - for_each: condition
    steps:
      - step: thermal
        window_s: -5
      - step: bais
        dwell_s: 30
"""


def _write(tmp_path: Path) -> Path:
    path = tmp_path / "three.yaml"
    path.write_text(THREE, encoding="utf-8")
    return path


def test_three_mistakes_are_three_lines_in_file_order(tmp_path: Path) -> None:
    path = _write(tmp_path)
    with pytest.raises(ConfigError) as caught:
        load_procedure(path)
    lines = str(caught.value).splitlines()
    assert len(lines) == 3, lines
    assert lines[0].startswith(f"{path}:8: field conditions.ordr")  # a run-wide field
    assert lines[1].startswith(f"{path}:14: field steps.1.steps.0.window_s")  # a setting
    assert lines[2].startswith(f"{path}:15: steps.1.steps.1.step: unknown step type 'bais'")


def test_station_run_prints_the_three_lines(tmp_path: Path) -> None:
    path = _write(tmp_path)
    proc = subprocess.run(
        [sys.executable, "-m", "station", "run", "--sim", "--procedure", str(path),
         "--dut", "SIM-0001", "--out", str(tmp_path / "runs")],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode != 0
    errors = [ln for ln in proc.stderr.splitlines() if str(path) in ln]
    assert len(errors) == 3, proc.stderr
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_a_file_with_only_step_mistakes_still_reports_each(tmp_path: Path) -> None:
    path = tmp_path / "steps_only.yaml"
    path.write_text(THREE.replace("  ordr: as_listed\n", ""), encoding="utf-8")
    with pytest.raises(ConfigError) as caught:
        load_procedure(path)
    assert len(str(caught.value).splitlines()) == 2
