"""The simulated operator's hand at a fixture turned by hand between two mechanical stops.

The article's bench has no rate table: each socket's fixture turns on a bearing between a
stop at 0 deg and a stop at the fixture's stop angle, and the operator turns it by hand when
the station prompts. The hand sees nothing of the station but its prompts (`on_prompt`, fed
by the bench's operator endpoint, drivers/sim/operator_eyes.py). After a reaction time it
moves the fixture to the other stop in 3 to 4 s; a human move is not smooth: it is a few
overlapping minimum-jerk sub-movements of uneven size, so the velocity has several bumps.
Sometimes the fixture bounces off the stop (a decaying rebound away from it, never through
it); when configured, sometimes the operator flicks it fast enough to over-range the part.

Everything is analytic in world time (as drivers/sim/motion.py), so the fixture's samples
evaluate the fixture angle at any time, vectorised; a move is planned after the prompt
arrives and starts later, so samples already sent are never changed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.sim.config import HandConfig

FloatArray = NDArray[np.float64]


def _min_jerk(s: FloatArray) -> FloatArray:
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s * s)


def _min_jerk_rate(s: FloatArray) -> FloatArray:
    inside = (s > 0.0) & (s < 1.0)
    return np.where(inside, 30.0 * s * s * (1.0 - s) ** 2, 0.0)


@dataclass(frozen=True)
class SubMove:
    """amplitude_deg x the minimum-jerk shape over [t0_s, t0_s + duration_s]."""

    t0_s: float
    duration_s: float
    amplitude_deg: float

    def position_deg(self, t: FloatArray) -> FloatArray:
        return self.amplitude_deg * _min_jerk((t - self.t0_s) / self.duration_s)

    def rate_dps(self, t: FloatArray) -> FloatArray:
        s = (t - self.t0_s) / self.duration_s
        return self.amplitude_deg / self.duration_s * _min_jerk_rate(s)


@dataclass(frozen=True)
class StopBounce:
    """A rebound off the stop at `t0_s`: the angle leaves the stop by
    amplitude e^-(t-t0)/decay |sin(2 pi f (t-t0))| on the side it came from."""

    t0_s: float
    amplitude_deg: float  # signed: towards where the move came from
    frequency_hz: float
    decay_s: float

    def position_deg(self, t: FloatArray) -> FloatArray:
        tau = np.maximum(t - self.t0_s, 0.0)
        w = 2.0 * math.pi * self.frequency_hz
        return self.amplitude_deg * np.exp(-tau / self.decay_s) * np.abs(np.sin(w * tau))

    def rate_dps(self, t: FloatArray) -> FloatArray:
        tau = np.maximum(t - self.t0_s, 0.0)
        w = 2.0 * math.pi * self.frequency_hz
        sin = np.sin(w * tau)
        env = self.amplitude_deg * np.exp(-tau / self.decay_s)
        rate = env * (w * np.cos(w * tau) * np.sign(sin) - np.abs(sin) / self.decay_s)
        return np.where(t > self.t0_s, rate, 0.0)


@dataclass(frozen=True)
class HandMove:
    """One move from stop to stop: its sub-movements and, perhaps, a bounce at the end."""

    start_s: float
    end_s: float
    from_deg: float
    to_deg: float
    submoves: tuple[SubMove, ...]
    bounce: StopBounce | None
    flicked: bool

    def position_deg(self, t: FloatArray) -> FloatArray:
        out = np.full_like(t, self.from_deg)
        for sub in self.submoves:
            out += sub.position_deg(t)
        if self.bounce is not None:
            out += self.bounce.position_deg(t)
        return out

    def rate_dps(self, t: FloatArray) -> FloatArray:
        out = np.zeros_like(t)
        for sub in self.submoves:
            out += sub.rate_dps(t)
        if self.bounce is not None:
            out += self.bounce.rate_dps(t)
        return out

    def as_dict(self) -> dict[str, Any]:
        return {
            "start_s": self.start_s,
            "end_s": self.end_s,
            "from_deg": self.from_deg,
            "to_deg": self.to_deg,
            "submoves": len(self.submoves),
            "bounced": self.bounce is not None,
            "over_range_flick": self.flicked,
        }


def plan_move(
    start_s: float,
    from_deg: float,
    to_deg: float,
    duration_s: float,
    cfg: HandConfig,
    rng: np.random.Generator,
    flicked: bool = False,
) -> HandMove:
    """A human move of `duration_s`: `cfg.submoves` overlapping minimum-jerk sub-movements of
    uneven size and length (each in the move's direction, so the fixture never passes the
    stop), the last one ending at `start_s + duration_s` exactly on the stop."""
    distance = to_deg - from_deg
    k = 1 if flicked else cfg.submoves
    weights = rng.uniform(0.5, 1.5, k)
    amplitudes = distance * weights / weights.sum()
    subs: list[SubMove] = []
    if k == 1:
        subs.append(SubMove(start_s, duration_s, float(amplitudes[0])))
    else:
        lengths = duration_s * rng.uniform(0.35, 0.55, k)
        latest = duration_s - lengths  # latest start that still ends inside the move
        starts = np.sort(rng.uniform(0.0, 1.0, k)) * latest
        starts[0] = 0.0
        starts[-1] = latest[-1]  # the last sub-movement lands on the stop at the end
        for s0, length, amp in zip(starts, lengths, amplitudes, strict=True):
            subs.append(SubMove(start_s + float(s0), float(length), float(amp)))
    end_s = start_s + duration_s
    bounce = None
    if not flicked and cfg.bounce_amplitude_deg > 0 and rng.random() < cfg.bounce_probability:
        amp = -math.copysign(cfg.bounce_amplitude_deg * rng.uniform(0.5, 1.0), distance)
        bounce = StopBounce(end_s, amp, cfg.bounce_frequency_hz, cfg.bounce_decay_s)
    return HandMove(start_s, end_s, from_deg, to_deg, tuple(subs), bounce, flicked)


class HandFixture:
    """One socket's hand-turned fixture: its angle in world time, and the operator's hand."""

    def __init__(self, cfg: HandConfig, stop_angle_deg: float, seed: int, socket: int) -> None:
        self.cfg = cfg
        self.stop_angle_deg = stop_angle_deg
        self.rng = np.random.default_rng([seed, socket, 4263])
        self.moves: list[HandMove] = []
        self.prompts_seen = 0

    @property
    def target_after_moves_deg(self) -> float:
        return self.moves[-1].to_deg if self.moves else 0.0

    def on_prompt(self, t_s: float, earliest_s: float | None = None) -> HandMove | None:
        """The operator read a prompt for this socket at world time `t_s`: plan the turn to
        the other stop (after the reaction time, and after any move still under way), never
        before `earliest_s` (the samples up to then are already sent)."""
        self.prompts_seen += 1
        if not self.cfg.responds:
            return None
        cfg = self.cfg
        start = t_s + float(self.rng.uniform(cfg.reaction_min_s, cfg.reaction_max_s))
        if earliest_s is not None:
            start = max(start, earliest_s)
        if self.moves:
            last = self.moves[-1]
            settled = last.end_s + (5.0 * last.bounce.decay_s if last.bounce else 0.0)
            start = max(start, settled)
        here = self.target_after_moves_deg
        there = self.stop_angle_deg if abs(here) < 0.5 * self.stop_angle_deg else 0.0
        flicked = bool(self.rng.random() < cfg.over_range_probability)
        duration = (
            cfg.over_range_move_s
            if flicked
            else float(self.rng.uniform(cfg.move_min_s, cfg.move_max_s))
        )
        move = plan_move(start, here, there, duration, cfg, self.rng, flicked)
        self.moves.append(move)
        return move

    def _eval(self, t_s: ArrayLike, rate: bool) -> FloatArray:
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        if not self.moves:
            return np.zeros_like(t)
        out = np.zeros_like(t) if rate else np.full_like(t, self.moves[0].from_deg)
        bounds = [m.start_s for m in self.moves[1:]] + [math.inf]
        lower = -math.inf
        for move, upper in zip(self.moves, bounds, strict=True):
            sel = (t >= lower) & (t < upper)
            if sel.any():
                out[sel] = move.rate_dps(t[sel]) if rate else move.position_deg(t[sel])
            lower = upper
        return out

    def angle_deg(self, t_s: ArrayLike) -> FloatArray:
        """The fixture's angle from its first stop (deg) at world times `t_s`."""
        return self._eval(t_s, rate=False)

    def rate_dps(self, t_s: ArrayLike) -> FloatArray:
        return self._eval(t_s, rate=True)

    def truth(self, t_s: float) -> dict[str, Any]:
        return {
            "angle_deg": float(self.angle_deg(t_s)[0]),
            "rate_dps": float(self.rate_dps(t_s)[0]),
            "prompts_seen": self.prompts_seen,
            "moves": [m.as_dict() for m in self.moves[-20:]],
        }
