"""How a part's raw output codes read in engineering units: the one conversion.

The fixture sends the part's rate and temperature codes as they come out of the part (24-bit
fields on the wire, see `drivers.fixture_protocol`); what a code means depends on the part,
so the product file states it (`codes:` in config/products/*.yaml, validated by `CodeFormat`).
The defaults are the ADIS16130's, so a product file without the section reads as before.

A code of `width_bits` bits sits right-aligned in the wire field; bits above it are ignored.
Signed codes are two's complement in `width_bits`; unsigned codes are offset binary (the code
at zero is `rate_zero_code`). Then

    rate_dps = (code - rate_zero_code) / rate_counts_per_dps
    temp_c   = (code - temp_zero_code) / temp_counts_per_c + temp_zero_c

Every conversion between codes and deg/s or C in the station, the simulated bench and the
replay driver goes through the methods below (no copies of the formula elsewhere).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

CODE_FIELD_BITS = 24  # the fixture's code fields are 24 bits wide

# the ADIS16130's codes (today's parts; the defaults of CodeFormat)
ADIS16130_RATE_ZERO_CODE = 8_388_608
ADIS16130_RATE_COUNTS_PER_DPS = 23_488.0
ADIS16130_TEMP_ZERO_CODE = 8_036_283
ADIS16130_TEMP_COUNTS_PER_C = 14_093.0

# the simulated three-axis part's accelerometer: 24-bit offset binary, +-8.5 g
ACCEL_ZERO_CODE = 8_388_608
ACCEL_COUNTS_PER_MPS2 = 100_000.0

_SCALE_MIN = 1e-3  # counts per unit: below this a code step is > 1000 deg/s (or C)
_SCALE_MAX = 1e9


def _range(width_bits: int, signed: bool) -> tuple[int, int]:
    """Smallest and largest code value (as a number, before the wire's masking)."""
    if signed:
        return -(1 << (width_bits - 1)), (1 << (width_bits - 1)) - 1
    return 0, (1 << width_bits) - 1


class CodeFormat(BaseModel):
    """The code format of one part type: widths, signedness, zero codes and scales."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    rate_width_bits: int = Field(
        CODE_FIELD_BITS, ge=8, le=CODE_FIELD_BITS, description="bits of the rate code"
    )
    rate_signed: bool = Field(False, description="rate code is two's complement (else unsigned)")
    rate_zero_code: int = Field(ADIS16130_RATE_ZERO_CODE, description="rate code at 0 deg/s")
    rate_counts_per_dps: float = Field(
        ADIS16130_RATE_COUNTS_PER_DPS,
        description="rate code counts per deg/s (negative for a part whose code falls with rate)",
    )
    temp_width_bits: int = Field(
        CODE_FIELD_BITS, ge=8, le=CODE_FIELD_BITS, description="bits of the temperature code"
    )
    temp_signed: bool = Field(False, description="temperature code is two's complement")
    temp_zero_code: int = Field(
        ADIS16130_TEMP_ZERO_CODE, description="temperature code at temp_zero_c"
    )
    temp_zero_c: float = Field(
        0.0, ge=-273.15, le=1000.0, description="temperature at which the code is temp_zero_code, C"
    )
    temp_counts_per_c: float = Field(
        ADIS16130_TEMP_COUNTS_PER_C, description="temperature code counts per C"
    )
    # three-axis parts' accelerometer codes (single-axis parts have none; unused there)
    accel_width_bits: int = Field(
        CODE_FIELD_BITS, ge=8, le=CODE_FIELD_BITS, description="bits of the accelerometer code"
    )
    accel_signed: bool = Field(False, description="accelerometer code is two's complement")
    accel_zero_code: int = Field(
        ACCEL_ZERO_CODE, description="accelerometer code at 0 m/s^2"
    )
    accel_counts_per_mps2: float = Field(
        ACCEL_COUNTS_PER_MPS2, description="accelerometer code counts per m/s^2"
    )

    @field_validator("rate_counts_per_dps", "temp_counts_per_c", "accel_counts_per_mps2")
    @classmethod
    def _scale(cls, value: float) -> float:
        if not _SCALE_MIN <= abs(value) <= _SCALE_MAX:
            raise ValueError(
                f"counts per unit must be between {_SCALE_MIN:g} and {_SCALE_MAX:g} in size "
                f"(got {value!r}); take it from the part's datasheet"
            )
        return value

    @model_validator(mode="after")
    def _zero_codes_fit(self) -> CodeFormat:
        for name, zero, width, signed in (
            ("rate_zero_code", self.rate_zero_code, self.rate_width_bits, self.rate_signed),
            ("temp_zero_code", self.temp_zero_code, self.temp_width_bits, self.temp_signed),
            ("accel_zero_code", self.accel_zero_code, self.accel_width_bits, self.accel_signed),
        ):
            low, high = _range(width, signed)
            if not low <= zero <= high:
                kind = "signed" if signed else "unsigned"
                raise ValueError(
                    f"{name} {zero} is not a {width}-bit {kind} code ({low}..{high})"
                )
        return self

    # ------------------------------------------------------------ limits

    @property
    def rate_code_range(self) -> tuple[int, int]:
        return _range(self.rate_width_bits, self.rate_signed)

    @property
    def temp_code_range(self) -> tuple[int, int]:
        return _range(self.temp_width_bits, self.temp_signed)

    def rate_span_dps(self) -> tuple[float, float]:
        """The lowest and highest rate the code can express, deg/s."""
        ends = [float(v) for v in self.rate_code_to_dps(_wire(np.array(self.rate_code_range),
                                                              self.rate_width_bits))]
        return min(ends), max(ends)

    # ------------------------------------------------------------ conversions

    def rate_code_to_dps(self, code: ArrayLike) -> NDArray[np.float64]:
        """Wire codes (as the parser gives them) to deg/s."""
        value = _value(code, self.rate_width_bits, self.rate_signed)
        return (value - self.rate_zero_code) / self.rate_counts_per_dps

    def rate_dps_to_code(self, rate_dps: ArrayLike) -> NDArray[np.int64]:
        """deg/s to wire codes, rounded and clipped at the code's rails."""
        return self._to_code(
            np.asarray(rate_dps, dtype=np.float64) * self.rate_counts_per_dps
            + self.rate_zero_code,
            self.rate_width_bits,
            self.rate_signed,
        )

    def temp_code_to_c(self, code: ArrayLike) -> NDArray[np.float64]:
        """Wire codes to degrees C."""
        value = _value(code, self.temp_width_bits, self.temp_signed)
        return (value - self.temp_zero_code) / self.temp_counts_per_c + self.temp_zero_c

    def temp_c_to_code(self, temp_c: ArrayLike) -> NDArray[np.int64]:
        """Degrees C to wire codes, rounded and clipped at the code's rails."""
        return self._to_code(
            (np.asarray(temp_c, dtype=np.float64) - self.temp_zero_c) * self.temp_counts_per_c
            + self.temp_zero_code,
            self.temp_width_bits,
            self.temp_signed,
        )

    def accel_code_to_mps2(self, code: ArrayLike) -> NDArray[np.float64]:
        """Wire accelerometer codes (any shape, e.g. (n, 3)) to m/s^2."""
        value = _value(code, self.accel_width_bits, self.accel_signed)
        return (value - self.accel_zero_code) / self.accel_counts_per_mps2

    def accel_mps2_to_code(self, accel_mps2: ArrayLike) -> NDArray[np.int64]:
        """m/s^2 to wire accelerometer codes, rounded and clipped at the code's rails."""
        return self._to_code(
            np.asarray(accel_mps2, dtype=np.float64) * self.accel_counts_per_mps2
            + self.accel_zero_code,
            self.accel_width_bits,
            self.accel_signed,
        )

    def rate_code_at_rail(self, code: ArrayLike) -> NDArray[np.bool_]:
        """Where a wire rate code is at the lowest or highest code (a clipped sample)."""
        low, high = self.rate_code_range
        value = _value(code, self.rate_width_bits, self.rate_signed)
        return (value <= low) | (value >= high)

    @staticmethod
    def _to_code(value: NDArray[np.float64], width: int, signed: bool) -> NDArray[np.int64]:
        low, high = _range(width, signed)
        code = np.clip(np.rint(value), low, high).astype(np.int64)
        return _wire(code, width)


def _value(code: ArrayLike, width: int, signed: bool) -> NDArray[np.float64]:
    """The numeric value of wire codes: masked to `width` bits, sign-extended if signed."""
    raw = np.asarray(code, dtype=np.int64)
    if width < CODE_FIELD_BITS or signed:
        raw = raw & ((1 << width) - 1)
    if signed:
        raw = raw - ((raw >> (width - 1)) << width)
    return raw.astype(np.float64)


def _wire(code: NDArray[np.int64], width: int) -> NDArray[np.int64]:
    """A code value as the wire field carries it (two's complement in `width` bits)."""
    return np.asarray(code, dtype=np.int64) & ((1 << width) - 1)


ADIS16130 = CodeFormat()

