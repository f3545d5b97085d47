"""The three-axis contract's types: calibration registers, orientation names, accel codes."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.orientation import (
    ORIENTATIONS,
    STANDARD_GRAVITY_MPS2,
    face_from_accel,
    gravity_specific_force_mps2,
    normalise_face,
    up_vector,
)
from drivers.part_codes import ADIS16130
from drivers.protocols import CalibrationRegisters3


def test_erased_registers_pass_raw_output_through() -> None:
    regs = CalibrationRegisters3()
    raw = np.array([[1.0, -2.0, 3.5], [0.25, 0.0, -7.0]])
    accel = np.array([[0.0, 0.0, 9.8], [9.8, 0.0, 0.0]])
    np.testing.assert_allclose(regs.compensate(raw, accel, 60.0, 5.5), raw)


def test_compensation_inverts_the_contract_model() -> None:
    rng = np.random.default_rng(3)
    m = np.eye(3) + rng.normal(0, 0.01, (3, 3))
    g = rng.normal(0, 0.01, (3, 3))
    b, btc, bvc = rng.normal(0, 1, 3), rng.normal(0, 0.01, 3), rng.normal(0, 0.1, 3)
    stc, svc = rng.normal(0, 1e-4, 3), rng.normal(0, 1e-3, 3)
    temp_c, supply_v = 47.0, 5.3
    d_t, d_v = temp_c - 25.0, supply_v - 5.0
    w = rng.normal(0, 50, (10, 3))
    a = rng.normal(0, 9.8, (10, 3))
    s = np.linalg.inv(m) @ np.diag(1 + stc * d_t + svc * d_v)
    raw = w @ s.T + (b + btc * d_t + bvc * d_v) + a @ g.T
    regs = CalibrationRegisters3(
        bias_dps=b, matrix=m, g_sensitivity_dps_per_mps2=g, bias_tc_dps_per_c=btc,
        bias_vc_dps_per_v=bvc, scale_tc_per_c=stc, scale_vc_per_v=svc,
    )
    np.testing.assert_allclose(regs.compensate(raw, a, temp_c, supply_v), w, atol=1e-9)


def test_registers_take_arrays_and_compare_as_tuples() -> None:
    a = CalibrationRegisters3(matrix=np.eye(3) * 2.0)
    b = CalibrationRegisters3(matrix=[[2, 0, 0], [0, 2, 0], [0, 0, 2]])
    assert a == b and isinstance(a.matrix[0][0], float)
    with pytest.raises(ValueError, match="3 x 3"):
        CalibrationRegisters3(matrix=np.eye(2))
    with pytest.raises(ValueError, match="3 numbers"):
        CalibrationRegisters3(bias_dps=[1.0, 2.0])


@pytest.mark.parametrize("face", ORIENTATIONS)
def test_each_face_round_trips_through_gravity(face: str) -> None:
    g = gravity_specific_force_mps2(face)
    assert np.isclose(np.linalg.norm(g), STANDARD_GRAVITY_MPS2)
    assert face_from_accel(g) == face
    assert np.count_nonzero(up_vector(face)) == 1


def test_face_from_accel_refuses_a_tilted_or_missing_gravity() -> None:
    g = STANDARD_GRAVITY_MPS2
    tilt = np.radians(15.0)
    assert face_from_accel(g * np.array([np.sin(tilt), 0, np.cos(tilt)])) is None
    assert face_from_accel(np.zeros(3)) is None
    tilt = np.radians(5.0)
    assert face_from_accel(g * np.array([0, -np.cos(tilt), np.sin(tilt)])) == "-y"


def test_normalise_face_names_the_faces_on_bad_input() -> None:
    assert normalise_face(" +Y ") == "+y"
    with pytest.raises(ValueError, match=r"\+x, -x"):
        normalise_face("up")


def test_accel_codes_round_trip() -> None:
    a = np.array([[0.0, -9.80665, 9.80665], [50.0, -50.0, 1e-3]])
    back = ADIS16130.accel_code_to_mps2(ADIS16130.accel_mps2_to_code(a))
    np.testing.assert_allclose(back, a, atol=1e-5)
