"""The simulated bench's configuration (config/sim/*.yaml), validated at the edge.

The pinned part keys of docs/interfaces.md (`socket`, `serial`, `bias_dps`, `scale`, the four
first-order coefficients, `arw_deg_per_sqrt_h`, `bias_instability_deg_per_h`, `effects`) are
accepted as they are; a part parameter left out is drawn from the population
(`drivers.sim.population`), deterministically per serial number. Everything else (table,
chamber, supply, fixture and part physics) has defaults close to the real bench.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from common.bounded import (
    MAX_ACCEL_DPS2,
    MAX_RATE_DPS,
    MAX_SUPPLY_V,
    ONE_DAY_S,
    TEMP_HIGH_C,
    TEMP_LOW_C,
    ShortName,
)
from common.yaml_input import ConfigError, format_validation_error, read_yaml
from drivers.rate_table_map import COUNTS_PER_REV
from drivers.sim.generic_terms import MAX_TERMS as MAX_GENERIC_TERMS
from drivers.sim.generic_terms import check_term, is_generic

# effect id -> parameter names it accepts (docs/interfaces.md's catalog)
EFFECT_PARAMS: dict[str, frozenset[str]] = {
    "k2_quadratic": frozenset({"k2_per_dps"}),
    "k3_cubic": frozenset({"k3_per_dps2"}),
    "scale_asymmetry": frozenset({"asymmetry"}),
    "bias_temperature": frozenset({"bias_temp_coeff_dps_per_c"}),
    "scale_temperature": frozenset({"scale_temp_coeff_per_c"}),
    "bias_supply": frozenset({"bias_supply_coeff_dps_per_v"}),
    "scale_supply": frozenset({"scale_supply_coeff_per_v"}),
    "g_sensitivity_tilt": frozenset({"g_sens_dps_per_g", "tilt_deg", "phase_deg"}),
    "sensor_lag": frozenset({"tau_s"}),
    "warmup_drift": frozenset({"amplitude_dps", "tau_s"}),
}
# effects whose parameters must all be given (the coefficient effects default to the part's own)
REQUIRED_EFFECT_PARAMS: dict[str, frozenset[str]] = {
    "k2_quadratic": frozenset({"k2_per_dps"}),
    "k3_cubic": frozenset({"k3_per_dps2"}),
    "scale_asymmetry": frozenset({"asymmetry"}),
    "g_sensitivity_tilt": frozenset({"g_sens_dps_per_g", "tilt_deg"}),
    "sensor_lag": frozenset({"tau_s"}),
    "warmup_drift": frozenset({"amplitude_dps", "tau_s"}),
}


MIN_SPEED = 0.01  # slower than this and a run does not visibly advance
MAX_SPEED = 10_000.0


class SimConfigError(ValueError):
    """The sim config file is missing, unreadable or has a bad value (message names it)."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


Coefficient = Annotated[float, Field(ge=-1e3, le=1e3)]
Tau = Annotated[float, Field(gt=0.0, le=ONE_DAY_S * 10)]
Temp = Annotated[float, Field(ge=TEMP_LOW_C, le=TEMP_HIGH_C)]


Vec3Spec = tuple[Coefficient, Coefficient, Coefficient]
Mat3Spec = tuple[Vec3Spec, Vec3Spec, Vec3Spec]


class ThreeAxisSpec(_Model):
    """A three-axis part's own truth (drivers/sim/gyro3.py); any value left out is drawn from
    the population with the spreads below, deterministically per serial number. Vectors are
    x, y, z; matrices rows x, y, z. The raw output is S w + b + G a with S = M^-1 D (the part
    applies the correction of docs/fixture-protocol.md section 7)."""

    bias_dps: Vec3Spec | None = None
    matrix: Mat3Spec | None = Field(
        default=None, description="M, the correction matrix (scale and misalignment)"
    )
    g_sensitivity_dps_per_mps2: Mat3Spec | None = None
    bias_temp_coeff_dps_per_c: Vec3Spec | None = None
    bias_supply_coeff_dps_per_v: Vec3Spec | None = None
    scale_temp_coeff_per_c: Vec3Spec | None = None
    scale_supply_coeff_per_v: Vec3Spec | None = None
    # population spreads (1 sigma) for the values left out
    bias_sigma_dps: float = Field(default=1.0, ge=0.0, le=100.0)
    scale_error_sigma: float = Field(default=0.01, ge=0.0, le=0.2, description="M's diagonal")
    misalignment_sigma: float = Field(
        default=0.004, ge=0.0, le=0.1, description="M's off-diagonal terms (0.4 %: 0.1-1 %)"
    )
    g_sensitivity_sigma_dps_per_mps2: float = Field(default=0.01, ge=0.0, le=1.0)
    accel_noise_mps2: float = Field(
        default=0.003, ge=0.0, le=1.0, description="accelerometer white noise per sample, 1 sigma"
    )
    # Appended (issue 29): effects that couple the axes beyond the first-order model
    # (drivers/sim/cross_axis.py), never drawn; left out they are 0 and a part behaves as before.
    cross_temp_coeff_per_c: Mat3Spec | None = Field(
        default=None,
        description="C: raw_j += C[j][k] dT w_k (k != j), a cross-coupling that drifts with "
        "temperature; the diagonal is 0 (the scale's own is scale_temp_coeff_per_c)",
    )
    g2_cross_dps_per_mps2_sq: Mat3Spec | None = Field(
        default=None,
        description="Q: raw_j += Q[j][k] a_k^2 (k != j), the g-squared sensitivity of axis j "
        "to the specific force along axis k; the diagonal is 0",
    )

    @field_validator("cross_temp_coeff_per_c", "g2_cross_dps_per_mps2_sq")
    @classmethod
    def _off_diagonal(cls, m: Mat3Spec | None) -> Mat3Spec | None:
        if m is not None and any(m[i][i] != 0 for i in range(3)):
            raise ValueError("a cross-axis matrix couples an axis to the others only: its "
                             "diagonal must be 0")
        if m is not None and any(abs(v) > 0.1 for row in m for v in row):
            raise ValueError("cross-axis coefficients must be within +-0.1")
        return m

    @field_validator("matrix")
    @classmethod
    def _usable_matrix(cls, m: Mat3Spec | None) -> Mat3Spec | None:
        if m is None:
            return m
        for i, row in enumerate(m):
            if not 0.5 < row[i] < 2.0:
                raise ValueError(f"matrix[{i}][{i}] must be between 0.5 and 2 (a scale), "
                                 f"got {row[i]!r}")
            if any(abs(v) > 0.2 for j, v in enumerate(row) if j != i):
                raise ValueError(f"matrix row {i}: misalignment terms must be within +-0.2")
        return m


class PartSpec(_Model):
    """One loaded socket's part; any parameter left as None is drawn from the population."""

    socket: int = Field(ge=1, le=64)
    serial: str = Field(min_length=1, max_length=40, pattern=r"^[\x21-\x7e]+$")
    bias_dps: float | None = Field(default=None, ge=-MAX_RATE_DPS, le=MAX_RATE_DPS)
    scale: float | None = Field(default=None, gt=0.5, lt=2.0)
    bias_temp_coeff_dps_per_c: Coefficient | None = None
    bias_supply_coeff_dps_per_v: Coefficient | None = None
    scale_temp_coeff_per_c: Coefficient | None = None
    scale_supply_coeff_per_v: Coefficient | None = None
    arw_deg_per_sqrt_h: float | None = Field(default=None, ge=0.0, le=1e4)
    bias_instability_deg_per_h: float | None = Field(default=None, ge=0.0, le=1e6)
    rrw_deg_per_h_per_sqrt_h: float | None = Field(default=None, ge=0.0, le=1e6)
    supply_current_a: float | None = Field(default=None, gt=0.0, le=0.5)
    effects: dict[str, dict[str, Annotated[float, Field(ge=-1e6, le=1e6)]]] = Field(
        default_factory=dict, max_length=len(EFFECT_PARAMS) + MAX_GENERIC_TERMS
    )
    # Appended (issue 12): not drawn from the population; left out they are 0, so every part
    # configured before keeps its behaviour. Turn-on to turn-on bias repeatability (IEEE 1431):
    # a bias offset drawn anew at each power-on, N(0, sigma); the temperature terms beyond
    # first order, about the 25 C reference (bias + b2 dT^2 + b3 dT^3, scale (1 + s2 dT^2 ...)).
    turn_on_bias_sigma_dps: float | None = Field(default=None, ge=0.0, le=100.0)
    bias_temp_coeff2_dps_per_c2: Coefficient | None = None
    bias_temp_coeff3_dps_per_c3: Coefficient | None = None
    scale_temp_coeff2_per_c2: Coefficient | None = None
    scale_temp_coeff3_per_c3: Coefficient | None = None
    # Appended (issue 18): a three-axis part (gyro x, y, z and an accelerometer) in a cube on
    # the table; without the block the part is single-axis as before. `three_axis: {}` draws
    # every three-axis value from the population.
    three_axis: ThreeAxisSpec | None = None

    @field_validator("effects")
    @classmethod
    def _known_effects(cls, effects: dict[str, dict[str, float]]) -> dict[str, dict[str, float]]:
        for effect_id, params in effects.items():
            if is_generic(effect_id):  # a generic term of an extended model (generic_terms.py)
                check_term(effect_id, params)
                continue
            if effect_id not in EFFECT_PARAMS:
                known = ", ".join(sorted(EFFECT_PARAMS))
                raise ValueError(
                    f"unknown effect id {effect_id!r}; use one of: {known}, or a generic "
                    "term lib_... (drivers/sim/generic_terms.py)"
                )
            unknown = set(params) - EFFECT_PARAMS[effect_id]
            if unknown:
                allowed = ", ".join(sorted(EFFECT_PARAMS[effect_id]))
                raise ValueError(
                    f"effect {effect_id!r} has no parameter {sorted(unknown)}; it takes: {allowed}"
                )
            missing = REQUIRED_EFFECT_PARAMS.get(effect_id, frozenset()) - set(params)
            if missing:
                raise ValueError(f"effect {effect_id!r} needs parameter(s) {sorted(missing)}")
            if effect_id in ("sensor_lag", "warmup_drift") and not 0 < params["tau_s"] <= 1e5:
                raise ValueError(f"effect {effect_id!r}: tau_s must be in (0, 100000] s")
        return effects


class BounceConfig(_Model):
    """Damped oscillation added after a position move ends (a bounce at a mechanical stop)."""

    amplitude_deg: float = Field(default=0.02, ge=0.0, le=5.0)
    frequency_hz: float = Field(default=4.0, gt=0.0, le=200.0)
    decay_s: float = Field(default=0.15, gt=0.0, le=10.0)


class TableConfig(_Model):
    model: ShortName = "SIM-RT-360"
    serial: ShortName = "RT-0001"
    firmware: ShortName = "2.4.1"
    counts_per_rev: int = Field(default=COUNTS_PER_REV, ge=COUNTS_PER_REV, le=COUNTS_PER_REV << 8)
    accel_limit_dps2: float = Field(default=100.0, gt=0.0, le=MAX_ACCEL_DPS2)
    max_accel_dps2: float = Field(default=2000.0, gt=0.0, le=MAX_ACCEL_DPS2)
    slew_rate_dps: float = Field(
        default=90.0, gt=0.0, le=MAX_RATE_DPS, description="position-mode speed limit"
    )
    ripple_dps: float = Field(default=0.004, ge=0.0, le=100.0, description="rate ripple amplitude")
    ripple_hz: float = Field(default=7.3, gt=0.0, le=1000.0)
    at_rate_settle_s: float = Field(default=0.2, ge=0.0, le=600.0)
    bounce: BounceConfig | None = None


class ChamberConfig(_Model):
    model: ShortName = "SIM-F4-CHAMBER"
    serial: ShortName = "CH-0001"
    firmware: ShortName = "1.9"
    ambient_c: float = Field(default=25.0, ge=-40.0, le=60.0)
    air_tau_s: Tau = Field(default=60.0, description="air response to the ramped setpoint")
    idle_tau_s: Tau = Field(default=900.0, description="drift to ambient when stopped")
    max_ramp_c_per_min: float = Field(default=5.0, gt=0.0, le=100.0)
    setpoint_low_c: Temp = -40.0
    setpoint_high_c: Temp = 125.0
    initial_setpoint_c: Temp = 25.0

    @model_validator(mode="after")
    def _limits(self) -> ChamberConfig:
        if not self.setpoint_low_c < self.setpoint_high_c:
            raise ValueError("setpoint_low_c must be below setpoint_high_c")
        return self


class SupplyConfig(_Model):
    """The supply's physics, and what the generic SCPI twin (`scpi`) says it is: no maker's
    product, so its *IDN? names the simulated bench (the LAN twins name their model)."""

    manufacturer: ShortName = "GYROCAL SIMULATED BENCH"
    model: ShortName = "SCPI SUPPLY TWIN"
    serial: ShortName = "PS-0001"
    firmware: ShortName = "1.2"
    max_voltage_v: float = Field(default=30.0, gt=0.0, le=MAX_SUPPLY_V)
    max_current_a: float = Field(default=3.0, gt=0.0, le=100.0)
    short_resistance_ohm: float = Field(default=0.5, gt=0.0, le=1e6)


class FixtureConfig(_Model):
    sockets: int = Field(default=1, ge=1, le=64)
    fifo_bytes: int = Field(
        default=1 << 20, ge=1024, le=1 << 28, description="outgoing FIFO per socket"
    )
    stop_angle_deg: float | None = Field(default=None, gt=10.0, lt=350.0)
    stop_angle_uncertainty_deg: float = Field(default=0.01, gt=0.0, le=10.0)
    clock_offset_s: float = Field(default=12.5, ge=0.0, le=1e6)
    encoder_input: bool = Field(
        default=True,
        description="the table's encoder output is wired to the fixture, which latches its "
        "count into every sample frame (hardware sync); false: the field is 0, the bit clear",
    )
    calibration_order: int = Field(
        default=3,
        ge=1,
        le=3,
        description="highest temperature order the part's calibration registers hold: 1 is "
        "the eight first-order registers only (CAL? lists eight; bias_tc2.. are refused)",
    )
    sockets_per_board: int = Field(
        default=8,
        ge=1,
        le=64,
        description="sockets on each fixture board: a load of 32 sockets is four boards of "
        "eight, each board its own twin with one serial port per socket",
    )


class ThermalPhysicsConfig(_Model):
    """The honest thermal physics of the parts (issue 28, drivers/sim/thermal_physics.py):
    the typical values and spreads (1 sigma) each part's draws come from. `mode: ideal` turns
    all four effects off (the part's bias and scale follow its own sensor's temperature);
    a spread of 0 gives every part the typical value, a typical value of 0 (with its spread 0)
    turns one off, so each effect can be on alone.
    The defaults are the GYR-130 product's `thermal_typical` (config/products/gyr130.yaml)."""

    mode: Literal["honest", "ideal"] = Field(
        "honest", description="honest: the four effects act; ideal: none does"
    )
    element_tau_s: float = Field(
        default=20.0, ge=0.0, le=3600.0,
        description="the sensing element's lag behind the on-chip temperature sensor, s",
    )
    element_tau_sigma_s: float = Field(default=5.0, ge=0.0, le=3600.0)
    gradient_dps_per_c_per_min: float = Field(
        default=0.0, ge=-10.0, le=10.0,
        description="typical bias per rate of die temperature change, (deg/s)/(C/min): the "
        "mean of the draws (0: the product's, which declares only the spread)",
    )
    gradient_sigma_dps_per_c_per_min: float = Field(
        default=0.004, ge=0.0, le=10.0,
        description="bias per rate of die temperature change, (deg/s)/(C/min), drawn "
        "N(typical, sigma)",
    )
    hysteresis_dps: float = Field(
        default=0.01, ge=0.0, le=10.0,
        description="bias difference between heating and cooling (+-h/2), deg/s",
    )
    hysteresis_sigma_dps: float = Field(default=0.004, ge=0.0, le=10.0)
    hysteresis_width_c: float = Field(
        default=1.0, gt=0.0, le=50.0,
        description="half-width of the play operator: a reversal of 2x this switches fully, C",
    )
    socket_air_sigma_c: float = Field(
        default=0.2, ge=0.0, le=10.0,
        description="chamber air at a fixture position minus the chamber's, drawn N(0, sigma), C",
    )
    socket_air_c: dict[int, float] = Field(
        default_factory=dict,
        description="a fixture position's air minus the chamber's, C, given instead of drawn "
        "(socket -> offset; `station discrepancy --simulate` gives a model's twin the "
        "measured die's)",
    )

    @field_validator("socket_air_c")
    @classmethod
    def _air_in_range(cls, v: dict[int, float]) -> dict[int, float]:
        for socket, offset in v.items():
            if not 1 <= socket <= 64 or not -10.0 <= offset <= 10.0:
                raise ValueError(f"socket_air_c: socket {socket} must be 1-64 and its offset "
                                 f"{offset} C within +-10 C")
        return v


class PartPhysicsConfig(_Model):
    """Thermal and electrical behaviour shared by all parts."""

    die_tau_s: Tau = Field(default=300.0, description="die lag behind chamber air")
    self_heat_c_per_w: float = Field(default=40.0, ge=0.0, le=1e4)
    self_heat_tau_s: Tau = Field(default=90.0)
    brownout_v: float = Field(default=4.0, gt=0.0, le=MAX_SUPPLY_V)
    supply_low_v: float = Field(default=4.5, gt=0.0, le=MAX_SUPPLY_V)
    temp_noise_c: float = Field(default=0.02, ge=0.0, le=10.0)
    thermal: ThermalPhysicsConfig = Field(
        default_factory=ThermalPhysicsConfig,
        description="the honest thermal physics: element lag, gradient bias, hysteresis, "
        "socket-to-socket air (mode: ideal turns them off)",
    )


# the instrument family each twin serves by default (today's instruments)
DEFAULT_FAMILIES: dict[str, str] = {
    "rate_table": "modbus-servo",
    "chamber": "watlow-f4",
    "supply": "scpi",
    "part": "fixture",
}


class InstrumentsConfig(_Model):
    """Which instrument family each twin serves (names pinned: the station picks the
    registered driver `<role>.<family>` for each)."""

    rate_table: Literal["modbus-servo", "acutrol", "none"] = Field(
        "modbus-servo",
        description="rate table twin: modbus-servo or acutrol; none: a bench without a rate "
        "table (the parts sit on fixtures turned by hand)",
    )
    chamber: Literal["watlow-f4", "watlow-f4t", "espec-p300"] = Field(
        "watlow-f4", description="chamber twin: watlow-f4, watlow-f4t or espec-p300"
    )
    supply: Literal["scpi", "keysight-e36300", "rigol-dp800"] = Field(
        "scpi", description="supply twin: scpi, keysight-e36300 or rigol-dp800"
    )
    inclinometer: Literal["none", "ascii-xy"] = Field(
        "none", description="an inclinometer on each socket's fixture: none or ascii-xy"
    )

    def families(self) -> dict[str, str]:
        """role -> family, the part role included (the fixture protocol)."""
        return {
            "rate_table": self.rate_table,
            "chamber": self.chamber,
            "supply": self.supply,
            "part": DEFAULT_FAMILIES["part"],
            **({"inclinometer": self.inclinometer} if self.inclinometer != "none" else {}),
        }


class HandConfig(_Model):
    """The simulated operator's hand at a fixture turned by hand (the article's bench): on a
    prompt the operator reacts, then turns the socket's fixture to its other stop in a
    human, jerky move (overlapping sub-movements), sometimes bouncing off the stop, and, when
    configured, sometimes flicking it fast enough to over-range the part."""

    responds: bool = Field(
        True, description="false: the operator never turns the fixture (a prompt left unseen)"
    )
    reaction_min_s: float = Field(default=0.6, ge=0.0, le=60.0)
    reaction_max_s: float = Field(default=1.5, ge=0.0, le=60.0)
    move_min_s: float = Field(default=3.0, gt=0.1, le=60.0, description="stop to stop, s")
    move_max_s: float = Field(default=4.0, gt=0.1, le=60.0)
    submoves: int = Field(
        default=3, ge=1, le=8, description="overlapping sub-movements of a move (jerkiness)"
    )
    bounce_probability: float = Field(default=0.3, ge=0.0, le=1.0)
    bounce_amplitude_deg: float = Field(default=0.4, ge=0.0, le=10.0)
    bounce_frequency_hz: float = Field(default=5.0, gt=0.0, le=100.0)
    bounce_decay_s: float = Field(default=0.08, gt=0.0, le=2.0)
    over_range_probability: float = Field(
        default=0.0, ge=0.0, le=1.0, description="share of moves flicked too fast"
    )
    over_range_move_s: float = Field(
        default=0.5, gt=0.05, le=10.0, description="duration of a flick, s"
    )

    @model_validator(mode="after")
    def _ranges(self) -> HandConfig:
        if self.reaction_min_s > self.reaction_max_s:
            raise ValueError("reaction_min_s must not exceed reaction_max_s")
        if self.move_min_s > self.move_max_s:
            raise ValueError("move_min_s must not exceed move_max_s")
        return self


class CubeConfig(_Model):
    """The cube a three-axis part sits in on the table, and the operator who turns it: on a
    prompt naming a face the operator reacts, then turns the socket's cube in a few seconds
    so that face points up (the table's axis)."""

    initial_face: Literal["+x", "-x", "+y", "-y", "+z", "-z"] = "+z"
    responds: bool = Field(True, description="false: the operator never turns the cube")
    reaction_min_s: float = Field(default=0.6, ge=0.0, le=60.0)
    reaction_max_s: float = Field(default=1.5, ge=0.0, le=60.0)
    turn_min_s: float = Field(default=2.0, gt=0.1, le=60.0, description="one reorientation, s")
    turn_max_s: float = Field(default=4.0, gt=0.1, le=60.0)
    wrong_face_probability: float = Field(
        default=0.0, ge=0.0, le=1.0, description="share of turns to a wrong face (a slip)"
    )

    @model_validator(mode="after")
    def _ranges(self) -> CubeConfig:
        if self.reaction_min_s > self.reaction_max_s:
            raise ValueError("reaction_min_s must not exceed reaction_max_s")
        if self.turn_min_s > self.turn_max_s:
            raise ValueError("turn_min_s must not exceed turn_max_s")
        return self


class SimConfig(_Model):
    speed: float = Field(
        default=1.0,
        ge=MIN_SPEED,
        le=MAX_SPEED,
        description=f"station seconds per wall second, {MIN_SPEED:g} to {MAX_SPEED:g}",
    )
    seed: int = Field(default=0, ge=0, le=2**32 - 1)
    parts: list[PartSpec] = Field(default_factory=list, max_length=64)
    table: TableConfig = Field(default_factory=TableConfig)
    chamber: ChamberConfig = Field(default_factory=ChamberConfig)
    supply: SupplyConfig = Field(default_factory=SupplyConfig)
    fixture: FixtureConfig = Field(default_factory=FixtureConfig)
    part_physics: PartPhysicsConfig = Field(default_factory=PartPhysicsConfig)
    instruments: InstrumentsConfig = Field(
        default_factory=InstrumentsConfig, description="the family each twin serves"
    )
    hand: HandConfig = Field(
        default_factory=HandConfig, description="the operator's hand at a hand-turned fixture"
    )
    cube: CubeConfig = Field(
        default_factory=CubeConfig, description="three-axis parts' cubes and their operator"
    )

    @model_validator(mode="after")
    def _sockets(self) -> SimConfig:
        seen: set[int] = set()
        for part in self.parts:
            if part.socket in seen:
                raise ValueError(f"socket {part.socket} is given two parts; one part per socket")
            seen.add(part.socket)
        return self

    @property
    def socket_count(self) -> int:
        """Sockets served: the fixture's count, grown to hold every configured part."""
        return max([self.fixture.sockets, *(p.socket for p in self.parts)])


def _format_validation(exc: ValidationError, source: str) -> str:
    lines = []
    for err in exc.errors():
        where = ".".join(str(x) for x in err["loc"]) or "(top level)"
        lines.append(f"{where}: {err['msg']}")
    return f"{source}: invalid sim config: " + "; ".join(lines) + " (fix it in the YAML file)"


def speed_problem(speed: float) -> str | None:
    """Why `speed` is not a usable bench speed factor (None if it is)."""
    if not MIN_SPEED <= speed <= MAX_SPEED:  # NaN fails too
        return (
            f"--speed must be from {MIN_SPEED:g} to {MAX_SPEED:g} (station seconds per wall "
            f"second; 1 is real time), got {speed:g}"
        )
    return None


def parse_sim_config(data: Any, source: str = "<sim config>") -> SimConfig:
    """Validate a mapping as a SimConfig; errors name the source and the field."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise SimConfigError(
            f"{source}: the sim config must be a YAML mapping, got {type(data).__name__}"
        )
    try:
        return SimConfig.model_validate(data)
    except ValidationError as exc:
        raise SimConfigError(_format_validation(exc, source)) from None


def load_sim_config(path: str | Path | None) -> SimConfig:
    """Read and validate a sim config file; None gives the defaults (one empty socket).

    Read by the product's bounded YAML reader; errors are `file:line: field ...` lines."""
    if path is None:
        return SimConfig()
    p = Path(path)
    if not p.is_file():
        raise SimConfigError(f"{p}: cannot read the sim config (no such file); check the path")
    try:
        loaded = read_yaml(p)
    except ConfigError as exc:
        raise SimConfigError(str(exc)) from None
    data = {} if loaded.data is None else loaded.data
    if not isinstance(data, dict):
        raise SimConfigError(
            f"{p}:1: the sim config must be a YAML mapping, got {type(data).__name__}"
        )
    try:
        return SimConfig.model_validate(data)
    except ValidationError as exc:
        raise SimConfigError(format_validation_error(exc, loaded, SimConfig)) from None
