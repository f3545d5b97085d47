"""station.yaml's roles -> drivers: today's file unchanged, `driver:` per role, the part alias,
the optional inclinometer, and on the simulated bench the family each twin serves."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from common.yaml_input import ConfigError
from station import instruments as roles
from station.endpoints import Endpoints
from station.station_file import load_settings

ROOT = Path(__file__).resolve().parents[2]


def _bench(**families: str) -> Endpoints:
    return Endpoints(
        speed=100.0, rate_table="127.0.0.1:4001", chamber="127.0.0.1:4002",
        supply="/dev/pts/77", duts={1: "/dev/pts/78"},
        families={"rate_table": "modbus-servo", "chamber": "watlow-f4", "supply": "scpi",
                  "part": "fixture", **families},
    )  # fmt: skip


def _settings(tmp_path: Path, instruments: str) -> object:
    path = tmp_path / "station.yaml"
    path.write_text("station: {id: ROLES}\ninstruments:\n" + instruments)
    return load_settings(path)


def test_todays_station_yaml_gets_todays_drivers_and_settings() -> None:
    settings = load_settings()
    plans = {r: roles.plan_role(settings, r) for r in ("rate_table", "chamber", "supply")}
    assert {r: p.name for r, p in plans.items() if p} == {
        "rate_table": "rate_table.modbus-servo", "chamber": "chamber.watlow-f4",
        "supply": "supply.scpi",
    }  # fmt: skip
    assert plans["chamber"] is not None
    assert plans["chamber"].settings == {"address": "127.0.0.1:5021"}  # calibration_due kept
    assert str(plans["chamber"].calibration_due) == "2027-03-31"
    assert plans["supply"] is not None
    assert plans["supply"].settings == {"address": "/dev/ttyUSB0", "baud": 115200}
    assert roles.plan_role(settings, "inclinometer") is None
    part = roles.plan_part(settings, 1, "/dev/ttyUSB1")
    assert part.name == "part.fixture"
    assert part.settings == {"address": "/dev/ttyUSB1", "socket": 1}
    for plan in [*plans.values(), part]:
        assert plan is not None and roles.check_settings(settings, plan) == []


def test_driver_settings_are_the_drivers_own(tmp_path: Path) -> None:
    settings = _settings(
        tmp_path,
        "  chamber: {driver: watlow-f4, address: 10.0.0.5:502, poll_s: 2, expected_model: F4}\n"
        "  part: {ports: {1: /dev/ttyS1}, baud: 230400, timeout_s: 0.5}\n",
    )
    chamber = roles.plan_role(settings, "chamber")  # type: ignore[arg-type]
    assert chamber is not None and chamber.name == "chamber.watlow-f4"
    assert chamber.settings == {"address": "10.0.0.5:502", "poll_s": 2}
    assert chamber.expected_model == "F4"
    part = roles.plan_part(settings, 1, "/dev/ttyS1")  # type: ignore[arg-type]
    assert part.settings == {"address": "/dev/ttyS1", "socket": 1, "baud": 230400,
                             "timeout_s": 0.5}
    assert part.yaml_path == ("instruments", "part")


def test_an_inclinometer_needs_a_named_driver(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"station.yaml:3: instruments.inclinometer has no "
                       r"default driver: name one with driver: "
                       r"\(registered: inclinometer.ascii-xy\)"):
        _settings(tmp_path, "  inclinometer: {address: 10.0.0.9:4001}\n")


def test_station_yaml_is_checked_against_each_drivers_model_when_loaded(
    tmp_path: Path,
) -> None:
    with pytest.raises(ConfigError) as info:
        _settings(
            tmp_path,
            "  chamber: {address: 10.0.0.5:502, timeout_s: .nan}\n"
            "  supply: {driver: scpi, volts: 5}\n",
        )
    lines = str(info.value).splitlines()
    assert len(lines) == 2, lines  # the supply's missing address waits for a run
    assert ":3: field instruments.chamber.timeout_s: " in lines[0], lines
    assert lines[0].endswith("(driver chamber.watlow-f4)"), lines
    assert ":4: field instruments.supply.volts: unknown field for this driver" in lines[1]


def test_on_the_bench_each_role_gets_the_driver_of_its_twins_family() -> None:
    settings = load_settings()
    plan = roles.plan_role(settings, "chamber", _bench())
    assert plan is not None and plan.name == "chamber.watlow-f4"
    assert plan.settings == {"address": "127.0.0.1:4002"}
    # another family than station.yaml's: its driver, given only the twin's address (and
    # timeout_s), never station.yaml's settings for the real instrument
    assert roles._sim_driver("chamber", None, _bench(chamber="watlow-f4t")) == (
        "chamber.watlow-f4t", False
    )
    assert roles._sim_driver("supply", None, _bench(supply="rigol-dp800")) == (
        "supply.rigol-dp800", False
    )


def test_on_the_bench_a_named_driver_is_kept_and_given_the_twins_address(
    tmp_path: Path,
) -> None:
    settings = _settings(
        tmp_path,
        "  chamber: {driver: 'drivers.chamber:factory', address: 10.0.0.5:502, poll_s: 2}\n",
    )
    plan = roles.plan_role(settings, "chamber", _bench(chamber="espec-p300"))  # type: ignore[arg-type]
    assert plan is not None and plan.name == "drivers.chamber:factory"
    assert plan.settings == {"address": "127.0.0.1:4002", "poll_s": 2}


def test_on_the_bench_another_family_keeps_the_settings_it_also_takes(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # station.yaml's scpi supply with a voltage rating, the bench serving a Keysight: the
    # rating still reaches the pre-flight; the serial baud, which a LAN supply has not, is
    # left out with a warning instead of silently
    settings = _settings(
        tmp_path, "  supply: {address: /dev/ttyUSB0, baud: 9600, max_voltage_v: 6}\n"
    )
    bench = dataclasses.replace(
        _bench(supply="keysight-e36300"), supply="TCPIP::127.0.0.1::4003::SOCKET"
    )
    with caplog.at_level("WARNING", logger="station.instruments"):
        plan = roles.plan_role(settings, "supply", bench)  # type: ignore[arg-type]
    assert plan is not None and plan.name == "supply.keysight-e36300"
    assert plan.settings == {"address": "TCPIP::127.0.0.1::4003::SOCKET", "max_voltage_v": 6}
    assert "baud" in caplog.text and "keysight-e36300" in caplog.text
