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

`scale` is required; an effect's parameters left out start at zero (time constants and the
tilt at their defaults, gyro_model.zero_params). A mistake is a ConfigError (a ValueError)
of one line per problem, `file:line: field a.b: what is wrong; what is allowed`, the same
form as the station's other YAML files (procedures/loading/config.py).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, ValidationError

from common.bounded import MAX_RATE_DPS, Name, ShortName
from common.yaml_input import ConfigError, LoadedYaml, format_validation_error, read_yaml
from procedures.model import effects as fx
from procedures.model.effects import CATALOG
from procedures.model.gyro_model import BUILT_IN, GyroModel, zero_params
from procedures.model.trajectory import REFERENCE_SUPPLY_V, REFERENCE_TEMPERATURE_C

Sigma = Annotated[float, Field(ge=0.0)]  # .inf allowed: a fit that could not bound it
ParamValue = Annotated[FiniteFloat, Field(ge=-1e9, le=1e9)]
MAX_SCALE = 100.0  # |output per deg/s|; a datasheet part is near 1
MAX_UNCERTAINTIES = 200

# Allowed values of parameters whose physics or conversion has limits (all others: any
# finite number), as (low, high, inclusive); time constants only where the workflow
# profiles them (effects.TAU_RANGE_S).
PARAM_LIMITS: dict[tuple[str, str], tuple[float, float, bool]] = {
    **{(e, "tau_s"): (lo, hi, True) for e, (lo, hi) in fx.TAU_RANGE_S.items()},
    ("g_sensitivity_tilt", "tilt_deg"): (0.0, 180.0, False),  # g_sens is divided by sin(tilt)
    ("scale_asymmetry", "asymmetry"): (-2.0, 2.0, False),  # the scale must not change sign
}


def param_problem(effect_id: str, name: str, value: float) -> str | None:
    """Why `value` is not allowed for parameter `name` of a catalog effect (with the allowed
    range and units), or None if it is allowed."""
    units = fx.check_effect_id(effect_id).params[name]
    if not math.isfinite(value):
        return f"{value} is not allowed; give a finite number ({units})"
    limits = PARAM_LIMITS.get((effect_id, name))
    if limits is None:
        return None
    lo, hi, inclusive = limits
    if inclusive:  # a profiled value may sit on a bound within rounding
        ok = lo * (1 - 1e-9) <= value <= hi * (1 + 1e-9)
        allowed = f"from {lo:g} to {hi:g} {units}"
    else:
        ok = lo < value < hi
        allowed = f"above {lo:g} and below {hi:g} {units}"
    return None if ok else f"{value:g} is out of range; allowed {allowed}"


class ModelFile(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: Name = Field("custom", description="a name for the model")
    reference_temperature_c: FiniteFloat = Field(
        REFERENCE_TEMPERATURE_C, description=f"must be {REFERENCE_TEMPERATURE_C:g} C"
    )
    reference_supply_v: FiniteFloat = Field(
        REFERENCE_SUPPLY_V, description=f"must be {REFERENCE_SUPPLY_V:g} V"
    )
    bias_dps: FiniteFloat = Field(
        0.0, ge=-MAX_RATE_DPS, le=MAX_RATE_DPS, description="bias at 25 C and 5.0 V, deg/s"
    )
    scale: FiniteFloat = Field(
        ge=-MAX_SCALE,
        le=MAX_SCALE,
        description="output per deg/s of rate at 25 C and 5.0 V, a nonzero number near 1"
    )
    effects: dict[ShortName, dict[ShortName, ParamValue]] = Field(
        default_factory=dict,
        max_length=len(CATALOG),
        description="catalog effect -> {parameter: finite number}",
    )
    uncertainties: dict[ShortName, Sigma] = Field(
        default_factory=dict,
        max_length=MAX_UNCERTAINTIES, description="optional 1 sigma by parameter path"
    )


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


def _where(loaded: LoadedYaml, loc: tuple[str, ...]) -> str:
    """`file:line` of the field at `loc` (or of its nearest parent in the file)."""
    for n in range(len(loc), -1, -1):
        line = loaded.lines.get(loc[:n])
        if line is not None:
            return f"{loaded.path}:{line}"
    return str(loaded.path)


def _line_of(message: str, loaded: LoadedYaml) -> int:
    """The line a `file:line: ...` message names (0 without one), to list problems in file
    order."""
    head = message[len(str(loaded.path)) :].split(":", 2)
    return int(head[1]) if len(head) > 2 and head[1].isdigit() else 0


def _value_problems(data: dict[str, Any], loaded: LoadedYaml) -> list[str]:
    """Checks pydantic's types do not express: the catalog's effects and parameters, their
    allowed ranges, a nonzero scale, the reference conditions. Runs on the raw mapping so
    they are reported beside any type error; values of the wrong type are left to pydantic."""
    out: list[str] = []

    def bad(loc: tuple[str, ...], msg: str) -> None:
        out.append(f"{_where(loaded, loc)}: field {'.'.join(loc)}: {msg}")

    def number(v: object) -> float | None:
        """The finite number pydantic will read from `v`; None if it reports `v` itself."""
        if isinstance(v, bool) or not isinstance(v, int | float | str):
            return None
        try:
            f = float(v)
        except ValueError:
            return None
        return f if math.isfinite(f) else None

    if number(data.get("scale")) == 0:
        bad(("scale",), "0 is not allowed; give the output per deg/s of rate (nonzero, near 1)")
    for key, ref in (
        ("reference_temperature_c", REFERENCE_TEMPERATURE_C),
        ("reference_supply_v", REFERENCE_SUPPLY_V),
    ):
        v = number(data.get(key))
        if v is not None and v != ref:
            bad((key,), f"{v} is not allowed; models use the station reference {ref:g}")
    effects = data.get("effects")
    if isinstance(effects, dict):
        for effect_id, params in effects.items():
            e = str(effect_id)
            spec = _spec_or_none(e)
            if spec is None:
                bad(("effects", e), f"unknown effect {e!r}; known effects: {', '.join(CATALOG)}"
                    " or a library term lib_... (docs/discrepancy.md)")
                continue
            if not isinstance(params, dict):
                continue
            for name, value in params.items():
                p = str(name)
                if p not in spec.params:
                    bad(("effects", e, p), f"unknown parameter {p!r}; effect {e} takes "
                        f"{', '.join(spec.params)}")
                elif (v := number(value)) is not None and (
                    problem := param_problem(e, p, v)
                ):
                    bad(("effects", e, p), problem)
    uncertainties = data.get("uncertainties")
    if isinstance(uncertainties, dict):
        known = {"bias_dps", "scale"} | {f"{e}.{p}" for e, s in CATALOG.items() for p in s.params}
        for key in uncertainties:
            e, _, p = str(key).partition(".")
            lib = _spec_or_none(e) if e.startswith("lib_") else None
            if str(key) not in known and not (lib is not None and p in lib.params):
                bad(("uncertainties", str(key)), "unknown parameter path; give bias_dps, "
                    "scale or EFFECT.PARAMETER of a catalog effect (e.g. k2_quadratic.k2_per_dps)")
    return out


def _spec_or_none(effect_id: str) -> fx.EffectSpec | None:
    """A catalog effect's or library term's spec (library ids spell their definition)."""
    try:
        return fx.check_effect_id(effect_id)
    except ValueError:
        return None


def model_from_loaded(loaded: LoadedYaml) -> GyroModel:
    """Validate a loaded model YAML; ConfigError naming file, line and field on any problem."""
    data = loaded.data
    if not isinstance(data, dict):
        raise ConfigError(
            f"{loaded.path}:1: expected a mapping of model fields at the top level (allowed: "
            f"{', '.join(ModelFile.model_fields)})"
        )
    problems: list[str] = []
    mf: ModelFile | None = None
    try:
        mf = ModelFile.model_validate(data)
    except ValidationError as exc:
        problems.extend(format_validation_error(exc, loaded, ModelFile).splitlines())
    problems.extend(_value_problems(data, loaded))
    if problems or mf is None:
        raise ConfigError("\n".join(sorted(problems, key=lambda m: _line_of(m, loaded))))
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
    except ValueError as exc:  # checked above; kept so nothing leaves without the file
        raise ConfigError(f"{loaded.path}: {exc}") from exc


def model_from_dict(data: object, origin: str = "model") -> GyroModel:
    """A model from an already parsed mapping (no line numbers); errors name `origin`."""
    return model_from_loaded(LoadedYaml(path=Path(origin), data=data, lines={}, sha256=""))


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
    return model_from_loaded(read_yaml(path))
