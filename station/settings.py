"""The station file (config/station.yaml): which instruments, where, and where results go.

Validated with pydantic at the edge; errors name the file, line and field (see
`common.yaml_input.load_yaml_model`). Relative paths inside the file are relative to the
folder that holds it, so the file can travel with its configuration folder. The model only:
`station.station_file.load_settings` reads the file and has each driver check its settings.
"""

from __future__ import annotations

import datetime as dt
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, field_validator, model_validator

from common.bounded import Name, PathText, ShortName
from common.yaml_input import LoadedYaml

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


_DRIVER_HELP = (
    "driver of this role: a registered name such as chamber.watlow-f4t (see docs/"
    "instruments.md) or module:attr of any factory(settings) -> driver; default: today's family"
)


REFERENCE_KEYS = ("calibration_certificate", "reference_uncertainty")  # station's, not drivers'


class InstrumentSettings(BaseModel):
    """One instrument role. Besides the station's own keys (driver, calibration_due,
    expected_model) every key is the driver's setting, checked by the driver's own model when
    the station prepares a run (address in the driver's form, timeout_s, ...)."""

    model_config = ConfigDict(extra="allow", frozen=True, allow_inf_nan=False)

    driver: PathText | None = Field(None, min_length=1, description=_DRIVER_HELP)
    address: PathText = Field(
        "",
        description="in the driver's own form: host:port (Modbus TCP, ASCII over TCP), a VISA "
        "resource (TCPIP::host::5025::SOCKET, ASRL/dev/ttyUSB0::INSTR) or a serial device",
    )
    expected_model: Name = Field("", description="if set, the identity must contain this model")
    calibration_due: dt.date | None = Field(
        None, description="ISO date (YYYY-MM-DD) the instrument's own calibration expires"
    )
    calibration_certificate: Name = Field(
        "", description="number of the instrument's calibration certificate (on certificates)"
    )
    reference_uncertainty: Name = Field(
        "", description="its uncertainty as a reference, e.g. '0.005 % of rate (k = 2)'"
    )

    def driver_settings(self) -> dict[str, Any]:
        """The keys for the driver: those given in station.yaml, the station's own left out."""
        given = self.model_dump(exclude_unset=True)
        given.update(self.model_extra or {})
        return {
            k: v for k, v in given.items()
            if k not in ("driver", "calibration_due", "expected_model", *REFERENCE_KEYS)
        }


MAX_SOCKETS = 64  # a load of 32 sockets is four boards of eight; room for eight boards


class FixtureBoard(BaseModel):
    """One fixture board: its name and its sockets' serial ports (a board of eight sockets
    brings eight ports, one per socket's microcontroller, docs/fixture-protocol.md)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: ShortName = Field(min_length=1, description="the board's name (label on the line)")
    ports: dict[int, PathText] = Field(
        min_length=1,
        max_length=MAX_SOCKETS,
        description="socket number (of the whole load) -> serial port on this board",
    )


class FixtureSettings(BaseModel):
    """The part role (key fixture, or part): the fixture's sockets and their ports; other
    keys are the part driver's settings (baud, timeout_s, ...). A load on several fixture
    boards lists them under `boards:`; their ports join `ports`."""

    model_config = ConfigDict(extra="allow", frozen=True, allow_inf_nan=False)

    driver: PathText | None = Field(None, min_length=1, description=_DRIVER_HELP)
    sockets: int = Field(1, ge=1, le=MAX_SOCKETS, description="number of part sockets")
    ports: dict[int, PathText] = Field(
        default_factory=dict,
        max_length=MAX_SOCKETS,
        description="socket number -> serial port of its microcontroller",
    )
    boards: list[FixtureBoard] = Field(
        default_factory=list,
        max_length=8,
        description="fixture boards, each with its sockets' ports (merged into ports)",
    )
    baud: int = Field(
        115200,
        gt=0,
        le=MAX_BAUD,
        description="serial baud rate of every socket; must carry the procedure's output rate "
        "(25-byte frames, 10 bits a byte: 200 Hz needs 50,000, 500 Hz needs 230,400)",
    )
    calibration_due: dt.date | None = Field(None, description="stop-angle calibration expiry")
    calibration_certificate: Name = Field(
        "", description="number of the stop angle's (inclinometer's) calibration certificate"
    )
    reference_uncertainty: Name = Field("", description="uncertainty of the stop angle")

    def driver_settings(self, socket: int, address: str) -> dict[str, Any]:
        """One socket's settings for the part driver: the given keys (the station's own and
        sockets/ports left out), the socket's port as `address` and its number as `socket`."""
        given = self.model_dump(exclude_unset=True)
        given.update(self.model_extra or {})
        out = {
            k: v for k, v in given.items()
            if k not in (
                "driver", "calibration_due", "sockets", "ports", "boards", *REFERENCE_KEYS
            )
        }
        out.update(address=address, socket=socket)
        return out

    @field_validator("ports")
    @classmethod
    def _sockets(cls, value: dict[int, str]) -> dict[int, str]:
        if any(not 1 <= k <= MAX_SOCKETS for k in value):
            raise ValueError(f"socket numbers are 1..{MAX_SOCKETS}")
        return value

    @model_validator(mode="after")
    def _boards_ports(self) -> FixtureSettings:
        """Every board's ports join `ports`; a socket on two boards (or on a board and in
        ports) is refused, and `sockets` covers the highest socket a board names."""
        if not self.boards:
            return self
        ports = dict(self.ports)
        for board in self.boards:
            for sock, path in board.ports.items():
                if not 1 <= sock <= MAX_SOCKETS:
                    raise ValueError(f"board {board.name}: socket numbers are 1..{MAX_SOCKETS}")
                if sock in ports:
                    raise ValueError(
                        f"socket {sock} is given two ports (board {board.name} and another); "
                        "give each socket one port"
                    )
                ports[sock] = path
        object.__setattr__(self, "ports", ports)
        object.__setattr__(self, "sockets", max(self.sockets, max(ports)))
        return self

    def board_of(self, socket: int) -> str | None:
        """The name of the board that holds `socket` (None when no board names it)."""
        for board in self.boards:
            if socket in board.ports:
                return board.name
        return None


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
        None,
        description="optional: an inclinometer (no default driver; name one, e.g. "
        "inclinometer.ascii-xy)",
    )

    def role_entry(self, role: str) -> InstrumentSettings | None:
        """The entry of a station role (rate_table, chamber, supply, inclinometer)."""
        entry = getattr(self, role, None)
        return entry if isinstance(entry, InstrumentSettings) else None


class OperatorEntry(_Strict):
    """One operator who may sign in at the browser station (badge scan, or name and PIN)."""

    name: str = Field(
        min_length=1,
        max_length=64,
        pattern=r"^[^\x00-\x1f\x7f]+$",
        description="the name recorded on every run the operator starts",
    )
    pin_hash: str | None = Field(
        None,
        max_length=256,
        description="scrypt hash of the operator's PIN; make it with `station ui --hash-pin`",
    )
    badge_hash: str | None = Field(
        None,
        max_length=256,
        description="salted hash of the operator's badge code; make it with "
        "`station ui --hash-badge`",
    )
    role: Literal["operator", "quality"] = Field(
        "operator", description="quality: may also approve runs in the review screen"
    )


class UiSettings(_Strict):
    """The browser UI (`station ui`)."""

    engineer_password_hash: str | None = Field(
        None,
        max_length=256,
        description="scrypt hash of the engineer password; make it with "
        "`station ui --hash-password` (never the password itself)",
    )
    operators: list[OperatorEntry] = Field(
        default_factory=list,
        max_length=1000,
        description="operators who sign in by badge or name and PIN; empty: an open station "
        "where the operator signs in with a name only",
    )
    require_operator: bool = Field(
        False, description="refuse to start a run until an operator has signed in"
    )
    allowed_hosts: list[str] = Field(
        default_factory=list,
        max_length=64,
        description="host names the browser may use to reach the station besides the loopback "
        "names and the --host address (e.g. the station's DNS name on the line network)",
    )
    tls_certificate: str | None = Field(
        None,
        max_length=4096,
        description="PEM certificate for HTTPS (relative to this file); needed to listen "
        "beyond loopback",
    )
    tls_key: str | None = Field(
        None, max_length=4096, description="PEM private key of tls_certificate (relative)"
    )
    max_connections: int = Field(
        256, ge=8, le=4096,
        description="connections the screen's server holds at once; beyond it the oldest "
        "idle one is closed (docs/ui-security.md)",
    )
    max_connections_per_client: int = Field(
        64, ge=4, le=4096,
        description="connections from one address (every loopback client is one address)",
    )
    language: str | None = Field(
        None,
        pattern=r"^[a-z]{2,3}$",
        description="language of the operator screen (a catalog under station/ui/messages, "
        "e.g. en, de); unset: the browser's language when the station has it, else English",
    )

    @field_validator("allowed_hosts")
    @classmethod
    def _hosts(cls, value: list[str]) -> list[str]:
        for host in value:
            if not re.fullmatch(r"[A-Za-z0-9._:\[\]-]{1,253}", host):
                raise ValueError(f"{host!r} is not a host name or address")
        return [h.lower() for h in value]

    @model_validator(mode="after")
    def _consistent(self) -> UiSettings:
        if self.require_operator and not self.operators:
            raise ValueError("require_operator needs at least one entry under ui.operators")
        names = [o.name.casefold() for o in self.operators]
        if len(set(names)) != len(names):
            raise ValueError("two operators have the same name; names must be unique")
        for o in self.operators:
            if not o.pin_hash and not o.badge_hash:
                raise ValueError(f"operator {o.name!r} has neither pin_hash nor badge_hash")
        if (self.tls_certificate is None) != (self.tls_key is None):
            raise ValueError("tls_certificate and tls_key go together; set both or neither")
        return self


class SigningSettings(_Strict):
    """The station's signing identity and certificate numbering (docs/records.md)."""

    key: PathText = Field("signing/station-key.pem", description="PEM private key (RSA); "
                          "made on first use with mode 0600 (relative to this file)")
    certificate: PathText = Field("signing/station-cert.pem", description="PEM X.509 "
                                  "certificate of the key; self-signed one made on first use")
    counter: PathText = Field("signing/certificate-counter.json", description="persistent "
                              "certificate number sequence of this station")


class AmbientSettings(_Strict):
    """The room's conditions as stated on certificates (a measured, typical value)."""

    temperature_c: float = Field(ge=-20, le=60, description="ambient temperature, C")
    humidity_pct: float | None = Field(None, ge=0, le=100, description="relative humidity, %")


class SafeStateSettings(_Strict):
    """How long the end-of-run safe-state pass keeps trying an instrument that does not read
    back safe or cannot be reached (docs/safety.md)."""

    retry_for_s: float = Field(
        120.0, ge=0.0, le=3600.0,
        description="station seconds of retries with backoff before the instrument is "
        "reported NOT SAFE",
    )
    wall_floor_s: float = Field(
        10.0, ge=1.0, le=3600.0,
        description="the least wall time the retries get (a fast simulated clock must not cut "
        "a slow link short)",
    )


class StationSettings(_Strict):
    """Everything specific to one physical station."""

    station: StationInfo
    instruments: Instruments = Instruments()
    output_folder: PathText = Field(
        "runs", description="run folders go here (relative to this file)"
    )
    min_free_space_mb: float = Field(
        200.0, ge=0.0, le=1e7,
        description="free space (MB) the output folder must have before a run starts (a "
        "part's run writes about 16 MB; a run that fills the disk ends ERROR)",
    )
    results_db: PathText = Field(
        "runs/results.sqlite",
        description="results database: a SQLite file path (relative to this file) or a URL "
        "(sqlite:///PATH, postgresql+psycopg://USER@HOST/DB)",
    )
    procedure: PathText = Field(
        "procedures/eol-ramp.yaml", description="default procedure (relative to this file)"
    )
    sim_config: PathText | None = Field(
        None, description="simulated bench configuration used by --sim (relative to this file)"
    )
    refuse_overdue_instruments: bool = Field(
        False, description="refuse to run when an instrument's calibration is overdue"
    )
    safe_state: SafeStateSettings = Field(
        default_factory=SafeStateSettings,
        description="how long the safe-state pass retries an instrument it cannot make safe",
    )
    ui: UiSettings = Field(default_factory=UiSettings, description="browser UI settings")
    central_db: PathText | None = Field(
        None,
        description="the line's central database URL: each run is written to results_db "
        "first and pushed there by the sync (store-and-forward); none: no central database",
    )
    sync_interval_s: float = Field(
        5.0, ge=0.5, le=3600.0, description="seconds between sync attempts (backoff on outage)"
    )
    signing: SigningSettings = Field(default_factory=SigningSettings,
                                     description="run folder manifests and PDF signatures")
    ambient: AmbientSettings | None = Field(
        None, description="ambient conditions for certificates (else 'not recorded')"
    )


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
    def results_db(self) -> Path | str:
        """The results database: a Path for a SQLite file, else its URL."""
        # sqlalchemy: loaded only when a database is used
        from station.db.connect import database_url, sqlite_path

        url = database_url(self.settings.results_db, self.folder)
        return sqlite_path(url) or url

    @property
    def central_db(self) -> str | None:
        """The line's central database URL (relative SQLite paths resolved), or None."""
        # sqlalchemy: loaded only when a database is used
        from station.db.connect import database_url

        text = self.settings.central_db
        return database_url(text, self.folder) if text else None

    @property
    def procedure(self) -> Path:
        return self.resolve(self.settings.procedure)
