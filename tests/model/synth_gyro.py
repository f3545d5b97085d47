"""Test-side generator of gyro runs with hidden effects.

Independent code on purpose: it shares nothing with drivers/sim (the bench) nor with
procedures/model (the model under test). It builds a realistic run — power-on, chamber
steps with the die lagging and self-heating, static windows, rate plateaus over the range in
both directions, accel-limited transitions, stop moves between two stops 90 deg apart, two
temperatures x two supplies — integrates the physics on a 5x finer grid and samples it.
Noise: white (angle random walk) plus bias instability as a sum of Gauss-Markov processes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

OVERSAMPLE = 5

# Realistic magnitudes (reference/METHOD.md): nonlinearity ~0.05 % FS, g sensitivity
# 0.015 deg/s/g on a 15 deg tilted mount, 5 ms lag (32 Hz bandwidth), 0.05 deg/s warm-up.
REALISTIC_EFFECTS: dict[str, dict[str, float]] = {
    "k2_quadratic": {"k2_per_dps": 2.0e-6},
    "k3_cubic": {"k3_per_dps2": 8.0e-9},
    "scale_asymmetry": {"asymmetry": 1.0e-3},
    "g_sensitivity_tilt": {"g_sens_dps_per_g": 0.015, "tilt_deg": 15.0, "phase_deg": 30.0},
    "sensor_lag": {"tau_s": 0.005},
    "warmup_drift": {"amplitude_dps": 0.05, "tau_s": 120.0},
}
FIRST_ORDER_REALISTIC = {
    "bias_temp_coeff_dps_per_c": 0.007,
    "scale_temp_coeff_per_c": 200e-6,
    "bias_supply_coeff_dps_per_v": 0.05,
    "scale_supply_coeff_per_v": 1.0e-3,
}
# Effects outside the catalog (generator-side names; the workflow knows none of them) with
# the base variables each depends on, in the workflow's pinned vocabulary, and a magnitude
# well above the noise of the SHORT profile with a thermal ramp.
BEYOND_CATALOG: dict[str, tuple[frozenset[str], dict[str, float]]] = {
    # bias = c dT^2
    "bias_temperature_quadratic": (frozenset({"temperature"}), {"c_dps_per_c2": 2.0e-4}),
    # bias = c d(die temperature)/dt
    "bias_temperature_rate": (frozenset({"temperature_rate"}), {"c_dps_per_c_per_s": 0.5}),
    # bias = a cos(2 angle - phase): twice per table turn
    "bias_angle_2nd": (frozenset({"angle"}), {"amplitude_dps": 0.02, "phase_deg": 40.0}),
    # scale (1 + c dT dV)
    "scale_temperature_supply": (frozenset({"rate", "temperature", "supply"}),
                                 {"c_per_c_per_v": 2.0e-4}),
    # bias = c sign(w): a bias that depends on the direction of rotation
    "bias_rate_sign": (frozenset({"rate"}), {"c_dps": 0.04}),
    # scale (1 + c dT^2)
    "scale_temperature_quadratic": (frozenset({"rate", "temperature"}), {"c_per_c2": 2.0e-6}),
    # bias +h/2 after heating, -h/2 after cooling: a play (backlash) operator of half-width
    # 1 C on the die temperature, its state (die - play) / 1 C from -1 to +1
    "bias_temperature_hysteresis": (frozenset({"temperature_direction"}),
                                    {"h_dps": 0.02, "half_width_c": 1.0}),
}

FIRST_ORDER_EFFECTS = {
    "bias_temperature": "bias_temp_coeff_dps_per_c",
    "scale_temperature": "scale_temp_coeff_per_c",
    "bias_supply": "bias_supply_coeff_dps_per_v",
    "scale_supply": "scale_supply_coeff_per_v",
}


@dataclass
class Part:
    bias_dps: float = 1.7
    scale: float = 1.021
    bias_temp_coeff_dps_per_c: float = 0.0
    scale_temp_coeff_per_c: float = 0.0
    bias_supply_coeff_dps_per_v: float = 0.0
    scale_supply_coeff_per_v: float = 0.0
    arw_deg_per_sqrt_h: float = 0.6
    bias_instability_deg_per_h: float = 10.0
    effects: dict[str, dict[str, float]] = field(default_factory=dict)

    def with_effect(self, effect_id: str, **params: float) -> Part:
        """A copy with an effect added (catalog id); first-order ids set the coefficient."""
        new = Part(**{k: v for k, v in self.__dict__.items() if k != "effects"})
        new.effects = dict(self.effects)
        if effect_id in FIRST_ORDER_EFFECTS:
            name = FIRST_ORDER_EFFECTS[effect_id]
            value = params.get(name, FIRST_ORDER_REALISTIC[name])
            setattr(new, name, value)
        elif effect_id in BEYOND_CATALOG:
            new.effects[effect_id] = {**BEYOND_CATALOG[effect_id][1], **params}
        else:
            new.effects[effect_id] = {**REALISTIC_EFFECTS[effect_id], **params}
        return new


def realistic_part() -> Part:
    return Part(**FIRST_ORDER_REALISTIC)


@dataclass
class Profile:
    rates_dps: tuple[float, ...] = (5, 10, 20, 50, 100, 150, 200, 250)
    plateau_s: float = 6.0
    static_s: float = 10.0
    stabilise_s: float = 60.0
    accel_dps2: float = 200.0
    rate_hz: float = 100.0
    temperatures_c: tuple[float, ...] = (25.0, 55.0)
    supplies_v: tuple[float, ...] = (4.75, 5.25)
    stop_wait_s: float = 5.0
    stop_move_s: float = 3.0
    # chamber ramp between temperatures (C/s; 0: a step), taken with the table at rest
    # before the stabilisation window
    thermal_ramp_c_per_s: float = 0.0


SHORT = Profile(rates_dps=(10, 50, 150, 250), plateau_s=4.0, static_s=8.0, stabilise_s=40.0,
                rate_hz=50.0)


def _rate_program(p: Profile) -> list[tuple[str, float, float, float]]:
    """(kind, duration, start rate, end rate) pieces; stop moves marked for a cosine profile."""
    prog: list[tuple[str, float, float, float]] = []
    first = True
    for i, temp in enumerate(p.temperatures_c):
        if i > 0 and p.thermal_ramp_c_per_s > 0:
            step = temp - p.temperatures_c[i - 1]
            prog.append(("ramp", abs(step) / p.thermal_ramp_c_per_s, p.temperatures_c[i - 1],
                         temp))
        for supply in p.supplies_v:
            prog.append(("stabilise", p.stabilise_s if not first else p.stabilise_s * 1.5,
                         temp, supply))
            first = False
            prog.append(("static", p.static_s, 0.0, 0.0))
            prev = 0.0
            for r in p.rates_dps:
                for target in (r, -r):
                    prog.append(("transition", abs(target - prev) / p.accel_dps2, prev, target))
                    prog.append(("plateau", p.plateau_s, target, target))
                    prev = target
            prog.append(("transition", abs(prev) / p.accel_dps2, prev, 0.0))
            prog.append(("stop_static", p.stop_wait_s, 0.0, 0.0))
            prog.append(("stop_move", p.stop_move_s, 90.0, 0.0))
            prog.append(("stop_static", p.stop_wait_s, 0.0, 0.0))
            prog.append(("stop_move", p.stop_move_s, -90.0, 0.0))
            prog.append(("stop_static", p.stop_wait_s, 0.0, 0.0))
    return prog


def _backlash(x: np.ndarray, half_width: float) -> np.ndarray:
    """Direction of x's history, -1 .. +1: x minus a backlash that trails it by half_width."""
    state = []
    values = x.tolist()
    trail = values[0]
    for v in values:
        trail = min(max(trail, v - half_width), v + half_width)
        state.append((v - trail) / half_width)
    return np.array(state)


def _gauss_markov(rng: np.random.Generator, n: int, dt: float, sigma: float, tau: float):
    a = math.exp(-dt / tau)
    e = rng.normal(0.0, sigma * math.sqrt(1 - a * a), n)
    e[0] = rng.normal(0.0, sigma)
    from scipy.signal import lfilter

    return lfilter([1.0], [1.0, -a], e)


def generate(part: Part, seed: int, profile: Profile | None = None) -> dict[str, object]:
    """A run: columns (time_s, gyro_dps, ref_rate_dps, ref_angle_deg, temp_c, supply_v) at
    the sample rate, plus `segments` [(kind, start_s, end_s)]."""
    p = profile or Profile()
    rng = np.random.default_rng(seed)
    dtf = 1.0 / (p.rate_hz * OVERSAMPLE)
    rates, chamber, supply = [], [], []
    segments: list[tuple[str, float, float]] = []
    t_now, temp_set, supply_set = 0.0, p.temperatures_c[0], p.supplies_v[0]
    for kind, dur, a, b in _rate_program(p):
        n = max(int(round(dur / dtf)), 1)
        x = (np.arange(n) + 0.5) / n
        ramp = None
        if kind == "stabilise":
            temp_set, supply_set = a, b
            w = np.zeros(n)
        elif kind == "ramp":
            ramp = a + (b - a) * x
            temp_set = b
            w = np.zeros(n)
            kind = "transition"
        elif kind == "stop_move":
            # smooth move of `a` degrees: rate = a/dur * (1 - cos(2 pi x))
            w = a / dur * (1 - np.cos(2 * np.pi * x))
        else:
            w = a + (b - a) * x
        rates.append(w)
        chamber.append(np.full(n, temp_set) if ramp is None else ramp)
        supply.append(np.full(n, supply_set))
        segments.append((kind, t_now, t_now + n * dtf))
        t_now += n * dtf
    w = np.concatenate(rates)
    n_f = w.size
    t = np.arange(n_f) * dtf
    angle = np.cumsum(w) * dtf
    chamber_c = np.concatenate(chamber)
    # die temperature: lags the chamber (40 s) plus self-heating after power-on
    from scipy.signal import lfilter

    a_die = math.exp(-dtf / 40.0)
    die = lfilter([1 - a_die], [1, -a_die], chamber_c, zi=[a_die * chamber_c[0]])[0]
    die = die + 1.5 * (1 - np.exp(-t / 90.0))
    supply_v = np.concatenate(supply) + rng.normal(0, 0.0005, n_f)
    d_t = die - 25.0
    d_v = supply_v - 5.0
    e = part.effects
    k_scale = part.scale * (
        1 + part.scale_temp_coeff_per_c * d_t + part.scale_supply_coeff_per_v * d_v
    )
    if "scale_temperature_supply" in e:
        k_scale = k_scale * (1 + e["scale_temperature_supply"]["c_per_c_per_v"] * d_t * d_v)
    if "scale_temperature_quadratic" in e:
        k_scale = k_scale * (1 + e["scale_temperature_quadratic"]["c_per_c2"] * d_t**2)
    if "scale_asymmetry" in e:
        k_scale = k_scale * (1 + e["scale_asymmetry"]["asymmetry"] / 2 * np.sign(w))
    y = k_scale * w + part.bias_dps + part.bias_temp_coeff_dps_per_c * d_t
    y = y + part.bias_supply_coeff_dps_per_v * d_v
    if "k2_quadratic" in e:
        y = y + e["k2_quadratic"]["k2_per_dps"] * w**2
    if "k3_cubic" in e:
        y = y + e["k3_cubic"]["k3_per_dps2"] * w**3
    if "g_sensitivity_tilt" in e:
        g = e["g_sensitivity_tilt"]
        y = y + g["g_sens_dps_per_g"] * math.sin(math.radians(g["tilt_deg"])) * np.cos(
            np.radians(angle - g["phase_deg"])
        )
    if "bias_temperature_quadratic" in e:
        y = y + e["bias_temperature_quadratic"]["c_dps_per_c2"] * d_t**2
    if "bias_temperature_rate" in e:
        y = y + e["bias_temperature_rate"]["c_dps_per_c_per_s"] * np.gradient(die, t)
    if "bias_angle_2nd" in e:
        h = e["bias_angle_2nd"]
        y = y + h["amplitude_dps"] * np.cos(np.radians(2 * angle - h["phase_deg"]))
    if "bias_temperature_hysteresis" in e:
        hy = e["bias_temperature_hysteresis"]
        y = y + 0.5 * hy["h_dps"] * _backlash(die, hy["half_width_c"])
    if "bias_rate_sign" in e:
        y = y + e["bias_rate_sign"]["c_dps"] * np.sign(w)
    if "warmup_drift" in e:
        y = y + e["warmup_drift"]["amplitude_dps"] * np.exp(-t / e["warmup_drift"]["tau_s"])
    if "sensor_lag" in e:
        # the continuous first-order lag, exact for input linear between grid points (a
        # one-pole y = a y + (1 - a) x would delay a ramp by dt a / (1 - a), far less than
        # tau once tau is below the grid step)
        tau = e["sensor_lag"]["tau_s"]
        a_lag = math.exp(-dtf / tau)
        g = tau / dtf * (1.0 - a_lag)
        b0, b1 = 1.0 - g, g - a_lag
        y = lfilter([b0, b1], [1, -a_lag], y, zi=[(b1 + a_lag) * y[0]])[0]
    idx = np.arange(0, n_f, OVERSAMPLE)
    dt = dtf * OVERSAMPLE
    n = idx.size
    white = rng.normal(0.0, part.arw_deg_per_sqrt_h / 60.0 / math.sqrt(dt), n)
    bi = part.bias_instability_deg_per_h / 3600.0 * 0.664
    wander = sum(
        _gauss_markov(rng, n, dt, bi * 0.75, tau) for tau in (5.0, 50.0, 500.0)
    )
    gyro = y[idx] + white + wander
    temp_meas = die[idx] + rng.normal(0, 0.02, n)
    return {
        "time_s": t[idx],
        "gyro_dps": gyro,
        "ref_rate_dps": w[idx],
        "ref_angle_deg": angle[idx] % 360.0,
        "temp_c": temp_meas,
        "supply_v": supply_v[idx],
        "segments": segments,
    }


# SHORT with the chamber ramping between the temperatures at 0.2 C/s (the die follows 40 s
# behind), so temperature-rate effects and intermediate temperatures are seen.
RAMPED = Profile(rates_dps=(10, 50, 150, 250), plateau_s=4.0, static_s=8.0, stabilise_s=40.0,
                 rate_hz=50.0, thermal_ramp_c_per_s=0.2)
# RAMPED with rate plateaus at a third temperature. At two temperatures w dT^2 is exactly
# a w + b w dT on the plateaus: only the die's settling tail in the hot condition is left to
# show a scale quadratic in temperature, and there dT moves with d(dT)/dt, the time since
# power-on and the supply order, so its look-alikes fit as well (not separable). A third
# temperature is what tells a curvature in temperature from a slope.
RAMPED3 = Profile(rates_dps=(10, 50, 150, 250), plateau_s=4.0, static_s=8.0, stabilise_s=40.0,
                  rate_hz=50.0, thermal_ramp_c_per_s=0.2, temperatures_c=(25.0, 40.0, 55.0))
# RAMPED up to the hot temperature and back down: the same temperature reached by heating
# and by cooling, so a hysteresis between them shows.
RAMPED_UPDOWN = Profile(rates_dps=(10, 50, 150, 250), plateau_s=4.0, static_s=8.0,
                        stabilise_s=40.0, rate_hz=50.0, thermal_ramp_c_per_s=0.2,
                        temperatures_c=(25.0, 55.0, 25.0))
# the profile on which each kind outside the catalog is tested and benchmarked
PROFILE_FOR_KIND: dict[str, Profile] = {
    **{kind: RAMPED for kind in BEYOND_CATALOG},
    "scale_temperature_quadratic": RAMPED3,
    "bias_temperature_hysteresis": RAMPED_UPDOWN,
}
