"""A Modbus TCP servo drive's register map, declared in YAML (a "profile").

Drives such as a Kollmorgen AKD or an Oriental Motor AZ let the integrator map their
parameters to Modbus registers; a profile says where each quantity the station needs sits,
its type, scaling and word order, the status and control bits, the fault codes and the
table's limits. Built-in profiles live next to this module in `drivers/profiles/`
(`servo-default` is the station's own table controller, the map of `drivers.rate_table_map`).

Engineering value = raw register value x `scale` (deg, deg/s, deg/s^2, s). Holding registers,
0-based addresses. The driver reads the status group (status .. time) in one request, writes
the command group (mode .. move_time) in one request (registers between them are written back
as read) and reads the three identity strings in one request; so each group's span is bounded.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from common.yaml_input import ConfigError, load_yaml_model

PROFILE_DIR = Path(__file__).with_name("profiles")
DEFAULT_PROFILE = "servo-default"
MAX_READ_SPAN = 125  # Modbus: registers in one read request
MAX_WRITE_SPAN = 123  # ... and in one write-multiple request

RegType = Literal["u16", "i16", "u32", "i32"]
FaultKind = Literal["overspeed", "following_error", "encoder_loss", "estop", "other"]
COMMAND_FIELDS = ("mode", "position_command", "rate_command", "accel_limit", "move_time")
STATUS_FIELDS = ("status", "fault_code", "encoder_counts", "position", "rate", "time")
# read with the status block, in the same request, when the profile has it
WATCHDOG_FIELDS = (*STATUS_FIELDS, "heartbeat")
STRING_FIELDS = ("model", "serial", "firmware")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Register(_Strict):
    """One numeric quantity in one register (16-bit) or a pair (32-bit)."""

    address: int = Field(ge=0, le=65534, description="holding register, 0-based")
    type: RegType = Field(description="u16, i16, u32 or i32")
    scale: float = Field(1.0, description="engineering units per LSB (value = raw x scale)")

    @field_validator("scale")
    @classmethod
    def _scale(cls, v: float) -> float:
        if not (math.isfinite(v) and v != 0 and 1e-12 <= abs(v) <= 1e12):
            raise ValueError("scale must be finite, non-zero, between 1e-12 and 1e12 in size")
        return v

    @property
    def words(self) -> int:
        return 2 if self.type in ("u32", "i32") else 1

    @property
    def bits(self) -> int:
        return 16 * self.words

    @property
    def signed(self) -> bool:
        return self.type.startswith("i")


class Text(_Strict):
    """ASCII string, two characters per register, high byte first, NUL padded."""

    address: int = Field(ge=0, le=65534)
    count: int = Field(ge=1, le=32, description="registers")


class Registers(_Strict):
    control: Register = Field(description="control word (see control_bits), u16")
    mode: Register = Field(description="operating mode (see modes), u16")
    position_command: Register = Field(description="position demand, deg")
    rate_command: Register = Field(description="rate demand, deg/s")
    accel_limit: Register = Field(description="acceleration limit, deg/s^2")
    move_time: Register = Field(description="position move time, s (0: trapezoid)")
    status: Register = Field(description="status word (see status_bits), u16")
    fault_code: Register = Field(description="fault code (see faults), u16")
    encoder_counts: Register = Field(description="raw encoder counts, wrapping")
    position: Register = Field(description="position feedback since zeroing, deg")
    rate: Register = Field(description="rate feedback, deg/s")
    time: Register = Field(description="controller clock at the snapshot, s, wrapping")
    heartbeat: Register | None = Field(
        None,
        description="counter the controller advances while it runs, u16 (optional: the "
        "station's watchdog judges a hung controller by it when given)",
    )
    model: Text
    serial: Text
    firmware: Text

    @model_validator(mode="after")
    def _shapes(self) -> Registers:
        for name in ("control", "mode", "status", "fault_code"):
            if getattr(self, name).type != "u16":
                raise ValueError(f"registers.{name} must be of type u16")
        taken: dict[int, str] = {}
        for name in type(self).model_fields:
            reg = getattr(self, name)
            if reg is None:
                continue
            count = reg.count if isinstance(reg, Text) else reg.words
            for a in range(reg.address, reg.address + count):
                if a in taken:
                    raise ValueError(f"registers.{name} overlaps registers.{taken[a]} at {a}")
                taken[a] = name
        for group, limit in (
            (COMMAND_FIELDS, MAX_WRITE_SPAN), (WATCHDOG_FIELDS, MAX_READ_SPAN),
            (STRING_FIELDS, MAX_READ_SPAN),
        ):
            first, end = self.span(group)
            if end - first > limit:
                raise ValueError(
                    f"{', '.join(group)} span registers {first}..{end - 1}: the driver moves "
                    f"them in one request, which holds at most {limit} registers"
                )
        return self

    def span(self, names: tuple[str, ...]) -> tuple[int, int]:
        """First register and one past the last of the named fields."""
        regs = [r for r in (getattr(self, n) for n in names) if r is not None]
        first = min(r.address for r in regs)
        end = max(r.address + (r.count if isinstance(r, Text) else r.words) for r in regs)
        return first, end


def _distinct(values: dict[str, int], what: str) -> None:
    seen: dict[int, str] = {}
    for name, v in values.items():
        if v in seen:
            raise ValueError(f"{what} {name} and {seen[v]} are both {v}")
        seen[v] = name


class ControlBits(_Strict):
    """Bit numbers (0..15) in the control word."""

    enable: int = Field(ge=0, le=15)
    halt: int = Field(ge=0, le=15)
    fault_reset: int = Field(ge=0, le=15, description="edge: the drive clears it")
    zero_encoder: int = Field(ge=0, le=15, description="edge: the drive clears it")

    @model_validator(mode="after")
    def _unique(self) -> ControlBits:
        _distinct(self.model_dump(), "control bits")
        return self

    def mask(self, *names: str) -> int:
        return sum(1 << getattr(self, n) for n in names)


class StatusBits(_Strict):
    """Bit numbers (0..15) in the status word."""

    ready: int = Field(ge=0, le=15)
    enabled: int = Field(ge=0, le=15)
    fault: int = Field(ge=0, le=15)
    in_position: int = Field(ge=0, le=15)
    at_rate: int = Field(ge=0, le=15)
    moving: int = Field(ge=0, le=15)
    interlock_open: int = Field(ge=0, le=15)

    @model_validator(mode="after")
    def _unique(self) -> StatusBits:
        _distinct(self.model_dump(), "status bits")
        return self


class Modes(_Strict):
    """Values of the mode register."""

    idle: int = Field(ge=0, le=65535)
    position: int = Field(ge=0, le=65535)
    rate: int = Field(ge=0, le=65535)

    @model_validator(mode="after")
    def _unique(self) -> Modes:
        _distinct(self.model_dump(), "modes")
        return self


class FaultCode(_Strict):
    code: int = Field(ge=1, le=65535)
    kind: FaultKind = Field("other", description="what the fault is, for the simulated twin")
    text: str = Field(min_length=1, max_length=300, description="what it means, what to do")


class Limits(_Strict):
    max_rate_dps: float = Field(gt=0, le=100_000, description="the drive's overspeed limit")
    max_accel_dps2: float = Field(gt=0, le=1e7, description="highest acceleration limit")


class ServoProfile(_Strict):
    name: str = Field(min_length=1, max_length=80)
    description: str = ""
    word_order: Literal["high_first", "low_first"] = Field(
        "high_first", description="32-bit values: which word sits at the lower address"
    )
    counts_per_rev: int = Field(ge=1, le=1 << 40, description="encoder counts per revolution")
    limits: Limits
    registers: Registers
    control_bits: ControlBits
    status_bits: StatusBits
    modes: Modes
    faults: list[FaultCode] = Field(default_factory=list)

    @model_validator(mode="after")
    def _faults(self) -> ServoProfile:
        _distinct({str(i): f.code for i, f in enumerate(self.faults)}, "fault entries")
        return self

    def fault_text(self, code: int) -> str:
        for f in self.faults:
            if f.code == code:
                return f.text
        return f"unknown fault code {code}: see the drive's manual, then reset the fault"

    # ------------------------------------------------------------ register codec

    def decode(self, reg: Register, block: list[int], first: int, *, raw: bool = False) -> float:
        """The value of `reg` from `block` (registers from `first`); raw: unsigned, unscaled."""
        at = reg.address - first
        words = [int(w) & 0xFFFF for w in block[at : at + reg.words]]
        if reg.words == 2 and self.word_order == "low_first":
            words.reverse()
        value = words[0] if reg.words == 1 else (words[0] << 16) | words[1]
        if raw:
            return value
        if reg.signed and value >= 1 << (reg.bits - 1):
            value -= 1 << reg.bits
        per_unit = _per_unit(reg.scale)  # divide by 1000 rather than multiply by 0.001
        return value / per_unit if per_unit else value * reg.scale

    def encode(self, reg: Register, value: float) -> list[int]:
        """Registers holding `value` (engineering units); ValueError if it does not fit."""
        per_unit = _per_unit(reg.scale)
        raw = int(round(value * per_unit if per_unit else value / reg.scale))
        lo, hi = (-(1 << (reg.bits - 1)), (1 << (reg.bits - 1)) - 1) if reg.signed else (
            0, (1 << reg.bits) - 1)
        if not lo <= raw <= hi:
            raise ValueError(
                f"{value:g} does not fit register {reg.address} ({reg.type}, scale {reg.scale:g})"
            )
        raw &= (1 << reg.bits) - 1
        if reg.words == 1:
            return [raw]
        words = [raw >> 16, raw & 0xFFFF]
        return words[::-1] if self.word_order == "low_first" else words


def _per_unit(scale: float) -> int:
    """1/scale when that is a whole number (scale 0.001 -> 1000), else 0."""
    inverse = 1.0 / scale
    whole = round(inverse)
    return whole if abs(scale) < 1 and abs(inverse - whole) < 1e-9 * abs(inverse) else 0


def builtin_profiles() -> list[str]:
    return sorted(p.stem for p in PROFILE_DIR.glob("*.yaml"))


def resolve_profile_path(profile: str) -> Path:
    """A built-in profile's name or a path to a YAML file."""
    if "/" not in profile and "\\" not in profile and not profile.endswith((".yaml", ".yml")):
        path = PROFILE_DIR / f"{profile}.yaml"
        if not path.is_file():
            raise ConfigError(
                f"no built-in servo profile {profile!r}; built-in: "
                f"{', '.join(builtin_profiles())}, or give the path of a profile YAML file"
            )
        return path
    return Path(profile).expanduser()


@functools.lru_cache(maxsize=16)
def _builtin(path: Path) -> ServoProfile:
    return load_yaml_model(path, ServoProfile)[0]


def load_profile(profile: str | Path = DEFAULT_PROFILE) -> ServoProfile:
    """Load a built-in profile by name or a profile file by path (file:line errors).

    Built-in profiles are read once (they are package data); a file is read at every call.
    """
    path = profile if isinstance(profile, Path) else resolve_profile_path(profile)
    if path.parent == PROFILE_DIR:
        return _builtin(path)
    return load_yaml_model(path, ServoProfile)[0]
