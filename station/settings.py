"""The station file (config/station.yaml): which instruments, where, and where results go.

Validated with pydantic at the edge; errors name the file, line and field (see
`procedures.config.load_yaml_model`). Relative paths inside the file are relative to the
folder that holds it, so the file can travel with its configuration folder.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, field_validator

from procedures.config import LoadedYaml, load_yaml_model

REPO_ROOT = Path(__file__).resolve().parents[1]
CONFIG_DIR = REPO_ROOT / "config"
DEFAULT_STATION_FILE = CONFIG_DIR / "station.yaml"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class StationInfo(_Strict):
    id: str = Field(description="station identifier printed on certificates")
    name: str = ""
    location: str = ""


_DRIVER_HELP = (
    "driver of this role: a registered name such as chamber.watlow-f4t (see docs/"
    "instruments.md) or module:attr of any factory(settings) -> driver; default: today's family"
)


class InstrumentSettings(BaseModel):
    """One instrument role. Besides the station's own keys (driver, calibration_due,
    expected_model) every key is the driver's setting, checked by the driver's own model when
    the station prepares a run (address in the driver's form, timeout_s, ...)."""

    model_config = ConfigDict(extra="allow", frozen=True)

    driver: str | None = Field(None, min_length=1, description=_DRIVER_HELP)
    address: str = Field(
        "",
        description="in the driver's own form: host:port (Modbus TCP, ASCII over TCP), a VISA "
        "resource (TCPIP::host::5025::SOCKET, ASRL/dev/ttyUSB0::INSTR) or a serial device",
    )
    expected_model: str = Field("", description="if set, the identity must contain this model")
    calibration_due: dt.date | None = Field(
        None, description="ISO date (YYYY-MM-DD) the instrument's own calibration expires"
    )

    def driver_settings(self) -> dict[str, Any]:
        """The keys for the driver: those given in station.yaml, the station's own left out."""
        given = self.model_dump(exclude_unset=True)
        given.update(self.model_extra or {})
        return {
            k: v for k, v in given.items()
            if k not in ("driver", "calibration_due", "expected_model")
        }


class FixtureSettings(BaseModel):
    """The part role (key fixture, or part): the fixture's sockets and their ports; other
    keys are the part driver's settings (baud, timeout_s, ...)."""

    model_config = ConfigDict(extra="allow", frozen=True)

    driver: str | None = Field(None, min_length=1, description=_DRIVER_HELP)
    sockets: int = Field(1, ge=1, le=16, description="number of part sockets")
    ports: dict[int, str] = Field(
        default_factory=dict, description="socket number -> serial port of its microcontroller"
    )
    baud: int = Field(
        115200,
        gt=0,
        description="serial baud rate of every socket; must carry the procedure's output rate "
        "(25-byte frames, 10 bits a byte: 200 Hz needs 50,000, 500 Hz needs 230,400)",
    )
    calibration_due: dt.date | None = Field(None, description="stop-angle calibration expiry")

    def driver_settings(self, socket: int, address: str) -> dict[str, Any]:
        """One socket's settings for the part driver: the given keys (the station's own and
        sockets/ports left out), the socket's port as `address` and its number as `socket`."""
        given = self.model_dump(exclude_unset=True)
        given.update(self.model_extra or {})
        out = {
            k: v for k, v in given.items()
            if k not in ("driver", "calibration_due", "sockets", "ports")
        }
        out.update(address=address, socket=socket)
        return out

    @field_validator("ports")
    @classmethod
    def _sockets(cls, value: dict[int, str]) -> dict[int, str]:
        if any(k < 1 for k in value):
            raise ValueError("socket numbers start at 1")
        return value


class Instruments(_Strict):
    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)

    rate_table: InstrumentSettings = InstrumentSettings()
    chamber: InstrumentSettings = InstrumentSettings()
    supply: InstrumentSettings = InstrumentSettings()
    fixture: FixtureSettings = Field(
        FixtureSettings(),
        validation_alias=AliasChoices("fixture", "part"),
        description="the part role: the fixture's sockets (key fixture or part)",
    )
    inclinometer: InstrumentSettings | None = Field(
        None, description="optional: an inclinometer (no built-in driver; name one)"
    )

    def role_entry(self, role: str) -> InstrumentSettings | None:
        """The entry of a station role (rate_table, chamber, supply, inclinometer)."""
        entry = getattr(self, role, None)
        return entry if isinstance(entry, InstrumentSettings) else None


class UiSettings(_Strict):
    """The browser UI (`station ui`)."""

    engineer_password_hash: str | None = Field(
        None,
        description="scrypt hash of the engineer password; make it with "
        "`station ui --hash-password` (never the password itself)",
    )


class StationSettings(_Strict):
    """Everything specific to one physical station."""

    station: StationInfo
    instruments: Instruments = Instruments()
    output_folder: str = Field("runs", description="run folders go here (relative to this file)")
    results_db: str = Field(
        "runs/results.sqlite", description="SQLite results database (relative to this file)"
    )
    procedure: str = Field(
        "procedures/eol-rate-table.yaml", description="default procedure (relative to this file)"
    )
    sim_config: str | None = Field(
        None, description="simulated bench configuration used by --sim (relative to this file)"
    )
    refuse_overdue_instruments: bool = Field(
        False, description="refuse to run when an instrument's calibration is overdue"
    )
    ui: UiSettings = Field(default_factory=UiSettings, description="browser UI settings")


@dataclass(frozen=True)
class LoadedSettings:
    settings: StationSettings
    source: LoadedYaml

    @property
    def folder(self) -> Path:
        return self.source.path.resolve().parent

    def resolve(self, relative: str) -> Path:
        p = Path(relative).expanduser()
        return p if p.is_absolute() else (self.folder / p).resolve()

    @property
    def output_folder(self) -> Path:
        return self.resolve(self.settings.output_folder)

    @property
    def results_db(self) -> Path:
        return self.resolve(self.settings.results_db)

    @property
    def procedure(self) -> Path:
        return self.resolve(self.settings.procedure)


def load_settings(path: Path | None = None) -> LoadedSettings:
    """Load station.yaml (default: config/station.yaml of this installation)."""
    model, loaded = load_yaml_model(Path(path or DEFAULT_STATION_FILE), StationSettings)
    return LoadedSettings(settings=model, source=loaded)
