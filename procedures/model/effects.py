"""The effect catalog: each physical effect a gyro may show, its parameters and units.

Output model (docs/interfaces.md, reference 25 C and 5.0 V), w the true rate in deg/s:

    y = scale * (1 + sT dT + sV dV) * w + bias + bT dT + bV dV + effects + noise

Every effect except `sensor_lag` adds terms that are linear in some coefficients once its
nonlinear parameters (time constants) are fixed: `columns()` gives the regressors and
`to_params()` / `to_coefficients()` convert between fitted coefficients and the physical
parameters. `sensor_lag` instead passes the whole deterministic output through a
first-order low-pass (see lag.py).

Linearisation used (documented in docs/discrepancy.md): terms of an effect are not
multiplied by the temperature/supply scale corrections (second-order small), and
`scale_asymmetry` enters as scale * asymmetry/2 * |w|.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from procedures.model import library
from procedures.model.effect_spec import EffectSpec
from procedures.model.trajectory import FloatArray, Trajectory

CATALOG: dict[str, EffectSpec] = {
    s.id: s
    for s in (
        EffectSpec(
            "bias_temperature",
            {"bias_temp_coeff_dps_per_c": "deg/s/C"},
            "bias changes linearly with die temperature",
            "temperature",
            first_order=True,
            regressors=("temperature",),
            formula=("bias proportional to die temperature - 25 C: "
                     "{bias_temp_coeff_dps_per_c:.4g} deg/s per C"),
        ),
        EffectSpec(
            "scale_temperature",
            {"scale_temp_coeff_per_c": "1/C"},
            "scale factor changes linearly with die temperature",
            "temperature x rate",
            first_order=True,
            regressors=("rate", "temperature"),
            formula=("scale factor proportional to die temperature - 25 C: "
                     "{scale_temp_coeff_per_c:.4g} per C"),
        ),
        EffectSpec(
            "bias_supply",
            {"bias_supply_coeff_dps_per_v": "deg/s/V"},
            "bias changes linearly with supply voltage",
            "supply",
            first_order=True,
            regressors=("supply",),
            formula=("bias proportional to supply - 5.0 V: "
                     "{bias_supply_coeff_dps_per_v:.4g} deg/s per V"),
        ),
        EffectSpec(
            "scale_supply",
            {"scale_supply_coeff_per_v": "1/V"},
            "scale factor changes linearly with supply voltage",
            "supply x rate",
            first_order=True,
            regressors=("rate", "supply"),
            formula=("scale factor proportional to supply - 5.0 V: "
                     "{scale_supply_coeff_per_v:.4g} per V"),
        ),
        EffectSpec(
            "k2_quadratic",
            {"k2_per_dps": "1/(deg/s)"},
            "second-order nonlinearity: adds k2 w^2",
            "rate",
            regressors=("rate",),
            formula="adds k2 w^2: k2 = {k2_per_dps:.4g} per deg/s",
        ),
        EffectSpec(
            "k3_cubic",
            {"k3_per_dps2": "1/(deg/s)^2"},
            "third-order nonlinearity: adds k3 w^3",
            "rate",
            regressors=("rate",),
            formula="adds k3 w^3: k3 = {k3_per_dps2:.4g} per (deg/s)^2",
        ),
        EffectSpec(
            "scale_asymmetry",
            {"asymmetry": "1"},
            "scale differs between positive and negative rates: scale*(1 + a/2 sign(w))",
            "sign of rate",
            regressors=("rate",),
            formula="scale differs by sign of rate: asymmetry {asymmetry:.4g}",
        ),
        EffectSpec(
            "g_sensitivity_tilt",
            {"g_sens_dps_per_g": "deg/s/g", "tilt_deg": "deg", "phase_deg": "deg"},
            "gravity sensitivity with the rate axis tilted: g_sens sin(tilt) cos(angle - phase)",
            "table angle",
            n_columns=2,
            regressors=("angle",),
            formula=("bias once per table turn: "
                     "g_sens {g_sens_dps_per_g:.4g} deg/s/g at tilt {tilt_deg:.3g} deg, "
                     "phase {phase_deg:.3g} deg"),
        ),
        EffectSpec(
            "sensor_lag",
            {"tau_s": "s"},
            "the output follows the rate through a first-order low-pass",
            "transitions",
            nonlinear=("tau_s",),
            n_columns=0,
            regressors=("rate",),
            formula="output lags the rate by a first-order low-pass: tau {tau_s:.4g} s",
        ),
        EffectSpec(
            "warmup_drift",
            {"amplitude_dps": "deg/s", "tau_s": "s"},
            "bias decays as amplitude exp(-t/tau) after power-on",
            "time since power-on",
            nonlinear=("tau_s",),
            regressors=("time",),
            formula=("bias decays after power-on: "
                     "{amplitude_dps:.4g} deg/s x exp(-t / {tau_s:.4g} s)"),
        ),
    )
}

FIRST_ORDER = tuple(i for i, s in CATALOG.items() if s.first_order)

# Profiling ranges (s) for the nonlinear time constants.
TAU_RANGE_S: dict[str, tuple[float, float]] = {
    "sensor_lag": (1e-5, 2.0),  # down to 10 us: a lag the data does not hold fits ~0
    "warmup_drift": (5.0, 3000.0),
}

# Tilt assumed when converting the fitted g-sensitivity amplitude (only g_sens*sin(tilt) is
# identifiable from rotation about a vertical axis).
DEFAULT_TILT_DEG = 90.0


def check_effect_id(effect_id: str) -> EffectSpec:
    """The spec of a catalog effect or of a library term (library.py, ids `lib_...`)."""
    if library.is_library_id(effect_id):
        return library.spec(effect_id)
    try:
        return CATALOG[effect_id]
    except KeyError:
        raise ValueError(
            f"unknown effect {effect_id!r}; the catalog holds: {', '.join(CATALOG)}; "
            "library terms start with 'lib_'"
        ) from None


def formula_of(effect_id: str, params: Mapping[str, float]) -> str:
    """The effect's readable formula with its parameter values."""
    spec = check_effect_id(effect_id)
    try:
        return spec.formula.format(**params)
    except (KeyError, ValueError):
        return spec.description


def columns(effect_id: str, traj: Trajectory, nonlinear: Mapping[str, float]) -> FloatArray:
    """Regressors (n, k) of an effect for fixed nonlinear parameters."""
    if library.is_library_id(effect_id):
        return library.columns(effect_id, traj)
    w = traj.ref_rate_dps
    if effect_id == "bias_temperature":
        cols = [traj.dtemp_c]
    elif effect_id == "scale_temperature":
        cols = [w * traj.dtemp_c]
    elif effect_id == "bias_supply":
        cols = [traj.dsupply_v]
    elif effect_id == "scale_supply":
        cols = [w * traj.dsupply_v]
    elif effect_id == "k2_quadratic":
        cols = [w**2]
    elif effect_id == "k3_cubic":
        cols = [w**3]
    elif effect_id == "scale_asymmetry":
        cols = [np.abs(w)]
    elif effect_id == "g_sensitivity_tilt":
        a = np.deg2rad(traj.ref_angle_deg)
        cols = [np.cos(a), np.sin(a)]
    elif effect_id == "warmup_drift":
        cols = [np.exp(-traj.time_since_power_on_s / nonlinear["tau_s"])]
    elif effect_id == "sensor_lag":
        return np.zeros((traj.n, 0))
    else:
        check_effect_id(effect_id)
        raise AssertionError(effect_id)
    return np.stack(cols, axis=1)


def to_params(
    effect_id: str,
    coefs: FloatArray,
    cov: FloatArray,
    nonlinear: Mapping[str, float],
    scale: float,
    tilt_deg: float = DEFAULT_TILT_DEG,
) -> tuple[dict[str, float], dict[str, float]]:
    """Physical parameters and their 1-sigma uncertainties from fitted coefficients."""
    if library.is_library_id(effect_id):
        return library.to_params(effect_id, coefs, cov)
    c = [float(v) for v in coefs]
    s = [math.sqrt(max(float(cov[i, i]), 0.0)) for i in range(len(c))]
    if effect_id in ("scale_temperature", "scale_supply"):
        name = next(iter(CATALOG[effect_id].params))
        return {name: c[0] / scale}, {name: s[0] / abs(scale)}
    if effect_id == "scale_asymmetry":
        return {"asymmetry": 2 * c[0] / scale}, {"asymmetry": 2 * s[0] / abs(scale)}
    if effect_id == "g_sensitivity_tilt":
        amp = math.hypot(c[0], c[1])
        phase = math.degrees(math.atan2(c[1], c[0]))
        sin_t = math.sin(math.radians(tilt_deg))
        # delta method on the amplitude and phase of (c0, c1)
        if amp > 0:
            j_amp = np.array([c[0], c[1]]) / amp
            j_ph = np.array([-c[1], c[0]]) / amp**2
            s_amp = math.sqrt(max(float(j_amp @ cov @ j_amp), 0.0))
            s_ph = math.degrees(math.sqrt(max(float(j_ph @ cov @ j_ph), 0.0)))
        else:
            s_amp, s_ph = s[0], 180.0
        return (
            {"g_sens_dps_per_g": amp / sin_t, "tilt_deg": tilt_deg, "phase_deg": phase},
            {"g_sens_dps_per_g": s_amp / sin_t, "tilt_deg": 0.0, "phase_deg": s_ph},
        )
    if effect_id == "warmup_drift":
        return (
            {"amplitude_dps": c[0], "tau_s": float(nonlinear["tau_s"])},
            {"amplitude_dps": s[0]},
        )
    if effect_id == "sensor_lag":
        return {"tau_s": float(nonlinear["tau_s"])}, {}
    name = next(iter(check_effect_id(effect_id).params))
    return {name: c[0]}, {name: s[0]}


def to_coefficients(effect_id: str, params: Mapping[str, float], scale: float) -> FloatArray:
    """Inverse of to_params: the linear coefficients that reproduce the parameters."""
    if library.is_library_id(effect_id):
        return library.to_coefficients(effect_id, params)
    spec = check_effect_id(effect_id)
    missing = [p for p in spec.params if p not in params]
    if effect_id == "g_sensitivity_tilt":
        missing = [p for p in ("g_sens_dps_per_g", "phase_deg") if p not in params]
    if missing:
        raise ValueError(f"effect {effect_id}: parameters {missing} are missing")
    if effect_id in ("scale_temperature", "scale_supply"):
        return np.array([params[next(iter(spec.params))] * scale])
    if effect_id == "scale_asymmetry":
        return np.array([params["asymmetry"] * scale / 2])
    if effect_id == "g_sensitivity_tilt":
        amp = params["g_sens_dps_per_g"] * math.sin(
            math.radians(params.get("tilt_deg", DEFAULT_TILT_DEG))
        )
        ph = math.radians(params["phase_deg"])
        return np.array([amp * math.cos(ph), amp * math.sin(ph)])
    if effect_id == "warmup_drift":
        return np.array([params["amplitude_dps"]])
    if effect_id == "sensor_lag":
        return np.zeros(0)
    return np.array([params[next(iter(spec.params))]])


def nonlinear_of(effect_id: str, params: Mapping[str, float]) -> dict[str, float]:
    spec = check_effect_id(effect_id)
    return {k: float(params[k]) for k in spec.nonlinear if k in params}
