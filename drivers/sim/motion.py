"""Analytic motion profiles of the rate table's axis.

Python cannot step a 1 kHz servo loop at 100x real time, so a commanded motion is planned
once as piecewise polynomials of time (acceleration-limited ramps, trapezoids, smooth
minimum-jerk moves) plus an optional damped bounce, and evaluated at any time, vectorised.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.sim.config import BounceConfig

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Piece:
    """Position p(t) = sum(c[k] * (t - t0)^k) for t0 <= t < t1."""

    t0_s: float
    t1_s: float
    coeffs: tuple[float, ...]

    def position_deg(self, t_s: FloatArray) -> FloatArray:
        tau = t_s - self.t0_s
        out = np.zeros_like(tau)
        for c in reversed(self.coeffs):
            out = out * tau + c
        return out

    def velocity_dps(self, t_s: FloatArray) -> FloatArray:
        tau = t_s - self.t0_s
        out = np.zeros_like(tau)
        for k in range(len(self.coeffs) - 1, 0, -1):
            out = out * tau + k * self.coeffs[k]
        return out


@dataclass(frozen=True)
class Bounce:
    """x(t) = A exp(-(t - t0)/decay) sin(2 pi f (t - t0)) for t >= t0."""

    t0_s: float
    amplitude_deg: float
    frequency_hz: float
    decay_s: float

    def position_deg(self, t_s: FloatArray) -> FloatArray:
        tau = np.maximum(t_s - self.t0_s, 0.0)
        w = 2 * math.pi * self.frequency_hz
        return self.amplitude_deg * np.exp(-tau / self.decay_s) * np.sin(w * tau)

    def velocity_dps(self, t_s: FloatArray) -> FloatArray:
        tau = np.maximum(t_s - self.t0_s, 0.0)
        w = 2 * math.pi * self.frequency_hz
        env = self.amplitude_deg * np.exp(-tau / self.decay_s)
        v = env * (w * np.cos(w * tau) - np.sin(w * tau) / self.decay_s)
        return np.where(t_s >= self.t0_s, v, 0.0)

    def settled_at_s(self, tolerance_deg: float) -> float:
        """World time after which the bounce stays within `tolerance_deg`."""
        if self.amplitude_deg <= tolerance_deg:
            return self.t0_s
        return self.t0_s + self.decay_s * math.log(self.amplitude_deg / tolerance_deg)


@dataclass(frozen=True)
class Profile:
    """A planned motion: pieces in time order, the last one running forever."""

    pieces: tuple[Piece, ...]
    motion_end_s: float  # after this, velocity is constant (zero or the commanded rate)
    bounce: Bounce | None = None

    @cached_property
    def _starts(self) -> FloatArray:
        """Each piece's start time (looked up on every evaluation: made once)."""
        return np.array([p.t0_s for p in self.pieces])

    def _index(self, t: FloatArray) -> NDArray[np.intp]:
        starts = self._starts
        return np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.pieces) - 1)

    def _eval(self, t_s: ArrayLike, velocity: bool) -> FloatArray:
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        return self._eval_pieces(t, velocity, self._piece_index(t))

    def _piece_index(self, t: FloatArray) -> NDArray[np.intp] | int:
        """The piece of every time in `t`, or one piece's index for all of them (the usual
        case: the whole batch inside one piece, t sorted)."""
        if len(self.pieces) == 1:
            return 0
        idx = self._index(t[[0, -1]]) if t.size else np.zeros(2, dtype=np.intp)
        return int(idx[0]) if idx[0] == idx[1] else self._index(t)

    def _eval_pieces(
        self, t: FloatArray, velocity: bool, idx: NDArray[np.intp] | int
    ) -> FloatArray:
        if isinstance(idx, int):
            piece = self.pieces[idx]
            out = piece.velocity_dps(t) if velocity else piece.position_deg(t)
        else:
            out = np.empty_like(t)
            for i in np.unique(idx):
                sel = idx == i
                piece = self.pieces[int(i)]
                out[sel] = piece.velocity_dps(t[sel]) if velocity else piece.position_deg(t[sel])
        if self.bounce is not None:
            out += self.bounce.velocity_dps(t) if velocity else self.bounce.position_deg(t)
        return out

    def position_velocity(self, t_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """(position_deg, velocity_dps) at every time: the pieces looked up once."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        idx = self._piece_index(t)
        return self._eval_pieces(t, False, idx), self._eval_pieces(t, True, idx)

    def position_deg(self, t_s: ArrayLike) -> FloatArray:
        return self._eval(t_s, velocity=False)

    def velocity_dps(self, t_s: ArrayLike) -> FloatArray:
        return self._eval(t_s, velocity=True)

    def at(self, t_s: float) -> tuple[float, float]:
        """(position_deg, velocity_dps) at one time."""
        return float(self.position_deg(t_s)[0]), float(self.velocity_dps(t_s)[0])

    def final_rate_dps(self) -> float:
        last = self.pieces[-1]
        return last.coeffs[1] if len(last.coeffs) > 1 else 0.0


def hold(t_s: float, angle_deg: float) -> Profile:
    return Profile((Piece(t_s, math.inf, (angle_deg,)),), motion_end_s=t_s)


def _ramp_pieces(t_s: float, p0: float, v0: float, v1: float, accel: float) -> list[Piece]:
    """Change velocity from v0 to v1 at `accel`, then keep v1 forever."""
    duration = abs(v1 - v0) / accel
    a = math.copysign(accel, v1 - v0) if duration > 0 else 0.0
    pieces = []
    if duration > 0:
        pieces.append(Piece(t_s, t_s + duration, (p0, v0, 0.5 * a)))
    p1 = p0 + v0 * duration + 0.5 * a * duration**2
    t1 = t_s + duration
    pieces.append(Piece(t1, math.inf, (p1, v1) if v1 != 0.0 else (p1,)))
    return pieces


def rate_profile(t_s: float, p0: float, v0: float, rate_dps: float, accel_dps2: float) -> Profile:
    """Rate mode: ramp to `rate_dps` at the acceleration limit, then turn at constant rate."""
    pieces = _ramp_pieces(t_s, p0, v0, rate_dps, accel_dps2)
    return Profile(tuple(pieces), motion_end_s=pieces[-1].t0_s)


def stop_profile(t_s: float, p0: float, v0: float, accel_dps2: float) -> Profile:
    """Decelerate to rest at `accel_dps2` and hold there."""
    return rate_profile(t_s, p0, v0, 0.0, accel_dps2)


def _stop_first(t_s: float, p0: float, v0: float, accel: float) -> tuple[list[Piece], float, float]:
    if v0 == 0.0:
        return [], t_s, p0
    pieces = _ramp_pieces(t_s, p0, v0, 0.0, accel)
    rest = pieces[-1]
    return pieces[:-1], rest.t0_s, rest.coeffs[0]


def _with_bounce(
    pieces: list[Piece], t_end: float, target: float, bounce: BounceConfig | None, moved: bool
) -> Profile:
    pieces.append(Piece(t_end, math.inf, (target,)))
    b = None
    if bounce is not None and moved and bounce.amplitude_deg > 0:
        b = Bounce(t_end, bounce.amplitude_deg, bounce.frequency_hz, bounce.decay_s)
    return Profile(tuple(pieces), motion_end_s=t_end, bounce=b)


def trapezoid_move(
    t_s: float,
    p0: float,
    v0: float,
    target_deg: float,
    accel_dps2: float,
    max_rate_dps: float,
    bounce: BounceConfig | None = None,
) -> Profile:
    """Position move at the acceleration limit and speed limit (triangle when short)."""
    pieces, t, p = _stop_first(t_s, p0, v0, accel_dps2)
    distance = target_deg - p
    s = math.copysign(1.0, distance)
    d = abs(distance)
    a = accel_dps2
    if d > 0:
        v_peak = min(max_rate_dps, math.sqrt(d * a))
        t_acc = v_peak / a
        d_acc = 0.5 * a * t_acc**2
        t_cruise = (d - 2 * d_acc) / v_peak
        pieces.append(Piece(t, t + t_acc, (p, 0.0, 0.5 * s * a)))
        t += t_acc
        p += s * d_acc
        if t_cruise > 0:
            pieces.append(Piece(t, t + t_cruise, (p, s * v_peak)))
            t += t_cruise
            p += s * v_peak * t_cruise
        pieces.append(Piece(t, t + t_acc, (p, s * v_peak, -0.5 * s * a)))
        t += t_acc
    return _with_bounce(pieces, t, target_deg, bounce, moved=d > 0)


def smooth_move(
    t_s: float,
    p0: float,
    v0: float,
    target_deg: float,
    duration_s: float,
    accel_dps2: float,
    bounce: BounceConfig | None = None,
) -> Profile:
    """Minimum-jerk move of `duration_s` (zero velocity and acceleration at both ends)."""
    pieces, t, p = _stop_first(t_s, p0, v0, accel_dps2)
    d = target_deg - p
    if d != 0.0:
        duration = duration_s
        # p(tau) = p + d (10 s^3 - 15 s^4 + 6 s^5), s = tau / T
        coeffs = (p, 0.0, 0.0, 10 * d / duration**3, -15 * d / duration**4, 6 * d / duration**5)
        pieces.append(Piece(t, t + duration, coeffs))
        t += duration
    return _with_bounce(pieces, t, target_deg, bounce, moved=d != 0.0)
