"""The station's model of a gyro: one bias, one scale, and a set of catalog effects."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from procedures.model import effects as fx
from procedures.model.lag import lag_filter
from procedures.model.trajectory import (
    REFERENCE_SUPPLY_V,
    REFERENCE_TEMPERATURE_C,
    FloatArray,
    Trajectory,
)


@dataclass(frozen=True)
class GyroModel:
    """Structure and parameter values of a gyro model (deg/s output)."""

    name: str = "base"
    bias_dps: float = 0.0
    scale: float = 1.0
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    uncertainties: Mapping[str, float] = field(default_factory=dict)  # 1 sigma, by param path
    reference_temperature_c: float = REFERENCE_TEMPERATURE_C
    reference_supply_v: float = REFERENCE_SUPPLY_V

    def __post_init__(self) -> None:
        for effect_id in self.effects:
            fx.check_effect_id(effect_id)
        if self.reference_temperature_c != REFERENCE_TEMPERATURE_C or (
            self.reference_supply_v != REFERENCE_SUPPLY_V
        ):
            raise ValueError(
                "models must use the station reference conditions 25 C and 5.0 V "
                f"(got {self.reference_temperature_c} C, {self.reference_supply_v} V)"
            )

    @property
    def effect_ids(self) -> tuple[str, ...]:
        return tuple(self.effects)

    def with_effect(self, effect_id: str, params: Mapping[str, float]) -> GyroModel:
        new = dict(self.effects)
        new[effect_id] = dict(params)
        return replace(self, effects=new)

    def predict(self, traj: Trajectory) -> FloatArray:
        """The output (deg/s) the model predicts for the trajectory, without noise."""
        y = self.bias_dps + self.scale * traj.ref_rate_dps
        for effect_id, params in self.effects.items():
            if effect_id == "sensor_lag":
                continue
            cols = fx.columns(effect_id, traj, fx.nonlinear_of(effect_id, params))
            y = y + cols @ fx.to_coefficients(effect_id, params, self.scale)
        if "sensor_lag" in self.effects:
            y = lag_filter(y, traj.time_s, float(self.effects["sensor_lag"]["tau_s"]))
        return np.asarray(y, dtype=float)


def zero_params(effect_id: str) -> dict[str, float]:
    """Starting parameters of an effect: no effect, with mid-range time constants."""
    spec = fx.check_effect_id(effect_id)
    params = {name: 0.0 for name in spec.params}
    if effect_id == "g_sensitivity_tilt":
        params["tilt_deg"] = fx.DEFAULT_TILT_DEG
    if effect_id == "sensor_lag":
        params["tau_s"] = 0.01
    if effect_id == "warmup_drift":
        params["tau_s"] = 300.0
    return params


def base_model() -> GyroModel:
    """The article's simple model: one bias and one scale for the whole record."""
    return GyroModel(name="base")


def first_order_model() -> GyroModel:
    """The station's correction model: base plus temperature and supply terms."""
    return GyroModel(name="first_order", effects={e: zero_params(e) for e in fx.FIRST_ORDER})


BUILT_IN = {"base": base_model, "first_order": first_order_model}
