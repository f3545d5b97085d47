"""The population simulated parts are drawn from (reference/METHOD.md's "ADIS16130-like").

Each parameter a sim config leaves out is drawn from a generator seeded by a hash of the
part's serial number, so the same serial is always the same part, on any machine.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from drivers.sim.config import PartSpec


@dataclass(frozen=True)
class PartParams:
    """A simulated part's true parameters (the world's truth, never the station's)."""

    serial: str
    bias_dps: float
    scale: float
    bias_temp_coeff_dps_per_c: float
    bias_supply_coeff_dps_per_v: float
    scale_temp_coeff_per_c: float
    scale_supply_coeff_per_v: float
    arw_deg_per_sqrt_h: float
    bias_instability_deg_per_h: float
    rrw_deg_per_h_per_sqrt_h: float
    supply_current_a: float
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    # appended (issue 12); 0 unless the sim config gives them (never drawn)
    turn_on_bias_sigma_dps: float = 0.0
    bias_temp_coeff2_dps_per_c2: float = 0.0
    bias_temp_coeff3_dps_per_c3: float = 0.0
    scale_temp_coeff2_per_c2: float = 0.0
    scale_temp_coeff3_per_c3: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def serial_seed(serial: str, salt: str = "") -> int:
    """A stable 64-bit seed from a serial number (Python's hash() is salted per process)."""
    digest = hashlib.sha256(f"{salt}:{serial}".encode()).digest()
    return int.from_bytes(digest[:8], "big")


def _signed(rng: np.random.Generator, low: float, high: float) -> float:
    return float(rng.uniform(low, high) * rng.choice((-1.0, 1.0)))


def draw_population(serial: str) -> dict[str, float]:
    """Every population parameter for `serial` (METHOD.md's typical values)."""
    rng = np.random.default_rng(serial_seed(serial, "population"))
    return {
        "bias_dps": float(rng.normal(0.0, 2.0)),
        "scale": float(1.0 + rng.normal(0.0, 0.02)),
        "bias_temp_coeff_dps_per_c": _signed(rng, 0.005, 0.01),
        "scale_temp_coeff_per_c": _signed(rng, 100e-6, 300e-6),
        "bias_supply_coeff_dps_per_v": _signed(rng, 0.03, 0.07),
        "scale_supply_coeff_per_v": _signed(rng, 0.6e-3, 1.4e-3),
        "arw_deg_per_sqrt_h": float(np.clip(0.6 * np.exp(rng.normal(0.0, 0.35)), 0.3, 2.5)),
        "bias_instability_deg_per_h": float(rng.uniform(5.0, 25.0)),
        "rrw_deg_per_h_per_sqrt_h": float(rng.uniform(1.0, 6.0)),
        "supply_current_a": float(rng.uniform(0.020, 0.030)),
    }


_COEFF_EFFECTS = {
    "bias_temperature": "bias_temp_coeff_dps_per_c",
    "scale_temperature": "scale_temp_coeff_per_c",
    "bias_supply": "bias_supply_coeff_dps_per_v",
    "scale_supply": "scale_supply_coeff_per_v",
}


def resolve_part(spec: PartSpec) -> PartParams:
    """The part's parameters: the spec's where given, the population's otherwise.

    A coefficient effect (`bias_temperature` ...) given with its parameter overrides that
    coefficient; given empty it keeps the part's own (the coefficients always act).
    """
    drawn = draw_population(spec.serial)
    values: dict[str, Any] = {}
    for name, default in drawn.items():
        given = getattr(spec, name)
        values[name] = float(given) if given is not None else default
    for effect_id, param in _COEFF_EFFECTS.items():
        if param in spec.effects.get(effect_id, {}):
            values[param] = float(spec.effects[effect_id][param])
    effects = {k: dict(v) for k, v in spec.effects.items()}
    for name in UNDRAWN_PARAMS:
        given = getattr(spec, name)
        values[name] = float(given) if given is not None else 0.0
    return PartParams(serial=spec.serial, effects=effects, **values)


# part parameters never drawn from the population: 0 unless the sim config gives them
UNDRAWN_PARAMS = (
    "turn_on_bias_sigma_dps",
    "bias_temp_coeff2_dps_per_c2",
    "bias_temp_coeff3_dps_per_c3",
    "scale_temp_coeff2_per_c2",
    "scale_temp_coeff3_per_c3",
)
