"""A simulated part in the world: its error model, noise, thermal and electrical state.

This is the world's truth and deliberately separate from procedures/model (the station's
model): the world may hold effects the station's model does not know.

    y = scale (1 + sT dT + sV dV) (1 + asym/2 sign w) w + bias + bT dT + bV dV
        + k2 w^2 + k3 w^3 + g_sens sin(tilt) cos(angle - phase) + warm-up drift
        -> first-order sensor lag (if any) -> + white noise + bias instability + rate random walk

Beyond first order in temperature (0 unless the part's parameters give them): the bias gains
b2 dT^2 + b3 dT^3 and the scale's bracket s2 dT^2 + s3 dT^3. Turn-on to turn-on repeatability
(IEEE 1431): at every power-on the bias takes a new offset drawn from N(0, sigma) with the
part's `turn_on_bias_sigma_dps`, held until the part next powers off (truth: `turn_on_bias_dps`).

Bias instability is a sum of three Gauss-Markov processes a decade apart in correlation time,
scaled so the flat part of the Allan deviation is 0.664 B (IEEE 952); rate random walk is
integrated white noise.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.protocols import CalibrationRegisters
from drivers.sim.config import PartPhysicsConfig
from drivers.sim.generic_terms import (
    DIRECTION_HALF_WIDTH_C,
    PartInputs,
    build_terms,
    lag_taus,
    total_dps,
)
from drivers.sim.population import PartParams, serial_seed
from drivers.sim.thermal_physics import ElementThermal, draw_thermal

FloatArray = NDArray[np.float64]
T_REF_C = 25.0
V_REF_V = 5.0
GM_TAUS_S = (3.0, 30.0, 300.0)
TURN_ON_HISTORY = 256  # turn-on offsets the truth keeps (the latest), for tests and benchmarks


def first_order_filter(x: FloatArray, a: float, b: float, y_prev: float) -> FloatArray:
    """y[n] = a y[n-1] + b x[n] from y[-1] = y_prev, vectorised (0 < a < 1).

    Uses y[n] = a^(n+1) (y_prev + b sum_k a^-(k+1) x[k]) in chunks short enough that
    a^-n stays finite; rounding stays at machine precision relative to |x|.
    """
    n = x.size
    out = np.empty(n)
    if n == 0:
        return out
    decay = -math.log(a) if 0 < a < 1 else 0.0
    chunk = n if decay == 0 else max(1, int(200.0 / decay))
    y = y_prev
    for start in range(0, n, chunk):
        seg = x[start : start + chunk]
        k = np.arange(1, seg.size + 1)
        if decay == 0:
            vals = y * a**k + b * np.cumsum(seg)
        else:
            grow = np.exp(decay * k)
            vals = (y + b * np.cumsum(seg * grow)) / grow
        out[start : start + seg.size] = vals
        y = float(vals[-1])
    return out


def gauss_markov_avar(tau_s: FloatArray, corr_s: float, sigma: float = 1.0) -> FloatArray:
    """Allan variance of a first-order Gauss-Markov process (variance sigma^2, time corr_s)."""
    x = tau_s / corr_s
    bracket = 1.0 - (3.0 - 4.0 * np.exp(-x) + np.exp(-2.0 * x)) / (2.0 * x)
    return 2.0 * sigma**2 * corr_s / tau_s * bracket


def _gm_sigma_for_bias_instability(bi_dps: float) -> float:
    """Common sigma of the Gauss-Markov terms whose summed ADEV peaks at 0.664 * bi."""
    tau = np.logspace(-1, 4, 400)
    avar = sum(gauss_markov_avar(tau, c) for c in GM_TAUS_S)
    return 0.664 * bi_dps / math.sqrt(float(np.max(avar)))


def _lfilter() -> Any:
    """scipy.signal.lfilter, imported on first need (only a part with a sensor lag)."""
    from scipy.signal import lfilter

    return lfilter


class PartModel:
    """One part: parameters, calibration registers, die temperature, power and noise state."""

    def __init__(
        self, params: PartParams, physics: PartPhysicsConfig, seed: int, t_s: float, air_c: float
    ) -> None:
        self.params = params
        self.physics = physics
        self.rng = np.random.default_rng([serial_seed(params.serial, "noise"), seed])
        self.cal = CalibrationRegisters()
        self.compensation = False
        self.die_c = air_c  # die temperature without self-heating (lags the air)
        self.heat_c = 0.0  # self-heating rise
        self._hist_t = [t_s, t_s]
        self._hist_die = [air_c, air_c]
        self._play_c = air_c  # play operator on the die temperature (generic term dTdir)
        # the sensing element behind the sensor (drivers/sim/thermal_physics.py); None: ideal
        draws = draw_thermal(params.serial, physics.thermal)
        self.element = None if draws.ideal else ElementThermal(draws, t_s, air_c)
        self.powered = False
        self.power_on_s: float | None = None
        self.shorted = False
        self.bi_dps = params.bias_instability_deg_per_h / 3600.0
        self._gm_sigma = _gm_sigma_for_bias_instability(self.bi_dps) if self.bi_dps > 0 else 0.0
        self._gm_state = self.rng.normal(0.0, 1.0, len(GM_TAUS_S)) * self._gm_sigma
        self._rrw_state = 0.0
        # last (input, output, sample time) of the lag
        self._lag_state: tuple[float, float, float] | None = None
        fx = params.effects
        self._k2 = fx.get("k2_quadratic", {}).get("k2_per_dps", 0.0)
        self._k3 = fx.get("k3_cubic", {}).get("k3_per_dps2", 0.0)
        self._asym = fx.get("scale_asymmetry", {}).get("asymmetry", 0.0)
        g = fx.get("g_sensitivity_tilt")
        self._g_tilt = (
            (g["g_sens_dps_per_g"] * math.sin(math.radians(g["tilt_deg"])), g.get("phase_deg", 0.0))
            if g
            else None
        )
        self._lag_tau = fx.get("sensor_lag", {}).get("tau_s")
        # scipy.signal costs seconds to import: here, when the part is made (bench start or a
        # load at START), never in the sample path. There it stopped the bench's one loop for
        # seconds the first time a lagged part streamed: at a scaled clock the whole bench
        # fell silent (every socket ERROR at the first START; issue 26 (3)).
        self._lfilter = _lfilter() if self._lag_tau is not None else None
        w = fx.get("warmup_drift")
        self._warmup = (w["amplitude_dps"], w["tau_s"]) if w else None
        self._generic = build_terms(fx)  # generic terms of an extended model (lib_...)
        # the temperatures that follow the die over each lagged rate's tau (dTdtlag<tau>s)
        self._lagged_c = dict.fromkeys(lag_taus(self._generic), self.die_temp_c())
        # turn-on offsets come from their own generator: the noise sequence stays as it was
        self._turn_on_rng = np.random.default_rng([serial_seed(params.serial, "turn-on"), seed])
        self.turn_on_bias_dps = 0.0
        self.power_on_count = 0
        self.turn_on_history_dps: deque[float] = deque(maxlen=TURN_ON_HISTORY)

    # ------------------------------------------------------------ electrical, thermal

    def conductance_s(self) -> float:
        """Load the part puts on the supply (a short is a fraction of an ohm)."""
        return self.params.supply_current_a / V_REF_V

    def step(self, t_s: float, dt_s: float, air_c: float, supply_v: float) -> None:
        """Advance thermal and power state to world time `t_s`."""
        was = self.powered
        self.powered = supply_v >= self.physics.brownout_v and not self.shorted
        if self.powered and not was:
            self.power_on_s = t_s
            self._turn_on()
            self._lagged_c = dict.fromkeys(self._lagged_c, self.die_temp_c())
        if not self.powered:
            self.power_on_s = None if supply_v < self.physics.brownout_v else self.power_on_s
        if dt_s > 0:
            k = 1.0 - math.exp(-dt_s / self.physics.die_tau_s)
            self.die_c += (air_c - self.die_c) * k
            power_w = supply_v**2 * self.conductance_s() if self.powered else 0.0
            target = self.physics.self_heat_c_per_w * power_w
            kh = 1.0 - math.exp(-dt_s / self.physics.self_heat_tau_s)
            self.heat_c += (target - self.heat_c) * kh
            self._hist_t = [self._hist_t[1], t_s]
            self._hist_die = [self._hist_die[1], self.die_temp_c()]
            half = DIRECTION_HALF_WIDTH_C
            self._play_c = min(max(self._play_c, self._hist_die[1] - half),
                               self._hist_die[1] + half)
            for tau, lagged in self._lagged_c.items():
                self._lagged_c[tau] = lagged + (self._hist_die[1] - lagged) * (
                    1.0 - math.exp(-dt_s / tau))
            if self.element is not None:
                self.element.step(t_s, self.die_temp_c())

    def _turn_on(self) -> None:
        """A new turn-on bias offset (IEEE 1431 turn-on to turn-on repeatability)."""
        self.power_on_count += 1
        sigma = self.params.turn_on_bias_sigma_dps
        if sigma > 0:
            self.turn_on_bias_dps = float(self._turn_on_rng.normal(0.0, sigma))
        self.turn_on_history_dps.append(self.turn_on_bias_dps)

    def die_temp_c(self) -> float:
        return self.die_c + self.heat_c

    def die_temp_at(self, t_s: FloatArray) -> FloatArray:
        t0, t1 = self._hist_t
        d0, d1 = self._hist_die
        if t1 <= t0:
            return np.full_like(t_s, d1)
        return d0 + (d1 - d0) * np.clip((t_s - t0) / (t1 - t0), 0.0, None)

    def element_temp_at(self, t_s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(sensor C, sensing element C, thermal bias deg/s) at sample times `t_s`: the
        element is the sensor and the bias 0 for an ideal part."""
        sensor = self.die_temp_at(t_s)
        if self.element is None:
            return sensor, sensor, np.zeros_like(sensor)
        element, bias = self.element.at(t_s, sensor)
        return sensor, element, bias

    # ------------------------------------------------------------ output

    def _noise(self, n: int, dt_s: float) -> FloatArray:
        p = self.params
        k_si = p.rrw_deg_per_h_per_sqrt_h / 216000.0
        use_gm = self._gm_sigma > 0
        rows = 1 + (len(GM_TAUS_S) if use_gm else 0) + (1 if k_si > 0 else 0)
        e = self.rng.standard_normal((rows, n))  # one draw for every noise term
        out = e[0] * (p.arw_deg_per_sqrt_h / 60.0 / math.sqrt(dt_s))
        row = 1
        if use_gm:
            gm = self._gauss_markov(e[row : row + len(GM_TAUS_S)], dt_s)
            for x in gm:  # in the order a filter at a time added them
                out += x
            row += len(GM_TAUS_S)
        if k_si > 0:
            walk = self._rrw_state + np.cumsum(e[row]) * (k_si * math.sqrt(dt_s))
            self._rrw_state = float(walk[-1])
            out += walk
        return out

    def _gauss_markov(self, e: FloatArray, dt_s: float) -> FloatArray:
        """The Gauss-Markov terms (one row per GM_TAUS_S) driven by the rows of `e`, their
        states carried on: the three filters at once when the block is short enough for one
        chunk of `first_order_filter` each (the same numbers, a third of the calls)."""
        n = e.shape[1]
        a = [math.exp(-dt_s / corr) for corr in GM_TAUS_S]
        b = [self._gm_sigma * math.sqrt(1 - ai * ai) for ai in a]
        decay = [-math.log(ai) for ai in a]
        if n == 0 or not all(d > 0 and n <= max(1, int(200.0 / d)) for d in decay):
            rows = [
                first_order_filter(e[i], a[i], b[i], float(self._gm_state[i]))
                for i in range(len(a))
            ]
            out = np.stack(rows) if n else np.empty((len(a), 0))
        else:
            grow = np.exp(np.asarray(decay)[:, None] * np.arange(1, n + 1))
            y_prev = np.asarray(self._gm_state, dtype=np.float64)[:, None]
            out = (y_prev + np.asarray(b)[:, None] * np.cumsum(e * grow, axis=1)) / grow
        if n:
            self._gm_state[:] = out[:, -1]
        return out

    def raw_output_dps(
        self,
        t_s: FloatArray,
        rate_dps: FloatArray,
        angle_deg: FloatArray,
        supply_v: float,
        dt_s: float,
    ) -> tuple[FloatArray, FloatArray]:
        """(raw output deg/s, die temperature C) at sample times `t_s` spaced `dt_s`."""
        p = self.params
        die, element, thermal_bias = self.element_temp_at(t_s)
        d_t = element - T_REF_C  # the element's temperature acts; the sensor's is reported
        d_v = supply_v - V_REF_V
        w = rate_dps
        scale = p.scale * (1.0 + p.scale_temp_coeff_per_c * d_t + p.scale_supply_coeff_per_v * d_v)
        if p.scale_temp_coeff2_per_c2 or p.scale_temp_coeff3_per_c3:
            scale = scale + p.scale * (
                p.scale_temp_coeff2_per_c2 * d_t**2 + p.scale_temp_coeff3_per_c3 * d_t**3
            )
        if self._asym:
            scale = scale * (1.0 + 0.5 * self._asym * np.sign(w))
        y = scale * w + p.bias_dps + p.bias_temp_coeff_dps_per_c * d_t
        y = y + p.bias_supply_coeff_dps_per_v * d_v
        if p.bias_temp_coeff2_dps_per_c2 or p.bias_temp_coeff3_dps_per_c3:
            y = y + p.bias_temp_coeff2_dps_per_c2 * d_t**2 + p.bias_temp_coeff3_dps_per_c3 * d_t**3
        if self.turn_on_bias_dps:
            y = y + self.turn_on_bias_dps
        if self.element is not None:
            y = y + thermal_bias
        if self._k2:
            y = y + self._k2 * w * w
        if self._k3:
            y = y + self._k3 * w**3
        if self._g_tilt is not None:
            g_term, phase = self._g_tilt
            y = y + g_term * np.cos(np.radians(angle_deg - phase))
        if self._warmup is not None and self.power_on_s is not None:
            amp, tau = self._warmup
            y = y + amp * np.exp(-np.maximum(t_s - self.power_on_s, 0.0) / tau)
        if self._generic:
            y = y + self._generic_dps(t_s, w, angle_deg, element, d_v)
        if self._lag_tau is not None:
            y = self._lag(y, t_s, dt_s, self._lag_tau)
        return y + self._noise(len(t_s), dt_s), die

    def _lag(self, x: FloatArray, t_s: FloatArray, dt_s: float, tau_s: float) -> FloatArray:
        """The sensing element's first-order lag, exact for an input that changes linearly
        between samples (first-order hold): a ramp comes out delayed by tau whatever the
        output period, as the continuous lag gives it. After a pause in sampling the lag
        starts settled on the first input."""
        alpha = math.exp(-dt_s / tau_s)
        g = tau_s / dt_s * (1.0 - alpha)
        b0, b1 = 1.0 - g, g - alpha
        state = self._lag_state
        if state is None or t_s[0] - state[2] > 1.5 * dt_s:
            state = (float(x[0]), float(x[0]), float(t_s[0]) - dt_s)
        x_prev, y_prev, _ = state
        assert self._lfilter is not None  # made with the part when it has a lag
        y, _ = self._lfilter([b0, b1], [1.0, -alpha], x, zi=[b1 * x_prev + alpha * y_prev])
        self._lag_state = (float(x[-1]), float(y[-1]), float(t_s[-1]))
        return np.asarray(y, dtype=float)

    def compensate(self, raw_dps: FloatArray, die_c: FloatArray, supply_v: float) -> FloatArray:
        """The part's own correction with its calibration registers (CalibrationRegisters)."""
        c = self.cal
        d_t = die_c - c.t0_c
        d_v = supply_v - c.v0_v
        bias = c.bias_dps + c.bias_tc_dps_per_c * d_t + c.bias_vc_dps_per_v * d_v
        scale = c.scale * (1.0 + c.scale_tc_per_c * d_t + c.scale_vc_per_v * d_v)
        if c.bias_tc2_dps_per_c2 or c.bias_tc3_dps_per_c3:
            bias = bias + c.bias_tc2_dps_per_c2 * d_t**2 + c.bias_tc3_dps_per_c3 * d_t**3
        if c.scale_tc2_per_c2 or c.scale_tc3_per_c3:
            scale = scale + c.scale * (c.scale_tc2_per_c2 * d_t**2 + c.scale_tc3_per_c3 * d_t**3)
        return (raw_dps - bias) / scale

    def truth(self) -> dict[str, Any]:
        return {
            "serial": self.params.serial,
            "parameters": self.params.as_dict(),
            "die_temp_c": self.die_temp_c(),
            "thermal": None if self.element is None else self.element.truth(),
            "self_heating_c": self.heat_c,
            "powered": self.powered,
            "power_on_s": self.power_on_s,
            "shorted": self.shorted,
            "compensation": self.compensation,
            "calibration": asdict(self.cal),
            "turn_on_bias_dps": self.turn_on_bias_dps,
            "power_on_count": self.power_on_count,
            "turn_on_history_dps": list(self.turn_on_history_dps),
        }

    def _generic_dps(
        self, t_s: FloatArray, w: FloatArray, angle_deg: FloatArray, die: FloatArray, d_v: float
    ) -> FloatArray:
        """The part's generic terms (drivers/sim/generic_terms.py) at these samples."""
        (t0, t1), (d0, d1) = self._hist_t, self._hist_die
        since = t_s - self.power_on_s if self.power_on_s is not None else np.zeros_like(t_s)
        inputs = PartInputs(
            rate_dps=np.asarray(w, dtype=float) * np.ones_like(t_s),
            angle_deg=np.asarray(angle_deg, dtype=float) * np.ones_like(t_s),
            dtemp_c=die - T_REF_C,
            temp_rate_c_per_s=(d1 - d0) / (t1 - t0) if t1 > t0 else 0.0,
            dsupply_v=d_v,
            since_power_on_s=since,
            temp_direction=(d1 - self._play_c) / DIRECTION_HALF_WIDTH_C,
            lagged_rates={tau: (d1 - c) / tau for tau, c in self._lagged_c.items()},
        )
        return total_dps(self._generic, inputs)
