"""Simulated hand-turned sessions of a three-axis part, written apart from the analysis.

The part is held in a cube: six static faces (each with a small random tilt, as a hand sets
it down), and in the x_p, y_p and z_p faces one rotation about the part's own axis with a
smooth rate profile, with rests before and after. Between sections the hand turns the cube
(arbitrary motion, outside every section). Physics, as the contract writes it:

    gyro  = S w + b + G a + white noise,   S = M^-1
    accel = a + white noise                (a: specific force in the part frame, +g up)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

G0 = 9.80665
UP_LAB = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Truth:
    bias_dps: NDArray[np.float64]
    matrix: NDArray[np.float64]  # M: w_hat = M (raw - b - G a)
    g_sensitivity: NDArray[np.float64]  # G, deg/s per m/s^2


@dataclass
class Session:
    gyro_dps: NDArray[np.float64]
    accel_mps2: NDArray[np.float64]
    sections: dict[str, tuple[int, int]]
    sample_rate_hz: float
    truth: Truth
    rotation_deg: float
    # the bias random walk added to each sample (zeros without one), for a time-varying truth
    bias_walk_dps: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))


def random_truth(rng: np.random.Generator) -> Truth:
    """A plausible MEMS part: bias of a few tenths of deg/s, 1 % scale, 0.5 deg misalignment."""
    scale = np.diag(1.0 + rng.normal(0.0, 0.01, 3))
    misalign = rng.normal(0.0, math.radians(0.5), (3, 3))
    np.fill_diagonal(misalign, 0.0)
    s = scale @ (np.eye(3) + misalign)
    return Truth(
        bias_dps=rng.normal(0.0, 0.3, 3),
        matrix=np.linalg.inv(s),
        g_sensitivity=rng.normal(0.0, 0.002, (3, 3)),
    )


def _rot(axis: NDArray[np.float64], angle_rad: float) -> NDArray[np.float64]:
    """Rotation matrix (Rodrigues) by angle about a unit axis, right-hand rule."""
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle_rad) * kx + (1 - math.cos(angle_rad)) * kx @ kx


def _face_orientation(face: str) -> NDArray[np.float64]:
    """R (part -> lab) with the named part axis pointing up (lab +z)."""
    axis = np.eye(3)["xyz".index(face[0])]
    v = axis * (1.0 if face[2] == "p" else -1.0)  # the part vector that must point up
    c = float(v @ UP_LAB)
    if abs(c - 1) < 1e-12:
        return np.eye(3)
    if abs(c + 1) < 1e-12:
        return _rot(np.array([1.0, 0.0, 0.0]), math.pi)
    cross = np.cross(v, UP_LAB)
    return _rot(cross, math.acos(c))


def hand_turned_session(
    rng: np.random.Generator,
    truth: Truth,
    *,
    sample_rate_hz: float = 100.0,
    face_s: float = 8.0,
    rotation_s: float = 4.0,
    rest_s: float = 1.0,
    turn_s: float = 2.0,
    rotation_deg: float = 360.0,
    gyro_noise_dps: float = 0.05,
    accel_noise_mps2: float = 0.02,
    tilt_deg: float = 1.0,
    rrw_dps_per_sqrt_s: float = 0.0,
) -> Session:
    """A session; `rrw_dps_per_sqrt_s` adds a bias random walk per axis (correlated noise)."""
    fs = sample_rate_hz
    s_matrix = np.linalg.inv(truth.matrix)
    w_parts: list[NDArray[np.float64]] = []  # true rate, part frame
    a_parts: list[NDArray[np.float64]] = []  # specific force, part frame
    sections: dict[str, tuple[int, int]] = {}
    n = 0

    def add(w: NDArray[np.float64], a: NDArray[np.float64]) -> tuple[int, int]:
        nonlocal n
        w_parts.append(w)
        a_parts.append(a)
        span = (n, n + w.shape[0])
        n += w.shape[0]
        return span

    def turn() -> None:
        k = int(turn_s * fs)
        t = np.arange(k) / fs
        phase = rng.uniform(0, 2 * math.pi, 3)
        w = 60.0 * np.sin(2 * math.pi * t[:, None] / turn_s + phase)
        a = G0 * rng.normal(0, 0.6, 3) + np.zeros((k, 3))
        add(w, a)

    for face in ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a"):
        tilt_axis = np.array([*rng.normal(0, 1, 2), 0.0])
        tilt = _rot(tilt_axis, math.radians(tilt_deg) * abs(rng.normal(0, 1)))
        r0 = tilt @ _face_orientation(face)
        a0 = r0.T @ (G0 * UP_LAB)
        k = int(face_s * fs)
        sections[face] = add(np.zeros((k, 3)), np.tile(a0, (k, 1)))
        if face.endswith("_p"):
            turn()  # lift the hand, settle again on the same face
            sections[face[0] + "_rot"] = _rotation(
                add, face[0], a0, fs, rotation_s, rest_s, rotation_deg
            )
        turn()

    w_true = np.concatenate(w_parts)
    a_true = np.concatenate(a_parts)
    walk = np.cumsum(rng.normal(0, rrw_dps_per_sqrt_s / math.sqrt(fs), w_true.shape), axis=0)
    gyro = (
        w_true @ s_matrix.T
        + truth.bias_dps
        + a_true @ truth.g_sensitivity.T
        + rng.normal(0, gyro_noise_dps, w_true.shape)
        + walk
    )
    accel = a_true + rng.normal(0, accel_noise_mps2, a_true.shape)
    return Session(gyro, accel, sections, fs, truth, rotation_deg, walk)


def _rotation(
    add: Callable[[NDArray[np.float64], NDArray[np.float64]], tuple[int, int]],
    axis_name: str,
    a0: NDArray[np.float64],
    fs: float,
    rotation_s: float,
    rest_s: float,
    rotation_deg: float,
) -> tuple[int, int]:
    """Rest, one smooth rotation about the part axis, rest; specific force turns with it."""
    axis = np.eye(3)["xyz".index(axis_name)]
    k_rest, k_move = int(rest_s * fs), int(rotation_s * fs)
    t = np.arange(k_move) / fs
    theta = math.radians(rotation_deg)
    cycle = 2 * math.pi * t / rotation_s
    rate = (theta / rotation_s) * (1 - np.cos(cycle))  # rad/s
    phi = (theta / rotation_s) * (t - rotation_s / (2 * math.pi) * np.sin(cycle))
    phi_all = np.concatenate([np.zeros(k_rest), phi, np.full(k_rest, theta)])
    rate_all = np.concatenate([np.zeros(k_rest), rate, np.zeros(k_rest)])
    w = np.outer(np.degrees(rate_all), axis)
    # the part turns by phi about its own axis: a fixed lab vector turns by -phi in its frame
    c, sn = np.cos(-phi_all)[:, None], np.sin(-phi_all)[:, None]  # Rodrigues, vectorised
    a = a0 * c + np.cross(axis, a0) * sn + axis * float(axis @ a0) * (1 - c)
    return add(w, a)
