"""Pre-flight: a configuration mistake is refused before measuring, never a part FAIL or an
ERROR after 45 minutes. Each refusal is one line per problem, exit 2, and nothing written
(no run folder, no results database), through `station run` on the simulated bench."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SHORT = ROOT / "tests/procedures/data/short.yaml"
PRODUCT = ROOT / "config/products/gyr130.yaml"


def station(
    *args: str, env: dict[str, str] | None = None, timeout: float = 120
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "station", *args],
        capture_output=True,
        text=True,
        env=env or dict(os.environ, PYTHONPATH=str(ROOT)),
        cwd=ROOT,
        timeout=timeout,
    )


def _procedure(tmp_path: Path, old: str, new: str) -> Path:
    text = SHORT.read_text()
    assert text.count(old) == 1, old
    path = tmp_path / "procedure.yaml"
    path.write_text(
        text.replace(old, new).replace(
            "product: ../../../config/products/gyr130.yaml", f"product: {PRODUCT}"
        )
    )
    return path


def _line_of(path: Path, words: str) -> int:
    return next(i + 1 for i, t in enumerate(path.read_text().splitlines()) if words in t)


def _refused(r: subprocess.CompletedProcess[str], out: Path, n_lines: int = 1) -> list[str]:
    """Exit 2, `n_lines` error lines naming the command, no traceback, nothing written."""
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == n_lines, r.stderr
    assert all(line.startswith("station run: error: ") for line in lines), r.stderr
    assert not out.exists(), sorted(p.name for p in out.rglob("*"))
    return [line.removeprefix("station run: error: ") for line in lines]


def test_setpoint_beyond_the_chambers_limits_is_refused_before_any_folder(
    tmp_path: Path,
) -> None:
    # today the 200 C condition failed with SetpointOutOfRange after 44.8 station minutes
    proc = _procedure(tmp_path, "temperatures_c: [25.0, 35.0]", "temperatures_c: [25.0, 200.0]")
    out = tmp_path / "out"
    r = station("run", "--sim", "--dut", "SIM-0001", "--procedure", str(proc), "--out", str(out))
    (line,) = _refused(r, out)
    assert line.startswith(f"{proc}:{_line_of(proc, 'temperatures_c')}: ")
    assert "conditions.temperatures_c 200 C is outside the setpoint limits [-40, 125] C" in line
    assert "chamber.watlow-f4" in line  # the limits are the chamber's own (read from it)


def test_every_problem_is_its_own_line(tmp_path: Path) -> None:
    proc = _procedure(
        tmp_path, "temperatures_c: [25.0, 35.0]", "temperatures_c: [-60.0, 25.0, 200.0]"
    )
    out = tmp_path / "out"
    r = station("run", "--sim", "--dut", "SIM-0001", "--procedure", str(proc), "--out", str(out))
    lines = _refused(r, out, n_lines=2)
    assert "-60 C is outside" in lines[0] and "200 C is outside" in lines[1]


def test_rate_beyond_the_parts_range_is_refused_not_failed(tmp_path: Path) -> None:
    # today a 300 deg/s rate on a 250 deg/s part saturated it and FAILed the part
    proc = _procedure(
        tmp_path, "rates_dps: [50, -50, 200, -200]", "rates_dps: [50, -50, 300, -200]"
    )
    out = tmp_path / "out"
    r = station("run", "--sim", "--dut", "SIM-0001", "--procedure", str(proc), "--out", str(out))
    (line,) = _refused(r, out)
    assert line.startswith(f"{proc}:{_line_of(proc, 'rates_dps: [50')}: ")
    assert "rates_dps" in line and "300 d" in line and "250 deg/s" in line, line
    assert "simulated bench running" not in r.stdout  # refused from the files alone


def test_acceleration_beyond_the_tables_limit_is_refused(tmp_path: Path) -> None:
    proc = _procedure(tmp_path, "accel_dps2: 200\n    repeats", "accel_dps2: 5000\n    repeats")
    out = tmp_path / "out"
    r = station("run", "--sim", "--dut", "SIM-0001", "--procedure", str(proc), "--out", str(out))
    (line,) = _refused(r, out)
    assert line.startswith(f"{proc}:{_line_of(proc, 'accel_dps2: 5000')}: ")
    assert "steps.1.steps.2.accel_dps2 (step rate_table) 5000 deg/s^2 is beyond the 2000 " \
        "deg/s^2" in line


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_unreachable_instrument_refuses_the_run(tmp_path: Path) -> None:
    port = _closed_port()
    text = (ROOT / "config/station.yaml").read_text()
    text = text.replace("address: 127.0.0.1:5021", f"address: 127.0.0.1:{port}")
    text = text.replace("address: 127.0.0.1:5020", f"address: 127.0.0.1:{port}")
    yaml = tmp_path / "station.yaml"
    yaml.write_text(text)
    out = tmp_path / "out"
    r = station(
        "run", "--station", str(yaml), "--dut", "SIM-0001", "--procedure", str(SHORT),
        "--out", str(out),
    )  # fmt: skip
    (line,) = _refused(r, out)
    assert f"cannot reach the rate table at 127.0.0.1:{port}" in line
    assert "rate_table.modbus-servo" in line and "refused until every instrument answers" in line


INCLINOMETER = '''
import socket
from drivers.errors import ConnectionLost
from drivers.protocols import InstrumentIdentity


class Inclinometer:
    def __init__(self, sock):
        self.sock = sock

    def identify(self):
        return InstrumentIdentity("ACME", "INC-1", "1", "1.0")

    def close(self):
        self.sock.close()


def factory(settings):
    host, _, port = settings["address"].rpartition(":")
    try:
        return Inclinometer(socket.create_connection((host, int(port)), timeout=0.5))
    except OSError as exc:
        raise ConnectionLost(f"no inclinometer at {settings['address']}: {exc}") from None
'''


def test_a_plugin_role_the_bench_does_not_serve_is_refused_not_reached(tmp_path: Path) -> None:
    """The optional inclinometer (no twin on the bench, a plugin driver): --sim never goes to
    station.yaml's own address for it (tests/station/test_sim_stays_on_bench.py)."""
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "acme_inclinometer.py").write_text(INCLINOMETER)
    port = _closed_port()
    text = (ROOT / "config/station.yaml").read_text()
    text += (
        f"  inclinometer:\n    driver: acme_inclinometer:factory\n"
        f"    address: 127.0.0.1:{port}\n"
    )
    yaml = tmp_path / "station.yaml"
    yaml.write_text(text)
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(tmp_path / "pkg")]))
    r = station(
        "run", "--sim", "--station", str(yaml), "--dut", "SIM-0001", "--procedure", str(SHORT),
        "--out", str(out), env=env,
    )  # fmt: skip
    (line,) = _refused(r, out)
    assert "station.yaml names the inclinometer but the simulated bench does not serve it" in line
    assert "instruments.inclinometer: ascii-xy in the sim config" in line


@pytest.mark.parametrize(
    "entry, words",
    [
        ("    driver: chamber.no-such\n", "unknown driver 'chamber.no-such'; registered chamber "
         "drivers: chamber.espec-p300, chamber.watlow-f4, chamber.watlow-f4t"),
        ("    colour: red\n", "field instruments.chamber.colour: unknown field for this driver; "
         "allowed: address, poll_s, timeout_s (driver chamber.watlow-f4)"),
        ("    timeout_s: -1\n", "field instruments.chamber.timeout_s: Input should be greater "
         "than 0 (driver chamber.watlow-f4)"),
    ],
)
def test_bad_driver_or_setting_is_one_line_with_station_yaml_line(
    tmp_path: Path, entry: str, words: str
) -> None:
    text = (ROOT / "config/station.yaml").read_text()
    text = text.replace("  chamber:\n", "  chamber:\n" + entry)
    yaml = tmp_path / "station.yaml"
    yaml.write_text(text)
    out = tmp_path / "out"
    r = station(
        "run", "--sim", "--station", str(yaml), "--dut", "SIM-0001", "--procedure", str(SHORT),
        "--out", str(out),
    )  # fmt: skip
    (line,) = _refused(r, out)
    assert line.startswith(f"{yaml}:{_line_of(yaml, entry.strip())}: "), line
    assert words in line


def test_every_product_problem_is_its_own_line(tmp_path: Path) -> None:
    # two rates beyond the part's range and a supply level beyond its supply range: three lines
    proc = _procedure(
        tmp_path, "rates_dps: [50, -50, 200, -200]", "rates_dps: [50, -50, 2000, -2000]"
    )
    text = proc.read_text()
    assert text.count("supplies_v: [4.75, 5.25]") == 1
    proc.write_text(text.replace("supplies_v: [4.75, 5.25]", "supplies_v: [4.75, 25]"))
    out = tmp_path / "out"
    r = station("run", "--sim", "--dut", "SIM-0001", "--procedure", str(proc), "--out", str(out))
    lines = _refused(r, out, n_lines=3)
    assert sum("2000 deg/s is beyond the range" in line for line in lines) == 2, lines
    (supply,) = [line for line in lines if "supplies_v" in line]
    assert supply.startswith(f"{proc}:{_line_of(proc, 'supplies_v:')}: "), supply
    assert "25 V is outside the supply range [4.75, 5.25] V" in supply, supply
    assert "simulated bench running" not in r.stdout  # refused from the files alone


@pytest.mark.parametrize("strategy", ["setpoint", "fastest"])
def test_a_condition_that_heats_the_die_past_the_parts_maximum_is_refused(
    tmp_path: Path, strategy: str
) -> None:
    # issue 26 (1): [25, 40, 100] on gyr130 (max_part_temperature_c 85) ran to PASS with the
    # die at 104.2 C (setpoint); with `fastest` it was refused only after 26 station minutes,
    # a run folder written. 100 C is inside the chamber's own limits [-40, 125].
    proc = _procedure(tmp_path, "temperatures_c: [25.0, 35.0]", "temperatures_c: [25, 40, 100]")
    if strategy == "fastest":
        text = proc.read_text()
        proc.write_text(text.replace("  ramp_c_per_min: 5.0\n",
                                     "  ramp_c_per_min: 5.0\n  strategy: fastest\n", 1))
    out = tmp_path / "out"
    r = station("run", "--sim", "--dut", "SIM-0001", "--procedure", str(proc), "--out", str(out))
    (line,) = _refused(r, out)
    assert line.startswith(f"{proc}:{_line_of(proc, 'temperatures_c')}: "), line
    # the hottest condition at 100 C, the die with its self-heating: 40 C/W x 5.25 V x 40 mA
    assert "condition T100_V5.25: the die is predicted to reach 108.4 C" in line, line
    assert "100 C + 8.4 C self-heating at 5.25 V and 40 mA" in line, line
    assert "above the part's maximum of 85 C" in line, line


def test_the_predicted_die_counts_self_heating_near_the_maximum(tmp_path: Path) -> None:
    """A setpoint below the maximum whose die, self-heated, would pass it: refused too."""
    from procedures.loading.config import load_procedure, load_product
    from station.preflight import part_temperature_problems

    proc = _procedure(tmp_path, "temperatures_c: [25.0, 35.0]", "temperatures_c: [25, 80]")
    procedure, loaded = load_procedure(proc)
    product, _ = load_product(PRODUCT)
    (line,) = part_temperature_problems(procedure, loaded, product, (-40.0, 125.0))
    assert "condition T80_V5.25: the die is predicted to reach 88.4 C" in line, line
    cool = _procedure(tmp_path, "temperatures_c: [25.0, 35.0]", "temperatures_c: [25, 75]")
    procedure, loaded = load_procedure(cool)
    assert part_temperature_problems(procedure, loaded, product, (-40.0, 125.0)) == []
    cold = _procedure(tmp_path, "temperatures_c: [25.0, 35.0]", "temperatures_c: [-45, 25]")
    procedure, loaded = load_procedure(cold)
    (line,) = part_temperature_problems(procedure, loaded, product, (-60.0, 125.0))
    assert "die would be at -45 C, below the part's minimum of -40 C" in line, line


def test_start_on_the_operator_screen_refuses_a_part_heated_past_its_maximum(
    tmp_path: Path,
) -> None:
    """The operator screen's START runs the same pre-flight: refused, nothing written."""
    from drivers.sim.launcher import launch_bench
    from station.endpoints import Endpoints
    from station.errors import UserError
    from station.station_file import load_settings
    from station.ui.runner_adapter import EngineRunner, StartRequest

    proc = _procedure(tmp_path, "temperatures_c: [25.0, 35.0]", "temperatures_c: [25, 40, 100]")
    out = tmp_path / "out"
    with launch_bench(config={"parts": [{"socket": 1, "serial": "SIM-0001"}]},
                      lockstep=True) as bench:
        runner = EngineRunner(load_settings(None), out=out,
                              endpoints=Endpoints.of_bench(bench.endpoints),
                              control=bench.control)
        request = StartRequest({1: "SIM-0001"}, str(proc), str(PRODUCT))
        with pytest.raises(UserError, match="condition T100_V5.25: the die is predicted to "
                                            "reach 108.4 C") as refused:
            runner.start(request, lambda event: None)
        runner.close()
    assert len(str(refused.value).splitlines()) == 1, refused.value
    assert not out.exists()
