"""Which cube faces a three-axis part is measured in at each condition, in turn order.

At the first condition of the loop (the reference) the part is measured in all six faces:
static windows with gravity along +x, -x, +y, -y, +z and -z separate the bias b from the
g-sensitivity G, and table-rate plateaus about each axis give the columns of S = M^-1 D.
At every further condition one face per axis is enough: G is a property of the part (fitted
once, from all windows), so three static windows give the bias vector there, and one rate
plateau pair about each axis gives that axis's scale there, which is what the per-axis
temperature and supply coefficients need. The sign of the face does not matter (a rate about
-x is a rate about x), so each condition starts in the face the cube is already in: the
operator turns the cube 5 times at the reference and 2 times at each further condition
(docs/three-axis.md).
"""

from __future__ import annotations

from collections.abc import Sequence

from drivers.orientation import ORIENTATIONS, normalise_face

_ONE_PER_AXIS = ("+z", "+x", "+y")


def faces_for_condition(condition_index: int, current_face: str | None) -> list[str]:
    """The faces to measure in at this condition, starting with the current face if it is
    one of them (so the operator turns the cube as few times as possible)."""
    current = normalise_face(current_face) if current_face is not None else None
    if condition_index == 0:
        wanted = list(ORIENTATIONS)
        if current is not None:
            wanted.remove(current)
            wanted.insert(0, current)
        return wanted
    faces = [current] if current is not None else []
    for face in _ONE_PER_AXIS:
        if not any(f[1] == face[1] for f in faces):
            faces.append(face)
    return faces


def turns(sequence: Sequence[str], start_face: str | None) -> int:
    """Operator turns to follow `sequence` from `start_face` (None: an unknown start, the
    first face costs a turn)."""
    count, face = 0, start_face
    for nxt in sequence:
        if nxt != face:
            count += 1
        face = nxt
    return count


def plan(n_conditions: int, start_face: str | None) -> list[list[str]]:
    """Faces per condition for a whole run, each condition starting where the last ended."""
    out: list[list[str]] = []
    face = start_face
    for k in range(n_conditions):
        faces = faces_for_condition(k, face)
        out.append(faces)
        face = faces[-1]
    return out
