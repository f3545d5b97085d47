"""Orientations of a three-axis part in its cube on a single-axis table (table axis vertical).

An orientation is named by the part axis that points up along the table axis: "+x", "-x",
"+y", "-y", "+z", "-z". On a level table the accelerometer then measures +g along that axis
(specific force, m/s^2), and a table rate +r about the up axis is the part-frame rate
r * e_up. One place for these conventions, used by the bench, the drivers and the procedures.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

STANDARD_GRAVITY_MPS2 = 9.80665
ORIENTATIONS = ("+x", "-x", "+y", "-y", "+z", "-z")
_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


def normalise_face(face: str) -> str:
    """'+X', ' +y ' -> '+x', '+y'; raises ValueError for anything that is not a face."""
    name = str(face).strip().lower()
    if name not in ORIENTATIONS:
        raise ValueError(
            f"orientation {face!r} is not a face of the cube: use one of {', '.join(ORIENTATIONS)}"
        )
    return name


def up_vector(face: str) -> NDArray[np.float64]:
    """The unit vector, in the part frame, of the axis that points up in orientation `face`."""
    name = normalise_face(face)
    e = np.zeros(3)
    e[_AXIS_INDEX[name[1]]] = 1.0 if name[0] == "+" else -1.0
    return e


def gravity_specific_force_mps2(face: str) -> NDArray[np.float64]:
    """What a level part's accelerometer measures at rest in orientation `face`, m/s^2."""
    return STANDARD_GRAVITY_MPS2 * up_vector(face)


def face_from_accel(accel_mps2: NDArray[np.float64], max_tilt_deg: float = 10.0) -> str | None:
    """The face pointing up, from a mean accelerometer reading (m/s^2, 3-vector): the axis
    nearest to the measured gravity direction, if within `max_tilt_deg` of it; else None."""
    a = np.asarray(accel_mps2, dtype=np.float64).reshape(3)
    norm = float(np.linalg.norm(a))
    if not math.isfinite(norm) or norm < 0.5 * STANDARD_GRAVITY_MPS2:
        return None
    i = int(np.argmax(np.abs(a)))
    if math.degrees(math.acos(min(1.0, abs(a[i]) / norm))) > max_tilt_deg:
        return None
    return ("+" if a[i] > 0 else "-") + "xyz"[i]
