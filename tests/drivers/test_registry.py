"""Drivers by configuration: names -> factories (entry points or module:attr), settings
checked by the driver's own model, attach_clock after the factory, clear errors otherwise."""

from __future__ import annotations

import importlib.metadata
from typing import Any

import pytest
from pydantic import ValidationError

from common.clock import ScaledClock
from drivers import registry

PINNED = {
    "rate_table.modbus-servo": "drivers.rate_table:factory",
    "rate_table.acutrol": "drivers.acutrol:factory",
    "chamber.watlow-f4": "drivers.chamber:factory",
    "chamber.watlow-f4t": "drivers.watlow_f4t:factory",
    "chamber.espec-p300": "drivers.espec_p300:factory",
    "supply.scpi": "drivers.supply:factory",
    "supply.keysight-e36300": "drivers.keysight_e36300:factory",
    "supply.rigol-dp800": "drivers.rigol_dp800:factory",
    "part.fixture": "drivers.part_link:factory",
    "part.replay": "drivers.replay_part:factory",
}


def test_the_ten_pinned_entry_points_are_registered() -> None:
    eps = {ep.name: ep.value for ep in importlib.metadata.entry_points(group=registry.GROUP)}
    assert {k: eps.get(k) for k in PINNED} == PINNED
    assert registry.registered("chamber") == [
        "chamber.espec-p300", "chamber.watlow-f4", "chamber.watlow-f4t"
    ]


@pytest.mark.parametrize("role", ["rate_table", "chamber", "supply", "part"])
def test_each_role_defaults_to_todays_family(role: str) -> None:
    name, factory = registry.resolve(role, None)
    assert name == registry.DEFAULT_DRIVERS[role]
    assert factory.__name__ == "factory"
    assert factory.__module__ == PINNED[name].partition(":")[0]


def test_short_names_and_module_attr_resolve() -> None:
    assert registry.resolve("chamber", "watlow-f4")[0] == "chamber.watlow-f4"
    name, factory = registry.resolve("chamber", "drivers.chamber:factory")
    assert name == "drivers.chamber:factory"
    assert factory is registry.resolve("chamber", None)[1]


def test_unknown_name_lists_the_registered_drivers_of_its_role() -> None:
    with pytest.raises(registry.DriverError) as info:
        registry.resolve("supply", "keithley-2230")
    text = str(info.value)
    assert "unknown driver 'supply.keithley-2230'" in text
    assert "supply.keysight-e36300, supply.rigol-dp800, supply.scpi" in text
    assert "chamber." not in text
    with pytest.raises(registry.DriverError, match="is not a supply driver"):
        registry.resolve("supply", "chamber.watlow-f4")


def test_an_entry_point_that_fails_to_load_says_why(monkeypatch: pytest.MonkeyPatch) -> None:
    broken = importlib.metadata.EntryPoint(
        name="chamber.broken", value="no_such_package.oven:factory", group=registry.GROUP
    )
    real = registry._entry_points()
    monkeypatch.setattr(registry, "_entry_points", lambda: [*real, broken])
    with pytest.raises(registry.DriverError) as info:
        registry.resolve("chamber", "broken")
    text = str(info.value)
    assert "entry point no_such_package.oven:factory failed to load" in text
    assert "ModuleNotFoundError" in text and "chamber.watlow-f4" in text


@pytest.mark.parametrize(
    "spec, words",
    [
        ("no_such_module_xyz:factory", "module 'no_such_module_xyz' cannot be imported"),
        ("drivers.chamber:no_factory", "has no attribute 'no_factory'"),
        ("drivers.chamber:NAME", "is a str, not a callable factory"),
        ("drivers.chamber:", "give module:attr"),
    ],
)
def test_module_attr_errors(spec: str, words: str) -> None:
    with pytest.raises(registry.DriverError, match=words):
        registry.resolve("chamber", spec)


def test_inclinometer_has_no_default() -> None:
    with pytest.raises(registry.DriverError, match="no default driver: name one"):
        registry.resolve("inclinometer", None)


class _Driver:
    def __init__(self, settings: dict[str, Any]) -> None:
        self.settings = settings
        self.clock: Any = None

    def attach_clock(self, clock: Any) -> None:
        self.clock = clock


def test_open_driver_calls_the_factory_then_attach_clock() -> None:
    clock = ScaledClock(50.0)
    settings = {"address": "x", "timeout_s": 2.0}
    driver = registry.open_driver(_Driver, settings, clock)
    assert driver.settings == settings and driver.settings is not settings
    assert driver.clock is clock
    plain = registry.open_driver(lambda s: object(), settings, clock)  # no attach_clock: fine
    assert not hasattr(plain, "clock")


def test_builtin_settings_are_validated_before_connecting() -> None:
    factory = registry.resolve("chamber", None)[1]
    with pytest.raises(ValidationError) as info:
        factory({"address": "not-an-address", "colour": "red"})
    kinds = {(e["loc"][0], e["type"]) for e in info.value.errors()}
    assert kinds == {("address", "value_error"), ("colour", "extra_forbidden")}
    assert registry.settings_model(factory).__name__ == "Settings"
    assert registry.driver_settings(
        {"driver": "x", "calibration_due": "2027-01-01", "expected_model": "M", "address": "a"}
    ) == {"address": "a"}


def test_docs_list_every_registered_drivers_settings() -> None:
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs/instruments.md").read_text()
    for name in PINNED:
        role = name.split(".", 1)[0]
        model = registry.settings_model(registry.resolve(role, name)[1])
        assert model is not None, name
        head = f"#### `{name}`\n"
        assert head in doc, name
        section = doc.split(head, 1)[1].split("\n#", 1)[0]
        missing = [f for f in model.model_fields if f"| `{f}` |" not in section]
        assert not missing, (name, missing)
