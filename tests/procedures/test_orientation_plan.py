from __future__ import annotations

import pytest

from procedures.runtime.orientation_plan import faces_for_condition, plan, turns


def test_reference_condition_visits_all_six_faces_starting_where_the_cube_is() -> None:
    faces = faces_for_condition(0, "-y")
    assert faces[0] == "-y" and sorted(faces) == sorted(["+x", "-x", "+y", "-y", "+z", "-z"])


def test_further_conditions_need_one_face_per_axis_starting_in_the_current_one() -> None:
    faces = faces_for_condition(2, "-x")
    assert faces[0] == "-x" and len(faces) == 3
    assert sorted(f[1] for f in faces) == ["x", "y", "z"]


def test_four_conditions_cost_eleven_turns_from_a_known_face() -> None:
    runs = plan(4, "+z")
    flat = [f for faces in runs for f in faces]
    assert turns(flat, "+z") == 5 + 3 * 2
    assert turns(flat, None) == 12


def test_unknown_face_is_refused() -> None:
    with pytest.raises(ValueError, match="not a face"):
        faces_for_condition(1, "up")
