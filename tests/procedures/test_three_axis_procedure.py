"""The three-axis procedure file loads against its product; the fit step's per-axis
measurements and registers follow the fit; prompt words."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from procedures.analysis.three_axis import fit_three_axis
from procedures.loading.config import check_procedure_for_product, load_procedure, load_product
from procedures.steps.cube import prompt_text
from procedures.steps.three_axis_fit import FitThreeAxis, per_axis_measurements, registers_from
from tests.analysis.test_three_axis import random_truth, synth_windows

ROOT = Path(__file__).resolve().parents[2]


def test_three_axis_procedure_loads_and_every_measurement_has_a_limit() -> None:
    proc, proc_file = load_procedure(ROOT / "config/procedures/eol-three-axis.yaml")
    product, product_file = load_product(ROOT / "config/products/imu3.yaml")
    assert product.axes == 3
    check_procedure_for_product(proc, proc_file, product, product_file)  # raises on a problem


def test_fit_measurements_are_declared_and_registers_apply_the_fit() -> None:
    rng = np.random.default_rng(11)
    truth = random_truth(rng)
    cal = fit_three_axis(synth_windows(truth, rng))
    declared = {d.name for d in FitThreeAxis.measurements(FitThreeAxis.Settings())}
    rows = per_axis_measurements(cal)
    assert {r[0] for r in rows} == declared  # temperature/supply fitted: all of them
    mis = {r[0]: r[1] for r in rows}["misalignment_xy_mrad"]
    assert abs(mis - 1e3 * truth["matrix"][0, 1] / truth["matrix"][0, 0]) < 0.1
    # the registers undo the truth's raw output: compensate(raw) is the true rate
    regs = registers_from(cal)
    w = np.array([[10.0, -20.0, 30.0]])
    a = np.array([[0.0, 0.0, 9.80665]])
    dt, dv = 12.0, 0.2
    s = np.linalg.inv(truth["matrix"]) @ np.diag(
        1 + truth["scale_temp_coeff_per_c"] * dt + truth["scale_supply_coeff_per_v"] * dv)
    b = (truth["bias_dps"] + truth["bias_temp_coeff_dps_per_c"] * dt
         + truth["bias_supply_coeff_dps_per_v"] * dv)
    raw = w @ s.T + b + a @ truth["g_sensitivity_dps_per_mps2"].T
    assert np.allclose(regs.compensate(raw, a, 25.0 + dt, 5.0 + dv), w, atol=0.01)


def test_prompt_names_socket_and_face_in_plain_words() -> None:
    assert prompt_text("+y", [1]) == "Turn socket 1's cube so that face +Y points up"
    assert prompt_text("-z", [1, 2, 3]) == (
        "Turn the cubes of sockets 1, 2 and 3 so that face -Z points up")
