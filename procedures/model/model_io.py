"""Gyro models as YAML files, validated with pydantic at the edge.

    name: first_order+k2_quadratic
    reference_temperature_c: 25.0
    reference_supply_v: 5.0
    bias_dps: 8.6
    scale: 1.0567
    effects:
      bias_temperature: {bias_temp_coeff_dps_per_c: 0.007}
      k2_quadratic: {k2_per_dps: 2.0e-6}
    uncertainties: {bias_dps: 0.001, k2_quadratic.k2_per_dps: 1.0e-8}   # optional, 1 sigma
"""

from __future__ import annotations

from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from procedures.model.effects import CATALOG
from procedures.model.gyro_model import BUILT_IN, GyroModel, zero_params


class ModelFile(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str = "custom"
    reference_temperature_c: float = 25.0
    reference_supply_v: float = 5.0
    bias_dps: float = 0.0
    scale: float = 1.0
    effects: dict[str, dict[str, float]] = Field(default_factory=dict)
    uncertainties: dict[str, float] = Field(default_factory=dict)


def model_to_dict(model: GyroModel) -> dict[str, object]:
    return {
        "name": model.name,
        "reference_temperature_c": model.reference_temperature_c,
        "reference_supply_v": model.reference_supply_v,
        "bias_dps": float(model.bias_dps),
        "scale": float(model.scale),
        "effects": {k: {p: float(v) for p, v in ps.items()} for k, ps in model.effects.items()},
        "uncertainties": {k: float(v) for k, v in model.uncertainties.items()},
    }


def save_model(model: GyroModel, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(model_to_dict(model), sort_keys=False), encoding="utf-8")
    return path


def model_from_dict(data: object, origin: str = "model") -> GyroModel:
    try:
        mf = ModelFile.model_validate(data)
    except ValidationError as exc:
        raise ValueError(f"{origin}: not a valid gyro model: {exc}") from exc
    for effect_id, params in mf.effects.items():
        if effect_id not in CATALOG:
            raise ValueError(
                f"{origin}: unknown effect {effect_id!r}; known effects: {', '.join(CATALOG)}"
            )
        unknown = set(params) - set(CATALOG[effect_id].params)
        if unknown:
            raise ValueError(
                f"{origin}: effect {effect_id} has unknown parameters {sorted(unknown)}; "
                f"it takes {list(CATALOG[effect_id].params)}"
            )
    effects = {e: {**zero_params(e), **p} for e, p in mf.effects.items()}
    try:
        return GyroModel(
            name=mf.name,
            bias_dps=mf.bias_dps,
            scale=mf.scale,
            effects=effects,
            uncertainties=mf.uncertainties,
            reference_temperature_c=mf.reference_temperature_c,
            reference_supply_v=mf.reference_supply_v,
        )
    except ValueError as exc:
        raise ValueError(f"{origin}: {exc}") from exc


def load_model(spec: str | Path) -> GyroModel:
    """A built-in model by name (`base`, `first_order`) or a model YAML file."""
    if isinstance(spec, str) and spec in BUILT_IN:
        return BUILT_IN[spec]()
    path = Path(spec)
    if not path.exists():
        raise ValueError(
            f"model {str(spec)!r} is neither a built-in model ({', '.join(BUILT_IN)}) "
            "nor an existing YAML file"
        )
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML ({exc})") from exc
    return model_from_dict(data, origin=str(path))
