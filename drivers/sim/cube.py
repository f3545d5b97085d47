"""A three-axis part's cube on the table, and the simulated operator who turns it.

The part sits in a cube on the single-axis table (table axis vertical); the cube rests on one
of its six faces, named by the part axis that points up ("+x" .. "-z", drivers/orientation.py).
On a prompt naming a face (the operator endpoint, drivers/sim/operator_eyes.py) the operator
reacts, then tips the cube over in a few seconds so that face points up: 90 deg over an edge
to a neighbouring face, 180 deg to the opposite one, as a minimum-jerk rotation about a fixed
axis, so the part sees a real (non-zero) rate during the turn. Everything is analytic in
world time (as drivers/sim/hand.py), evaluated vectorised at any sample times; a turn is
planned after its prompt and starts no earlier than the world's present, so samples already
sent never change.

The attitude R maps part-frame vectors to the table frame (z up). The part-frame rate is the
table's rate about z, R^T z r, plus the turn's own rate; the accelerometer reads +g R^T z.
The cube sits on the table's axis (no centripetal acceleration).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.orientation import ORIENTATIONS, STANDARD_GRAVITY_MPS2, normalise_face, up_vector
from drivers.sim.config import CubeConfig

FloatArray = NDArray[np.float64]


def resting_attitude(face: str) -> FloatArray:
    """R (part -> table) of the cube resting with `face` up: its third row is the up axis in
    the part frame, so R e_up = z; the heading about z is a fixed choice per face."""
    up = up_vector(face)
    side = np.roll(np.abs(up), 1)  # a part axis perpendicular to the up axis
    second = np.cross(up, side)
    return np.vstack([side, second, up])


def tip_rotvec(here: str, target: str) -> FloatArray:
    """The part-frame rotation (axis x angle, rad) that tips the cube from resting on `here`
    to resting on `target`: R_new = R Rot with Rot e_target = e_here (so R_new^T z = e_target),
    90 deg over an edge or 180 deg for the opposite face."""
    a, b = up_vector(target), up_vector(here)
    axis = np.cross(a, b)
    if np.linalg.norm(axis) < 0.5:  # opposite faces: any horizontal axis will do
        return math.pi * np.roll(np.abs(a), 1)
    return 0.5 * math.pi * axis


def _min_jerk(s: FloatArray) -> FloatArray:
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s * s)


def _min_jerk_rate(s: FloatArray) -> FloatArray:
    inside = (s > 0.0) & (s < 1.0)
    return np.where(inside, 30.0 * s * s * (1.0 - s) ** 2, 0.0)


def _rotation() -> Any:
    """scipy's Rotation, imported on first need (a bench with cubes)."""
    from scipy.spatial.transform import Rotation

    return Rotation


@dataclass(frozen=True)
class CubeTurn:
    """One reorientation: R(t) = R_from Rot(k, theta s(t)) over [start_s, end_s]; the body
    rate is k theta s'(t) (k a unit axis in the part frame)."""

    start_s: float
    end_s: float
    from_face: str
    to_face: str
    asked_face: str
    rotvec: tuple[float, float, float]  # k theta, rad, part frame
    from_attitude: tuple[tuple[float, ...], ...]  # R at the start (part -> table)

    def progress(self, t: FloatArray) -> FloatArray:
        return _min_jerk((t - self.start_s) / (self.end_s - self.start_s))

    def attitude(self, t: FloatArray) -> NDArray[np.float64]:
        """(n, 3, 3) attitudes at times `t` inside or around the turn."""
        rotation = _rotation()
        s = self.progress(t)
        rel = rotation.from_rotvec(np.outer(s, self.rotvec)).as_matrix()
        return np.asarray(np.asarray(self.from_attitude) @ rel, dtype=np.float64)

    def final_attitude(self) -> FloatArray:
        return np.asarray(self.from_attitude) @ _rotation().from_rotvec(self.rotvec).as_matrix()

    def body_rate_dps(self, t: FloatArray) -> FloatArray:
        s = (t - self.start_s) / (self.end_s - self.start_s)
        ds = _min_jerk_rate(s) / (self.end_s - self.start_s)
        return np.degrees(np.outer(ds, self.rotvec))

    def as_dict(self) -> dict[str, Any]:
        return {"start_s": self.start_s, "end_s": self.end_s, "from": self.from_face,
                "to": self.to_face, "asked": self.asked_face,
                "angle_deg": math.degrees(float(np.linalg.norm(self.rotvec)))}


class Cube:
    """One socket's cube: its resting face over world time and the operator's turns."""

    def __init__(self, cfg: CubeConfig, seed: int, socket: int) -> None:
        self.cfg = cfg
        self.initial_face = normalise_face(cfg.initial_face)
        self.rng = np.random.default_rng([seed, socket, 3303])
        self.turns: list[CubeTurn] = []
        self.prompts_seen = 0
        self._attitude = resting_attitude(self.initial_face)  # after the planned turns
        # the turns' rotations need scipy (0.4 s of import): imported with the cube, never
        # inside the bench's sample path, where it would stall every twin at a scaled clock
        _rotation()

    def place(self, face: str) -> None:
        """Put the cube down on `face` with no turns (a test's or a bench operator's setup)."""
        self.initial_face = normalise_face(face)
        self.turns.clear()
        self._attitude = resting_attitude(self.initial_face)

    @property
    def face_after_turns(self) -> str:
        return self.turns[-1].to_face if self.turns else self.initial_face

    def face_at(self, t_s: float) -> str | None:
        """The face up at world time `t_s`; None while a turn is under way."""
        face = self.initial_face
        for turn in self.turns:
            if t_s < turn.start_s:
                break
            if t_s < turn.end_s:
                return None
            face = turn.to_face
        return face

    def on_prompt(self, t_s: float, face: str, earliest_s: float | None = None) -> CubeTurn | None:
        """The operator read "turn so that `face` points up" at world time `t_s`: plan the
        turn after the reaction time and any turn under way (None: nothing to do, or the
        operator does not respond). A slip (cfg.wrong_face_probability) ends on another face."""
        self.prompts_seen += 1
        asked = normalise_face(face)
        cfg = self.cfg
        if not cfg.responds:
            return None
        here = self.face_after_turns
        target = asked
        if cfg.wrong_face_probability > 0 and self.rng.random() < cfg.wrong_face_probability:
            target = str(self.rng.choice([f for f in ORIENTATIONS if f not in (asked, here)]))
        if target == here:
            return None
        start = t_s + float(self.rng.uniform(cfg.reaction_min_s, cfg.reaction_max_s))
        if earliest_s is not None:
            start = max(start, earliest_s)
        if self.turns:
            start = max(start, self.turns[-1].end_s)
        duration = float(self.rng.uniform(cfg.turn_min_s, cfg.turn_max_s))
        rotvec = tip_rotvec(here, target)
        turn = CubeTurn(start, start + duration, here, target, asked,
                        (float(rotvec[0]), float(rotvec[1]), float(rotvec[2])),
                        tuple(tuple(float(v) for v in row) for row in self._attitude))
        self.turns.append(turn)
        self._attitude = turn.final_attitude()
        return turn

    def _segments(self, t: FloatArray) -> list[tuple[NDArray[np.bool_], CubeTurn | None, str]]:
        """Masks of `t` by what governs them: a turn, or rest on a face (turn None)."""
        out: list[tuple[NDArray[np.bool_], CubeTurn | None, str]] = []
        lower, face = -math.inf, self.initial_face
        for turn in self.turns:
            out.append(((t >= lower) & (t < turn.start_s), None, face))
            out.append(((t >= turn.start_s) & (t < turn.end_s), turn, face))
            lower, face = turn.end_s, turn.to_face
        out.append((t >= lower, None, face))
        return out

    def up_in_part(self, t_s: ArrayLike) -> FloatArray:
        """(n, 3): the table's up axis in the part frame at world times `t_s` (R^T z)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        out = np.empty((t.size, 3))
        for mask, turn, face in self._segments(t):
            if not mask.any():
                continue
            if turn is None:
                out[mask] = up_vector(face)
            else:
                out[mask] = turn.attitude(t[mask])[:, 2, :]
        return out

    def turn_rate_dps(self, t_s: ArrayLike) -> FloatArray:
        """(n, 3): the part-frame rate of the operator's turning, deg/s (0 at rest)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        out = np.zeros((t.size, 3))
        for mask, turn, _ in self._segments(t):
            if turn is not None and mask.any():
                out[mask] = turn.body_rate_dps(t[mask])
        return out

    def specific_force_mps2(self, t_s: ArrayLike) -> FloatArray:
        """(n, 3): what an ideal accelerometer in the part reads (gravity's reaction, up)."""
        return STANDARD_GRAVITY_MPS2 * self.up_in_part(t_s)

    def truth(self, t_s: float) -> dict[str, Any]:
        return {"face": self.face_at(t_s), "prompts_seen": self.prompts_seen,
                "turns": [turn.as_dict() for turn in self.turns[-20:]]}
