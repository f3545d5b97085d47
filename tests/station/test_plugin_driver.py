"""A driver from a package outside the project, named in station.yaml as `module:attr`, runs a
full procedure on the simulated bench: the worked example of docs/instruments.md, written as
it stands there into a temporary folder that only the station's PYTHONPATH knows."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from procedures.runtime.record import Verdict, read_record

ROOT = Path(__file__).resolve().parents[2]
SHORT = ROOT / "tests/procedures/data/short.yaml"  # 25 and 35 C, the full 2 x 2 procedure
DOC = ROOT / "docs/instruments.md"


def example_source() -> str:
    """The docs' worked example (the python block that starts with `# acme_chamber.py`)."""
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)
    (source,) = [b for b in blocks if b.startswith("# acme_chamber.py\n")]
    return source


def _plugin_dir(tmp_path: Path) -> Path:
    """A folder outside the project holding the example as its own module."""
    package = tmp_path / "site"
    package.mkdir(exist_ok=True)
    (package / "acme_chamber.py").write_text(example_source())
    return package


def _station_yaml(tmp_path: Path, door_limit_c: float) -> Path:
    text = (ROOT / "config/station.yaml").read_text()
    old = "  chamber:\n    address: 127.0.0.1:5021\n"
    assert old in text
    text = text.replace(
        old,
        "  chamber:\n    driver: acme_chamber:factory\n    address: 192.0.2.1:502\n"
        f"    door_limit_c: {door_limit_c}\n",
    )
    path = tmp_path / f"station-{door_limit_c:g}.yaml"
    path.write_text(text)
    return path


def _run(tmp_path: Path, station_yaml: Path, out: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(_plugin_dir(tmp_path))]))
    return subprocess.run(
        [sys.executable, "-m", "station", "run", "--sim", "--speed", "150", "--station",
         str(station_yaml), "--dut", "SIM-0001", "--procedure", str(SHORT), "--out", str(out)],
        capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300,
    )  # fmt: skip


def test_the_example_is_outside_the_project_and_not_importable_here() -> None:
    source = example_source()
    assert "chamber.watlow-f4" in source and "def factory(settings" in source
    assert not (ROOT / "acme_chamber.py").exists()
    assert "acme_chamber" not in sys.modules


def test_module_attr_driver_wrapping_watlow_f4_runs_the_full_procedure(tmp_path: Path) -> None:
    out = tmp_path / "out"
    r = _run(tmp_path, _station_yaml(tmp_path, 40.0), out)
    assert r.returncode in (0, 1), r.stdout + r.stderr
    folder = next(out.glob("*_SIM-0001"))
    record = read_record(folder)
    assert record.verdict is Verdict.PASS, record.reason
    chamber = next(i for i in record.instruments if i.role == "chamber")
    # the plugin's own identity around the F4 twin's, at the twin's address (not station.yaml's)
    assert chamber.manufacturer == "ACME" and chamber.model == "CAB-85/SIM-F4-CHAMBER"
    assert chamber.address.startswith("127.0.0.1:") and chamber.address != "192.0.2.1:502"


def test_the_plugins_own_limit_refuses_the_run_before_measuring(tmp_path: Path) -> None:
    out = tmp_path / "out"
    r = _run(tmp_path, _station_yaml(tmp_path, 30.0), out)
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert "conditions.temperatures_c 35 C is outside the setpoint limits [-40, 30] C" in lines[0]
    assert "acme_chamber:factory" in lines[0]
    assert not out.exists()
