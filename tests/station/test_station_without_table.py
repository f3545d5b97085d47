"""A station without a rate table (the article's hand-turned bench, config/station-manual.yaml):
the role is absent, not broken; a procedure that moves a table is refused saying so."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from procedures.loading.config import load_procedure, load_product
from procedures.runtime.run_parts import Bench
from station import instruments as roles
from station.endpoints import Endpoints
from station.preflight import instrument_problems
from station.station_file import load_settings

ROOT = Path(__file__).resolve().parents[2]
MANUAL = ROOT / "config" / "station-manual.yaml"


def _endpoints(table: str, family: str) -> Endpoints:
    return Endpoints(
        speed=100.0, rate_table=table, chamber="127.0.0.1:4002", supply="/dev/pts/77",
        duts={1: "/dev/pts/78"}, families={"rate_table": family, "inclinometer": "ascii-xy"},
        operator="127.0.0.1:4009", inclinometers={1: "127.0.0.1:4011"},
    )


def test_the_manual_station_has_no_table_role_and_its_inclinometer_is_checked() -> None:
    settings = load_settings(MANUAL)
    assert roles.plan_role(settings, "rate_table") is None
    assert roles.settings_problems(settings) == []
    inclinometer = roles.plan_role(settings, "inclinometer")
    assert inclinometer is not None and inclinometer.name == "inclinometer.ascii-xy"
    assert roles.check_settings(settings, inclinometer) == []


def test_on_a_bench_without_a_table_the_role_is_absent_and_the_twins_are_used() -> None:
    settings = load_settings(MANUAL)
    bench = _endpoints("", "none")
    assert roles.plan_role(settings, "rate_table", bench) is None
    plan = roles.plan_role(settings, "inclinometer", bench)
    assert plan is not None and plan.settings["ports"] == {1: "127.0.0.1:4011"}
    # today's station.yaml names a table: on a bench that has one it is planned as before
    today = load_settings()
    assert roles.plan_role(today, "rate_table", _endpoints("127.0.0.1:4001", "modbus-servo"))
    assert roles.plan_role(today, "rate_table", bench) is None  # the bench has none


def test_a_procedure_that_moves_a_table_is_refused_on_a_station_without_one() -> None:
    bench: Any = Bench(chamber=object(), supply=object(), links={}, clock=None)  # type: ignore[arg-type]
    table_proc, table_file = load_procedure(ROOT / "config/procedures/eol-stop-method.yaml")
    manual_proc, manual_file = load_procedure(ROOT / "config/procedures/eol-manual-stop.yaml")
    product, _ = load_product(ROOT / "config/products/gyr130.yaml")  # its part temperatures
    problems = instrument_problems(table_proc, table_file, product, bench, 1)
    assert any("this station has no rate table" in p and "eol-manual-stop.yaml" in p
               for p in problems), problems
    assert instrument_problems(manual_proc, manual_file, product, bench, 1) == []
