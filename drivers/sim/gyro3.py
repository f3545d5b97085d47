"""A simulated three-axis part: gyro x, y, z with per-axis errors, and an accelerometer.

The world's truth (never the station's model), in the part frame, deg/s and m/s^2:

    raw = S(T, V) w + b(T, V) + G a + X(T, w, a) + noise,     S = M^-1 D(T, V)
    D   = diag(1 + sT_i dT + sV_i dV),           b(T, V) = b + bT dT + bV dV   (per axis)

with w the true rate, a the specific force the accelerometer measures (gravity's reaction
from the cube's orientation, drivers/sim/cube.py), dT = T_die - 25 C, dV = V - 5 V, X the
effects that couple the axes beyond that model (drivers/sim/cross_axis.py; 0 unless
configured). M is the correction matrix the station fits (scale and misalignment; with X = 0
the part's compensated output D^-1 M (raw - b - G a) with the true registers is w). Each axis
has the single-axis model's noise (white, bias instability as three Gauss-Markov terms, rate
random walk) from the part's `PartParams`, independently; the die temperature, self-heating,
power and turn-on are the single-axis `PartModel`'s (this class extends it). The
accelerometer adds white noise only. The single-axis effects catalog (k2, lag,
tilt, ...) does not apply to three-axis parts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.protocols import CalibrationRegisters3
from drivers.sim.config import PartPhysicsConfig, ThreeAxisSpec
from drivers.sim.cross_axis import cross_axis_output
from drivers.sim.gyro import GM_TAUS_S, T_REF_C, V_REF_V, PartModel, first_order_filter
from drivers.sim.population import PartParams, serial_seed

FloatArray = NDArray[np.float64]
Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]


@dataclass(frozen=True)
class ThreeAxisParams:
    """A three-axis part's true parameters (the contract's truth keys)."""

    bias_dps: Vec3
    matrix: Mat3
    g_sensitivity_dps_per_mps2: Mat3
    bias_temp_coeff_dps_per_c: Vec3
    bias_supply_coeff_dps_per_v: Vec3
    scale_temp_coeff_per_c: Vec3
    scale_supply_coeff_per_v: Vec3
    accel_noise_mps2: float
    # issue 29: the cross-axis effects (drivers/sim/cross_axis.py), 0 unless configured
    cross_temp_coeff_per_c: Mat3 = ((0.0, 0.0, 0.0),) * 3
    g2_cross_dps_per_mps2_sq: Mat3 = ((0.0, 0.0, 0.0),) * 3

    def as_truth(self) -> dict[str, Any]:
        """The truth JSON's three-axis `parameters` keys."""
        return {
            "axes": 3,
            "bias_dps": list(self.bias_dps),
            "matrix": [list(r) for r in self.matrix],
            "g_sensitivity_dps_per_mps2": [list(r) for r in self.g_sensitivity_dps_per_mps2],
            "bias_temp_coeff_dps_per_c": list(self.bias_temp_coeff_dps_per_c),
            "bias_supply_coeff_dps_per_v": list(self.bias_supply_coeff_dps_per_v),
            "scale_temp_coeff_per_c": list(self.scale_temp_coeff_per_c),
            "scale_supply_coeff_per_v": list(self.scale_supply_coeff_per_v),
            "accel_noise_mps2": self.accel_noise_mps2,
            **{name: [list(r) for r in m] for name, m in self.cross_axis().items()
               if any(v != 0 for r in m for v in r)},
        }

    def cross_axis(self) -> dict[str, Mat3]:
        """The cross-axis effects' matrices by their config (and truth) key."""
        return {"cross_temp_coeff_per_c": self.cross_temp_coeff_per_c,
                "g2_cross_dps_per_mps2_sq": self.g2_cross_dps_per_mps2_sq}

    def registers(self) -> CalibrationRegisters3:
        """The registers that make the part's compensated output the true rate."""
        return CalibrationRegisters3(
            bias_dps=self.bias_dps,
            matrix=self.matrix,
            g_sensitivity_dps_per_mps2=self.g_sensitivity_dps_per_mps2,
            bias_tc_dps_per_c=self.bias_temp_coeff_dps_per_c,
            bias_vc_dps_per_v=self.bias_supply_coeff_dps_per_v,
            scale_tc_per_c=self.scale_temp_coeff_per_c,
            scale_vc_per_v=self.scale_supply_coeff_per_v,
            t0_c=T_REF_C,
            v0_v=V_REF_V,
        )


def _vec(a: Any) -> Vec3:
    v = np.asarray(a, dtype=np.float64).reshape(3)
    return (float(v[0]), float(v[1]), float(v[2]))


def _mat(a: Any) -> Mat3:
    m = np.asarray(a, dtype=np.float64).reshape(3, 3)
    return (_vec(m[0]), _vec(m[1]), _vec(m[2]))


def _signed3(rng: np.random.Generator, low: float, high: float) -> FloatArray:
    return rng.uniform(low, high, 3) * rng.choice((-1.0, 1.0), 3)


def resolve_three_axis(serial: str, spec: ThreeAxisSpec) -> ThreeAxisParams:
    """The part's three-axis truth: the spec's values where given, else drawn (per serial
    number, deterministically) with the spec's spreads; coefficients per axis as the
    single-axis population draws them (drivers/sim/population.py)."""
    rng = np.random.default_rng(serial_seed(serial, "three-axis"))
    off = rng.normal(0.0, spec.misalignment_sigma, (3, 3))
    drawn_m = np.eye(3) + np.diag(rng.normal(0.0, spec.scale_error_sigma, 3))
    drawn_m += off - np.diag(np.diag(off))
    drawn = {
        "bias_dps": rng.normal(0.0, spec.bias_sigma_dps, 3),
        "matrix": drawn_m,
        "g_sensitivity_dps_per_mps2": rng.normal(
            0.0, spec.g_sensitivity_sigma_dps_per_mps2, (3, 3)
        ),
        "bias_temp_coeff_dps_per_c": _signed3(rng, 0.005, 0.01),
        "bias_supply_coeff_dps_per_v": _signed3(rng, 0.03, 0.07),
        "scale_temp_coeff_per_c": _signed3(rng, 100e-6, 300e-6),
        "scale_supply_coeff_per_v": _signed3(rng, 0.6e-3, 1.4e-3),
    }
    values: dict[str, Any] = {}
    for name, default in drawn.items():
        given = getattr(spec, name)
        value = default if given is None else given
        values[name] = _mat(value) if name in ("matrix", "g_sensitivity_dps_per_mps2") else _vec(
            value
        )
    for name in ("cross_temp_coeff_per_c", "g2_cross_dps_per_mps2_sq"):  # never drawn
        given = getattr(spec, name)
        values[name] = _mat(np.zeros((3, 3)) if given is None else given)
    return ThreeAxisParams(accel_noise_mps2=spec.accel_noise_mps2, **values)


class PartModel3(PartModel):
    """A three-axis part: the single-axis part's thermal and power state, three gyro axes."""

    axes = 3

    def __init__(
        self,
        params: PartParams,
        three: ThreeAxisParams,
        physics: PartPhysicsConfig,
        seed: int,
        t_s: float,
        air_c: float,
    ) -> None:
        super().__init__(params, physics, seed, t_s, air_c)
        self.three = three
        self.cal3 = CalibrationRegisters3()
        self._m_inv = np.linalg.inv(np.asarray(three.matrix))
        self._rng3 = np.random.default_rng([serial_seed(params.serial, "noise3"), seed])
        self._gm3 = self._rng3.normal(0.0, 1.0, (3, len(GM_TAUS_S))) * self._gm_sigma
        self._rrw3 = np.zeros(3)

    def _noise3(self, n: int, dt_s: float) -> FloatArray:
        """(n, 3) noise, each axis the single-axis model's terms, independent."""
        p = self.params
        k_si = p.rrw_deg_per_h_per_sqrt_h / 216000.0
        e = self._rng3.standard_normal((3, 2 + len(GM_TAUS_S), n))
        out = e[:, 0, :] * (p.arw_deg_per_sqrt_h / 60.0 / math.sqrt(dt_s))
        for axis in range(3):
            if self._gm_sigma > 0:
                for i, corr in enumerate(GM_TAUS_S):
                    a = math.exp(-dt_s / corr)
                    x = first_order_filter(e[axis, 1 + i], a, self._gm_sigma * math.sqrt(1 - a * a),
                                           float(self._gm3[axis, i]))
                    self._gm3[axis, i] = x[-1]
                    out[axis] += x
            if k_si > 0:
                walk = self._rrw3[axis] + np.cumsum(e[axis, -1]) * (k_si * math.sqrt(dt_s))
                self._rrw3[axis] = walk[-1]
                out[axis] += walk
        return np.asarray(out.T, dtype=np.float64)

    def raw_output3(
        self,
        t_s: FloatArray,
        rate_xyz_dps: FloatArray,
        accel_xyz_mps2: FloatArray,
        supply_v: float,
        dt_s: float,
    ) -> tuple[FloatArray, FloatArray]:
        """(raw gyro output (n, 3) deg/s, die temperature (n,) C) at sample times `t_s`."""
        th = self.three
        die, element, thermal_bias = self.element_temp_at(t_s)
        d_t = (element - T_REF_C)[:, None]  # the element's temperature acts
        d_v = supply_v - V_REF_V
        scale = 1.0 + np.asarray(th.scale_temp_coeff_per_c) * d_t + np.asarray(
            th.scale_supply_coeff_per_v) * d_v
        bias = (np.asarray(th.bias_dps) + np.asarray(th.bias_temp_coeff_dps_per_c) * d_t
                + np.asarray(th.bias_supply_coeff_dps_per_v) * d_v)
        if self.turn_on_bias_dps:
            bias = bias + self.turn_on_bias_dps
        if self.element is not None:  # the same thermal bias on each axis (a simplification)
            bias = bias + thermal_bias[:, None]
        raw = (rate_xyz_dps * scale) @ self._m_inv.T + bias
        raw = raw + accel_xyz_mps2 @ np.asarray(th.g_sensitivity_dps_per_mps2).T
        raw = raw + cross_axis_output(rate_xyz_dps, accel_xyz_mps2, d_t,
                                      np.asarray(th.cross_temp_coeff_per_c),
                                      np.asarray(th.g2_cross_dps_per_mps2_sq))
        return raw + self._noise3(len(t_s), dt_s), die

    def accel_output(self, specific_force_mps2: FloatArray) -> FloatArray:
        """What the accelerometer reports: the specific force plus white noise."""
        sigma = self.three.accel_noise_mps2
        if sigma <= 0:
            return specific_force_mps2
        return specific_force_mps2 + self._rng3.normal(0.0, sigma, specific_force_mps2.shape)

    def compensate3(
        self, raw_dps: FloatArray, accel_mps2: FloatArray, die_c: FloatArray, supply_v: float
    ) -> FloatArray:
        """The part's own correction with its three-axis registers (the measured accel)."""
        return self.cal3.compensate(raw_dps, accel_mps2, die_c, supply_v)

    def truth(self) -> dict[str, Any]:
        out = super().truth()
        params = dict(out["parameters"])
        for name in ("bias_dps", "scale", "bias_temp_coeff_dps_per_c",
                     "bias_supply_coeff_dps_per_v", "scale_temp_coeff_per_c",
                     "scale_supply_coeff_per_v", "effects"):
            params.pop(name, None)  # the single-axis values do not describe this part
        params.update(self.three.as_truth())
        out["parameters"] = params
        out["axes"] = 3
        out["calibration"] = _registers_truth(self.cal3)
        return out


def _registers_truth(regs: CalibrationRegisters3) -> dict[str, Any]:
    return {
        "bias_dps": list(regs.bias_dps),
        "matrix": [list(r) for r in regs.matrix],
        "g_sensitivity_dps_per_mps2": [list(r) for r in regs.g_sensitivity_dps_per_mps2],
        "bias_tc_dps_per_c": list(regs.bias_tc_dps_per_c),
        "bias_vc_dps_per_v": list(regs.bias_vc_dps_per_v),
        "scale_tc_per_c": list(regs.scale_tc_per_c),
        "scale_vc_per_v": list(regs.scale_vc_per_v),
        "t0_c": regs.t0_c,
        "v0_v": regs.v0_v,
    }
