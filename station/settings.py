"""The station file (config/station.yaml): which instruments, where, and where results go.

Validated with pydantic at the edge; errors name the file, line and field (see
`procedures.config.load_yaml_model`). Relative paths inside the file are relative to the
folder that holds it, so the file can travel with its configuration folder.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, field_validator

from drivers.bounded import Name, PathText, ShortName
from procedures.config import LoadedYaml, load_yaml_model

REPO_ROOT = Path(__file__).resolve().parents[1]
CONFIG_DIR = REPO_ROOT / "config"
DEFAULT_STATION_FILE = CONFIG_DIR / "station.yaml"
MAX_BAUD = 10_000_000
MAX_TIMEOUT_S = 600.0  # a communication timeout, wall seconds


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class StationInfo(_Strict):
    id: ShortName = Field(min_length=1, description="station identifier printed on certificates")
    name: Name = ""
    location: Name = ""


class InstrumentSettings(_Strict):
    address: PathText = Field(
        "", description="host:port for Modbus TCP, or a serial port (e.g. /dev/ttyUSB0)"
    )
    baud: int = Field(
        115200, gt=0, le=MAX_BAUD, description="serial baud rate (serial instruments only)"
    )
    expected_model: Name = Field("", description="if set, the identity must contain this model")
    calibration_due: dt.date | None = Field(
        None, description="ISO date (YYYY-MM-DD) the instrument's own calibration expires"
    )
    timeout_s: float = Field(
        1.0, gt=0, le=MAX_TIMEOUT_S, description="communication timeout, wall seconds"
    )


class FixtureSettings(_Strict):
    sockets: int = Field(1, ge=1, le=16, description="number of part sockets")
    ports: dict[int, PathText] = Field(
        default_factory=dict,
        max_length=16,
        description="socket number -> serial port of its microcontroller",
    )
    baud: int = Field(
        115200,
        gt=0,
        le=MAX_BAUD,
        description="serial baud rate of every socket; must carry the procedure's output rate "
        "(25-byte frames, 10 bits a byte: 200 Hz needs 50,000, 500 Hz needs 230,400)",
    )
    calibration_due: dt.date | None = Field(None, description="stop-angle calibration expiry")

    @field_validator("ports")
    @classmethod
    def _sockets(cls, value: dict[int, str]) -> dict[int, str]:
        if any(not 1 <= k <= 16 for k in value):
            raise ValueError("socket numbers are 1..16")
        return value


class Instruments(_Strict):
    rate_table: InstrumentSettings = InstrumentSettings()
    chamber: InstrumentSettings = InstrumentSettings()
    supply: InstrumentSettings = InstrumentSettings()
    fixture: FixtureSettings = FixtureSettings()


class UiSettings(_Strict):
    """The browser UI (`station ui`)."""

    engineer_password_hash: str | None = Field(
        None,
        max_length=1_000,
        description="scrypt hash of the engineer password; make it with "
        "`station ui --hash-password` (never the password itself)",
    )


class StationSettings(_Strict):
    """Everything specific to one physical station."""

    station: StationInfo
    instruments: Instruments = Instruments()
    output_folder: PathText = Field(
        "runs", description="run folders go here (relative to this file)"
    )
    results_db: PathText = Field(
        "runs/results.sqlite", description="SQLite results database (relative to this file)"
    )
    procedure: PathText = Field(
        "procedures/eol-rate-table.yaml", description="default procedure (relative to this file)"
    )
    sim_config: PathText | None = Field(
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
