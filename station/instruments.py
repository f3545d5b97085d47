"""The station's instruments by configuration: station.yaml's roles -> drivers, opened.

Each role's entry in station.yaml names its driver (`driver:`, default: today's family) and
holds that driver's settings. On the simulated bench the state file says which family each
twin serves and where: a role whose driver station.yaml does not name gets the registered
driver of that family; a role whose driver it names keeps it and is given the twin's address
(so a plugin can be tried on the bench). Errors are the station's: a bad driver name or bad
settings is a `UserError` in station.yaml's file:line form; an instrument that cannot be
reached raises the driver's `InstrumentError` (or OSError) for the caller to word.
"""

from __future__ import annotations

import datetime as dt
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from common.clock import Clock, ScaledClock
from drivers import registry
from drivers.errors import InstrumentError
from drivers.protocols import Identifiable, InstrumentIdentity, Probeable
from station.errors import UserError
from station.settings import FixtureSettings, InstrumentSettings, LoadedSettings

if TYPE_CHECKING:
    from station.endpoints import Endpoints

log = logging.getLogger(__name__)

# role -> its key in station.yaml's instruments (the part role keeps today's key, fixture)
ROLE_KEYS = {
    "rate_table": "rate_table",
    "chamber": "chamber",
    "supply": "supply",
    "part": "fixture",
    "inclinometer": "inclinometer",
}
# role -> the sim config's key that gives the bench a twin for it, and a family to name there
SIM_KEYS = {
    "rate_table": ("instruments.rate_table", "modbus-servo"),
    "chamber": ("instruments.chamber", "watlow-f4"),
    "supply": ("instruments.supply", "scpi"),
    "inclinometer": ("instruments.inclinometer", "ascii-xy"),
}
ROLE_NAMES = {
    "rate_table": "rate table",
    "chamber": "chamber",
    "supply": "supply",
    "part": "fixture",
    "inclinometer": "inclinometer",
}


@dataclass(frozen=True)
class RoleDriver:
    """One role's driver as the station will open it."""

    role: str
    name: str  # registered name or module:attr
    factory: registry.Factory
    settings: dict[str, Any]
    yaml_path: tuple[str | int, ...]  # where the role's entry sits in station.yaml
    calibration_due: dt.date | None = None
    expected_model: str = ""
    socket: int | None = None  # the part role: which fixture socket

    @property
    def address(self) -> str:
        """Where the instrument is: its address, or for a per-socket instrument (the
        inclinometers) its ports as "1=host:port, 2=..."."""
        if self.settings.get("address"):
            return str(self.settings["address"])
        ports = self.settings.get("ports") or {}
        return ", ".join(f"{sock}={port}" for sock, port in sorted(ports.items()))

    @property
    def label(self) -> str:
        who = ROLE_NAMES.get(self.role, self.role)
        return f"{who} {self.socket}" if self.socket is not None else who


def _yaml_key(loaded: LoadedSettings, role: str) -> str:
    if role == "part" and ("instruments", "part") in loaded.source.lines:
        return "part"
    return ROLE_KEYS[role]


def _line(loaded: LoadedSettings, path: Sequence[str | int]) -> str:
    """`file:line` of the deepest known part of `path` in station.yaml."""
    for n in range(len(path), -1, -1):
        line = loaded.source.lines.get(tuple(path[:n]))
        if line is not None:
            return f"{loaded.source.path}:{line}"
    return str(loaded.source.path)


def _resolve(loaded: LoadedSettings, role: str, driver: str | None) -> tuple[str, Any]:
    try:
        return registry.resolve(role, driver)
    except registry.DriverError as exc:
        key = _yaml_key(loaded, role)
        raise UserError(f"{_line(loaded, ('instruments', key, 'driver'))}: {exc}") from None


def _sim_driver(
    role: str, configured: str | None, endpoints: Endpoints | None
) -> tuple[str | None, bool]:
    """The driver to use and whether station.yaml's settings go with it (else only those the
    bench's family also takes do: the bench serves another family than station.yaml's)."""
    if endpoints is None or configured is not None:
        return configured, True
    family = endpoints.families.get(role)
    default = registry.DEFAULT_DRIVERS.get(role)
    if family is None or f"{role}.{family}" == default:
        return None, True
    return f"{role}.{family}", False


def _carried_over(
    given: dict[str, Any], factory: Any, role: str, name: str
) -> dict[str, Any]:
    """station.yaml's settings for another family, as far as the bench's family `name` takes
    them (a supply's max_voltage_v, a timeout); the others are left out, with a warning, so a
    limit written for the real instrument is never dropped without a word."""
    model = registry.settings_model(factory)
    accepted = set(model.model_fields) if model is not None else {"address", "timeout_s"}
    kept = {k: v for k, v in given.items() if k in accepted}
    dropped = sorted(set(given) - set(kept))
    if dropped:
        log.warning(
            "instruments.%s: the simulated bench serves %s, which has no setting %s; "
            "those station.yaml settings are not used on the bench",
            ROLE_KEYS.get(role, role), name, ", ".join(dropped),
        )
    return kept


def plan_role(
    loaded: LoadedSettings, role: str, endpoints: Endpoints | None = None
) -> RoleDriver | None:
    """The driver of one station role (not the part role); None for an absent optional one."""
    cfg = loaded.settings.instruments
    entry: InstrumentSettings | None = getattr(cfg, role, None)
    if entry is None or table_absent(loaded, role, endpoints):
        return None
    if endpoints is not None and not endpoints.serves(role):
        raise UserError(not_served(loaded, role))
    driver, own_settings = _sim_driver(role, entry.driver, endpoints)
    name, factory = _resolve(loaded, role, driver)
    given = entry.driver_settings()
    settings = given if own_settings else _carried_over(given, factory, role, name)
    if endpoints is not None and endpoints.address(role):
        settings["address"] = endpoints.address(role)
    if role == "inclinometer" and endpoints is not None and endpoints.inclinometers:
        settings["ports"] = dict(endpoints.inclinometers)  # the twins on the bench's fixtures
        settings.pop("address", None)
    return RoleDriver(
        role, name, factory, settings, ("instruments", _yaml_key(loaded, role)),
        entry.calibration_due, entry.expected_model,
    )


def not_served(loaded: LoadedSettings, role: str) -> str:
    """One line: station.yaml names a role the simulated bench has no twin for. --sim never
    falls back to station.yaml's own address (a real instrument, perhaps on the LAN)."""
    key, family = SIM_KEYS.get(role, (f"instruments.{role}", "<family>"))
    return (
        f"{_line(loaded, ('instruments', _yaml_key(loaded, role)))}: station.yaml names the "
        f"{ROLE_NAMES.get(role, role)} but the simulated bench does not serve it: set "
        f"{key}: {family} in the sim config (--sim-config), or leave instruments."
        f"{_yaml_key(loaded, role)} out of station.yaml for simulated runs"
    )


def table_absent(loaded: LoadedSettings, role: str, endpoints: Endpoints | None) -> bool:
    """A station without a rate table (the article's hand-turned bench): station.yaml has no
    rate_table entry, or the simulated bench serves none. The role is absent, not broken."""
    if role != "rate_table":
        return False
    if endpoints is not None:
        return endpoints.families.get(role) == "none" or (
            not endpoints.address(role) and ("instruments", role) not in loaded.source.lines
        )
    return ("instruments", role) not in loaded.source.lines


def plan_part(
    loaded: LoadedSettings, socket: int, port: str, endpoints: Endpoints | None = None
) -> RoleDriver:
    """The part driver of one fixture socket, given the socket's port (or file)."""
    fixture: FixtureSettings = loaded.settings.instruments.fixture
    driver, own_settings = _sim_driver("part", fixture.driver, endpoints)
    name, factory = _resolve(loaded, "part", driver)
    settings = fixture.driver_settings(socket, port)
    if not own_settings:
        settings = _carried_over(settings, factory, "part", name)
    return RoleDriver(
        "part", name, factory, settings, ("instruments", _yaml_key(loaded, "part")),
        fixture.calibration_due, socket=socket,
    )


def format_settings_error(
    exc: ValidationError, loaded: LoadedSettings, plan: RoleDriver, *, missing: bool = True
) -> str:
    """One line per problem: `station.yaml:line: field instruments.<key>.<field>: message`
    (`missing=False`: required settings left out are not reported)."""
    model = registry.settings_model(plan.factory)
    allowed = sorted(model.model_fields) if model is not None else []
    out = []
    for err in exc.errors():
        if not missing and err["type"] == "missing":
            continue
        loc = [str(p) for p in err["loc"]]
        path: list[str | int] = [*plan.yaml_path, *loc]
        if plan.socket is not None and loc[:1] == ["address"]:
            path = [*plan.yaml_path, "ports", plan.socket]
        elif plan.socket is not None and loc[:1] == ["socket"]:
            path = [*plan.yaml_path, "ports"]
        field = ".".join(str(p) for p in path[1:])
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown field for this driver" + (
                f"; allowed: {', '.join(allowed)}" if allowed else ""
            )
        elif err["type"] == "missing":
            msg = "required field is missing"
        out.append(f"{_line(loaded, path)}: field instruments.{field}: {msg} (driver {plan.name})")
    return "\n".join(out)


def check_settings(
    loaded: LoadedSettings, plan: RoleDriver, *, missing: bool = True
) -> list[str]:
    """Problems with a role's settings, found without connecting (where the driver's model
    can be found; otherwise the factory itself checks them when it is called)."""
    model = registry.settings_model(plan.factory)
    if model is None:
        return []
    try:
        model.model_validate(plan.settings)
    except ValidationError as exc:
        return format_settings_error(exc, loaded, plan, missing=missing).splitlines()
    return []


def open_role(loaded: LoadedSettings, plan: RoleDriver, clock: Clock) -> Any:
    """Open one role's driver: factory(settings), attach_clock. Bad settings are a UserError
    in file:line form; an unreachable instrument raises the driver's error, reworded to say
    which role, driver and address."""
    try:
        driver = registry.open_driver(plan.factory, plan.settings, clock)
    except ValidationError as exc:
        raise UserError(format_settings_error(exc, loaded, plan)) from None
    except (InstrumentError, OSError) as exc:
        raise Unreachable(plan, exc) from exc
    if plan.expected_model and isinstance(driver, Identifiable):
        model = driver.identify().model
        if plan.expected_model not in model:
            _close_quietly(driver)
            raise UserError(
                f"{_line(loaded, (*plan.yaml_path, 'expected_model'))}: the {plan.label} at "
                f"{plan.address} identifies as {model!r}, not {plan.expected_model!r}: check "
                "its address or expected_model"
            )
    return driver


class Unreachable(InstrumentError):  # noqa: N818 - named like drivers.errors
    """An instrument could not be opened: which role, driver and address, and why."""

    def __init__(self, plan: RoleDriver, cause: BaseException) -> None:
        super().__init__(
            f"cannot reach the {plan.label} at {plan.address or '(no address)'} (driver "
            f"{plan.name}): {cause}",
            instrument=plan.label,
        )
        self.plan = plan


def identity(driver: Any) -> InstrumentIdentity | None:
    return driver.identify() if isinstance(driver, Identifiable) else None


def _close_quietly(driver: Any) -> None:
    close = getattr(driver, "close", None)
    if close is None:
        return
    try:
        close()
    except Exception as exc:  # noqa: BLE001 - closing a dead link must not hide the error
        log.info("closing an instrument: %s", exc)


def probe_role(plan: RoleDriver) -> tuple[bool, str]:
    """(reachable, what it reports) for the instrument lights: opened with its own driver,
    asked its own `probe()` (or `identify()` when it has none), closed."""
    try:
        driver = registry.open_driver(plan.factory, plan.settings, ScaledClock(1.0))
    except Exception as exc:  # noqa: BLE001 - any failure to open is "not connected"
        return False, f"no answer at {plan.address or '(no address)'}: {exc}"
    try:
        if isinstance(driver, Probeable):
            return True, driver.probe()
        identity(driver)
        return True, ""
    except Exception as exc:  # noqa: BLE001 - a failing query is a fault light
        return True, f"does not answer its queries: {exc}"
    finally:
        _close_quietly(driver)


def station_roles(needs_table: bool) -> list[str]:
    """The roles a run opens besides the part links, in opening order."""
    return [*(["rate_table"] if needs_table else []), "chamber", "supply", "inclinometer"]



def settings_problems(loaded: LoadedSettings) -> list[str]:
    """Every role's driver resolved and its settings checked against the driver's own model,
    without connecting (station.yaml's load): one line per problem, file:line."""
    problems: list[str] = []
    plans: list[RoleDriver] = []
    for role in station_roles(needs_table=True):
        if ("instruments", role) not in loaded.source.lines:
            continue  # not configured here: checked when a run needs it
        try:
            plan = plan_role(loaded, role)
        except UserError as exc:
            problems.append(str(exc))
            continue
        if plan is not None:
            plans.append(plan)
    fixture = loaded.settings.instruments.fixture
    for sock, port in sorted(fixture.ports.items()):
        try:
            plans.append(plan_part(loaded, sock, port))
        except UserError as exc:
            problems.append(str(exc))
            break
    for plan in plans:  # a setting left out is said when a run needs the instrument
        problems += check_settings(loaded, plan, missing=False)
    return list(dict.fromkeys(problems))
