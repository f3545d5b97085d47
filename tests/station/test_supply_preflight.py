"""The pre-flight refuses a load the supply's output cannot give, reading the output's range
from the family's model (issue 41): `station run --sim` as README shows it, with a station
file whose parts hang on an output too small for them. One line naming the output and its
range, exit 2, no run folder. Before, the pre-flight knew a supply's limit only from
station.yaml's max_current_a, and every socket ended ERROR in power_identify (-222)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
STATION = Path(sys.executable).parent / "station"  # the installed command (dev.py's .venv)


def _station_file(tmp: Path, base: str, sim: str, supply: dict[str, Any]) -> Path:
    """A copy of a shipped station file with the supply entry given, its sim config the
    shipped one serving `supply`'s family, everything written under `tmp`."""
    station = yaml.safe_load((ROOT / "config" / base).read_text(encoding="utf-8"))
    sim_config = yaml.safe_load((ROOT / "config" / "sim" / sim).read_text(encoding="utf-8"))
    sim_config["instruments"] = {"supply": supply["driver"]}
    (tmp / "sim.yaml").write_text(yaml.safe_dump(sim_config), encoding="utf-8")
    station["procedure"] = str(ROOT / "config" / "procedures" / "eol-ramp.yaml")
    station["sim_config"] = str(tmp / "sim.yaml")
    station["output_folder"] = str(tmp / "runs")
    station["results_db"] = str(tmp / "runs" / "results.sqlite")
    station["instruments"]["supply"] = {**supply, "calibration_due": "2027-01-31"}
    path = tmp / "station.yaml"
    path.write_text(yaml.safe_dump(station), encoding="utf-8")
    return path


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    if not STATION.exists():
        pytest.skip(f"no installed station command at {STATION}: run `python3 dev.py test`")
    return subprocess.run([str(STATION), "run", *args], capture_output=True, text=True,
                          timeout=600, cwd=ROOT, check=False)


def _refused_in_one_line(run: subprocess.CompletedProcess[str], tmp: Path) -> str:
    assert run.returncode == 2, run.stdout[-2000:] + run.stderr[-2000:]
    assert "Traceback" not in run.stderr, run.stderr[-3000:]
    errors = [line for line in run.stderr.splitlines() if line.startswith("station run: error")]
    assert len(errors) == 1, run.stderr
    assert not (tmp / "runs").exists() or not any(
        p.is_dir() and p.name != "results.sqlite" for p in (tmp / "runs").iterdir()
    ), "a run folder was written before the pre-flight refused the load"
    return errors[0]


def test_eight_parts_beyond_the_e36312a_output_2_are_refused_by_the_preflight(
    tmp_path: Path,
) -> None:
    """Eight parts of a product drawing up to 0.2 A each on output 2 of an E36312A (25 V,
    1 A): 1.6 A asked of a 1 A output. The range is the model's, told by *IDN?; station.yaml
    says nothing of it."""
    product = yaml.safe_load((ROOT / "config/products/gyr130.yaml").read_text(encoding="utf-8"))
    product["current_limit_a"] = 0.2
    (tmp_path / "heavy.yaml").write_text(yaml.safe_dump(product), encoding="utf-8")
    station = _station_file(tmp_path, "station.yaml", "eight_sockets.yaml", {
        "driver": "keysight-e36300", "address": "TCPIP::192.168.1.20::5025::SOCKET",
        "channel": 2})
    duts = [a for s in range(1, 9) for a in ("--dut", f"{s}=SIM-01{s:02d}")]
    run = _run("--sim", "--station", str(station), "--product", str(tmp_path / "heavy.yaml"),
               *duts)
    line = _refused_in_one_line(run, tmp_path)
    assert "8 part(s) at the product's current_limit_a 0.2 A need a 1.6 A limit" in line
    assert "output 2 of the Keysight E36312A (0 to 25 V, up to 1 A: the E36312A's rating)" in line


@pytest.mark.station_grid
def test_thirty_two_parts_beyond_the_generic_supplys_output_with_a_narrower_station_limit(
    tmp_path: Path,
) -> None:
    """The issue's load: 32 parts at 0.05 A on the generic SCPI twin, whose range it tells
    (`VOLT? MAX`, `CURR? MAX`: 30 V, 3 A), narrowed by station.yaml's max_current_a 1.5 A."""
    station = _station_file(tmp_path, "station-32.yaml", "thirty_two_sockets.yaml", {
        "driver": "scpi", "address": "/dev/ttyUSB0", "max_current_a": 1.5})
    duts = [a for s in range(1, 33) for a in ("--dut", f"{s}=SIM-32{s:02d}")]
    line = _refused_in_one_line(_run("--sim", "--station", str(station), *duts), tmp_path)
    assert "32 part(s) at the product's current_limit_a 0.05 A need a 1.6 A limit" in line
    assert ("the DC supply's output (0 to 30 V, up to 1.5 A: station.yaml's max_current_a "
            "within its VOLT? MAX and CURR? MAX)") in line
