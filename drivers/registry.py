"""Drivers chosen by configuration: a name in station.yaml -> a factory -> a driver object.

`instruments.<role>.driver` names either a registered driver, an entry point of the group
`gyrocal.drivers` named `<role>.<name>` (a separate package adds one with no change here), or
`module:attr`, any importable callable. A factory is `factory(settings: dict) -> driver`: it
validates `settings` (the role's entry in station.yaml without the station's own keys) with
its own pydantic model, letting `ValidationError` propagate, and connects. A driver that
waits in station time also has `attach_clock(clock)`, called right after the factory.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import logging
from collections.abc import Callable, Mapping
from typing import Any

from common.clock import Clock
from drivers.protocols import ClockUser

log = logging.getLogger(__name__)

GROUP = "gyrocal.drivers"
ROLES = ("rate_table", "chamber", "supply", "part", "inclinometer")
# the family each role gets when station.yaml names no driver (today's instruments)
DEFAULT_DRIVERS: dict[str, str] = {
    "rate_table": "rate_table.modbus-servo",
    "chamber": "chamber.watlow-f4",
    "supply": "supply.scpi",
    "part": "part.fixture",
}
# keys of a role's entry the station keeps for itself (never given to the driver):
# expected_model is checked by the station against the driver's identify()
STATION_KEYS = frozenset({"driver", "calibration_due", "expected_model"})

Factory = Callable[[dict[str, Any]], Any]


class DriverError(ValueError):
    """A driver name that cannot be resolved to a factory; the message says what to do."""


def _entry_points() -> list[importlib.metadata.EntryPoint]:
    return list(importlib.metadata.entry_points(group=GROUP))


def registered(role: str | None = None) -> list[str]:
    """Registered driver names (`<role>.<name>`), sorted; only `role`'s when given."""
    names = {ep.name for ep in _entry_points()}
    if role is not None:
        names = {n for n in names if n.startswith(f"{role}.")}
    return sorted(names)


def full_name(role: str, driver: str) -> str:
    """`watlow-f4` -> `chamber.watlow-f4`; a `module:attr` or a full name is kept."""
    driver = driver.strip()
    if ":" in driver or driver.split(".", 1)[0] in ROLES:
        return driver
    return f"{role}.{driver}"


def resolve(role: str, driver: str | None) -> tuple[str, Factory]:
    """The factory `driver` names for `role` (None: the role's default): (name, factory)."""
    if driver is None:
        if role not in DEFAULT_DRIVERS:
            raise DriverError(
                f"instruments.{role} has no default driver: name one with driver: "
                f"(registered: {_listing(role)}) or module:attr"
            )
        driver = DEFAULT_DRIVERS[role]
    name = full_name(role, driver)
    factory = _import_attr(role, name) if ":" in name else _load_entry_point(role, name)
    if not callable(factory):
        raise DriverError(
            f"instruments.{role}.driver {name!r} is a {type(factory).__name__}, not a callable "
            "factory(settings) -> driver"
        )
    return name, factory


def _listing(role: str) -> str:
    names = registered(role)
    if names:
        return ", ".join(names)
    return "none" if registered() else "none; is the station installed (pip install -e .)?"


def _load_entry_point(role: str, name: str) -> Factory:
    if name.split(".", 1)[0] != role:
        raise DriverError(
            f"instruments.{role}.driver: {name!r} is not a {role} driver; registered "
            f"{role} drivers: {_listing(role)} (or give module:attr)"
        )
    matches = [ep for ep in _entry_points() if ep.name == name]
    if not matches:
        raise DriverError(
            f"instruments.{role}.driver: unknown driver {name!r}; registered "
            f"{role} drivers: {_listing(role)} (or give module:attr)"
        )
    ep = matches[0]
    try:
        factory: Factory = ep.load()
    except Exception as exc:  # noqa: BLE001 - any import failure of a plugin is reported
        raise DriverError(
            f"instruments.{role}.driver {name!r}: its entry point {ep.value} failed to load "
            f"({type(exc).__name__}: {exc}); install the package that provides it or choose "
            f"another driver ({_listing(role)})"
        ) from None
    return factory


def _import_attr(role: str, spec: str) -> Factory:
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise DriverError(
            f"instruments.{role}.driver {spec!r}: give module:attr, e.g. my_drivers.oven:factory"
        )
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # noqa: BLE001 - a plugin's import error is the user's to fix
        raise DriverError(
            f"instruments.{role}.driver {spec!r}: module {module_name!r} cannot be imported "
            f"({type(exc).__name__}: {exc}); check PYTHONPATH or install its package"
        ) from None
    obj: Any = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise DriverError(
                f"instruments.{role}.driver {spec!r}: module {module_name!r} has no "
                f"attribute {attr!r}"
            )
        obj = getattr(obj, part)
    return obj


def driver_settings(entry: Mapping[str, Any]) -> dict[str, Any]:
    """A role's station.yaml entry as its driver's settings (the station's keys removed)."""
    return {k: v for k, v in entry.items() if k not in STATION_KEYS}


def settings_model(factory: Factory) -> Any:
    """The pydantic model a factory validates with, where it can be found (its `Settings`
    attribute, or its module's), for messages that list the allowed fields; else None."""
    model = getattr(factory, "Settings", None)
    if model is None:
        module = importlib.import_module(getattr(factory, "__module__", "") or "builtins")
        model = getattr(module, "Settings", None)
    return model if hasattr(model, "model_fields") else None


def open_driver(factory: Factory, settings: dict[str, Any], clock: Clock) -> Any:
    """`factory(settings)`, then `attach_clock(clock)` where the driver has it.

    pydantic's ValidationError (bad settings) and the driver's InstrumentError propagate."""
    driver = factory(dict(settings))
    if isinstance(driver, ClockUser):
        driver.attach_clock(clock)
    return driver
