"""The honest thermal physics of a simulated part (issue 28): what lies between the
temperature a part's own sensor reports and the temperature its sensing element is at.

Four effects, each drawn per part (per fixture position for the air) from the spreads of
`ThermalPhysicsConfig` (config/sim/*.yaml `part_physics.thermal`), deterministically per
serial number and seed, and listed in the bench's truth (docs/simulated-bench.md):

- the sensing element lags the on-chip temperature sensor, first order with time constant
  `element_tau_s`: the part's bias and scale follow the ELEMENT's temperature, the part
  reports its SENSOR's;
- a bias in proportion to the die's rate of temperature change (the gradient across the die
  drives heat through it), `gradient_dps_per_c_per_min` times the element's rate in C/min;
- bias hysteresis between heating and cooling: +-h/2 by the direction of the last
  significant change, switched smoothly by a play (backlash) operator of half-width
  `hysteresis_width_c` on the element's temperature;
- chamber air that differs from socket to socket by `socket_air_offset_c`.

The sensor's temperature is piecewise linear in time between the world's steps (the part's
`die_temp_at`), so the element's first-order response is exact in closed form at any sample
times: e(t) = d(t) - r tau + (e0 - d0 + r tau) exp(-(t - t0) / tau). The play operator
advances at the world's steps and is interpolated linearly between them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.sim.config import ThermalPhysicsConfig
from drivers.sim.population import serial_seed

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ThermalDraws:
    """One part's honest thermal parameters (all 0: the ideal part of before issue 28)."""

    element_tau_s: float = 0.0
    gradient_dps_per_c_per_min: float = 0.0
    hysteresis_dps: float = 0.0
    hysteresis_width_c: float = 1.0

    @property
    def ideal(self) -> bool:
        return not (self.element_tau_s or self.gradient_dps_per_c_per_min or self.hysteresis_dps)


def draw_thermal(serial: str, cfg: ThermalPhysicsConfig) -> ThermalDraws:
    """The part's draws: its own generator (salt "thermal"), so no other draw moves."""
    if cfg.mode == "ideal":
        return ThermalDraws()
    rng = np.random.default_rng(serial_seed(serial, "thermal"))
    e = rng.standard_normal(3)
    return ThermalDraws(
        element_tau_s=max(0.0, cfg.element_tau_s + cfg.element_tau_sigma_s * float(e[0])),
        gradient_dps_per_c_per_min=cfg.gradient_dps_per_c_per_min
        + cfg.gradient_sigma_dps_per_c_per_min * float(e[1]),
        hysteresis_dps=max(0.0, cfg.hysteresis_dps + cfg.hysteresis_sigma_dps * float(e[2])),
        hysteresis_width_c=cfg.hysteresis_width_c,
    )


def socket_air_offset_c(seed: int, socket: int, cfg: ThermalPhysicsConfig) -> float:
    """The chamber air at fixture position `socket` minus the chamber's air, C (given in
    `socket_air_c`, else drawn)."""
    if socket in cfg.socket_air_c:
        return float(cfg.socket_air_c[socket])
    if cfg.mode == "ideal" or cfg.socket_air_sigma_c == 0:
        return 0.0
    rng = np.random.default_rng([serial_seed(f"socket-{socket}", "air"), seed])
    return float(cfg.socket_air_sigma_c * rng.standard_normal())


class ElementThermal:
    """The sensing element's temperature and the hysteresis state, following the sensor's
    piecewise-linear temperature; the two ends of the latest world step are kept."""

    def __init__(self, draws: ThermalDraws, t_s: float, sensor_c: float) -> None:
        self.draws = draws
        self._t = (t_s, t_s)
        self._sensor = (sensor_c, sensor_c)
        self._element = (sensor_c, sensor_c)
        self._state = (0.0, 0.0)  # hysteresis state in [-1, 1]: +1 heating, -1 cooling
        self._play_c = sensor_c

    def _slope(self) -> float:
        (t0, t1), (d0, d1) = self._t, self._sensor
        return (d1 - d0) / (t1 - t0) if t1 > t0 else 0.0

    def _element_at(self, t_s: float) -> float:
        """The element's temperature at `t_s` from the start of the latest step."""
        tau = self.draws.element_tau_s
        t0, d0, e0, r = self._t[0], self._sensor[0], self._element[0], self._slope()
        dt = max(t_s - t0, 0.0)
        if tau <= 0:
            return d0 + r * dt
        return d0 + r * dt - r * tau + (e0 - d0 + r * tau) * math.exp(-dt / tau)

    def step(self, t_s: float, sensor_c: float) -> None:
        """The world stepped to `t_s` where the sensor reads `sensor_c` (no noise)."""
        if t_s <= self._t[1]:
            return
        self._t, self._sensor = (self._t[1], t_s), (self._sensor[1], sensor_c)
        self._element = (self._element[1], self._element[1])  # base of the new step
        e1 = self._element_at(t_s)
        self._element = (self._element[0], e1)
        w = self.draws.hysteresis_width_c
        self._play_c = min(max(self._play_c, e1 - w), e1 + w)
        self._state = (self._state[1], (e1 - self._play_c) / w)

    def at(self, t_s: FloatArray, sensor: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(element temperature C, thermal bias deg/s) at sample times `t_s`, where the
        sensor reads `sensor` (the part's `die_temp_at(t_s)`, linear over the step). With
        E = exp(-(t - t0) / tau): element = sensor - r tau + c E, c = e0 - d0 + r tau, and
        its rate (sensor - element) / tau = r - c E / tau: one exponential per sample."""
        dr = self.draws
        tau, r = dr.element_tau_s, self._slope()
        t0 = self._t[0]
        if tau > 0:
            c = self._element[0] - self._sensor[0] + r * tau
            decay = np.exp(np.minimum(t0 - t_s, 0.0) / tau)
            element = sensor + (c * decay - r * tau)
            bias = (60.0 * dr.gradient_dps_per_c_per_min) * (r - (c / tau) * decay)
        else:
            element = sensor
            bias = np.full_like(sensor, 60.0 * dr.gradient_dps_per_c_per_min * r)
        if dr.hysteresis_dps:
            (_, t1), (s0, s1) = self._t, self._state
            half = 0.5 * dr.hysteresis_dps
            if t1 > t0 and s1 != s0:  # linear between the step's ends, held beyond them
                bias = bias + np.interp(t_s, (t0, t1), (half * s0, half * s1))
            else:
                bias = bias + half * s1
        return element, bias

    def truth(self) -> dict[str, Any]:
        return {
            **asdict(self.draws),
            "element_temp_c": self._element[1],
            "hysteresis_state": self._state[1],
            "hysteresis_play_c": self._play_c,
        }


