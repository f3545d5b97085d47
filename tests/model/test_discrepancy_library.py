"""Effects outside the catalog (tests/model/synth_gyro.py BEYOND_CATALOG, generated apart
from the workflow, with a thermal ramp between the temperatures): named first by a library
term with the right base variables, the gap closed to the floor of the same record without
the effect, and the floor not inflated by the effect."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers_model import as_trajectory
from synth_gyro import BEYOND_CATALOG, RAMPED, RAMPED3, generate, realistic_part

from procedures.model import effects as fx
from procedures.model import library
from procedures.model.discrepancy import run_discrepancy
from procedures.model.effect_spec import REGRESSOR_VOCABULARY
from procedures.model.gyro_model import first_order_model
from procedures.model.model_io import load_model, save_model
from procedures.model.output import result_to_json

# kinds the RAMPED profile can show (its plateaus sit at two temperatures, so a scale
# quadratic in temperature is not separable there from its look-alikes: tested on RAMPED3)
KINDS = ["bias_temperature_quadratic", "bias_temperature_rate", "bias_angle_2nd",
         "scale_temperature_supply", "bias_rate_sign"]
SEED = 21
PINNED_CATALOG_REGRESSORS = {
    "bias_temperature": {"temperature"},
    "scale_temperature": {"rate", "temperature"},
    "bias_supply": {"supply"},
    "scale_supply": {"rate", "supply"},
    "k2_quadratic": {"rate"},
    "k3_cubic": {"rate"},
    "scale_asymmetry": {"rate"},
    "g_sensitivity_tilt": {"angle"},
    "warmup_drift": {"time"},
    "sensor_lag": {"rate"},
}


@pytest.fixture(scope="module")
def without_effect():
    traj = as_trajectory(generate(realistic_part(), SEED, RAMPED))
    return run_discrepancy(traj, first_order_model())


def test_catalog_effects_declare_their_regressors() -> None:
    got = {e: set(s.regressors) for e, s in fx.CATALOG.items()}
    assert got == PINNED_CATALOG_REGRESSORS
    for spec in fx.CATALOG.values():
        assert spec.formula, spec.id


def test_every_library_term_has_regressors_from_the_vocabulary_and_a_formula() -> None:
    for e in library.candidate_ids():
        spec = fx.check_effect_id(e)
        assert spec.regressors and set(spec.regressors) <= set(REGRESSOR_VOCABULARY), e
        assert "{" in spec.formula, e


def test_the_null_record_names_nothing(without_effect) -> None:
    assert without_effect.effects_added == []
    assert not without_effect.unexplained_remains


@pytest.mark.parametrize("kind", KINDS)
def test_effect_outside_catalog_named_first_with_its_regressors(kind: str, without_effect
                                                                ) -> None:
    part = realistic_part().with_effect(kind)
    res = run_discrepancy(as_trajectory(generate(part, SEED, RAMPED)), first_order_model())
    assert res.iterations, f"nothing named: gap {res.gap_initial_dps}, {res.noise_floor_dps}"
    first = res.iterations[0]
    assert library.is_library_id(first.effect), first.effect
    assert set(first.regressors) == BEYOND_CATALOG[kind][0]
    assert first.formula and "{" not in first.formula
    floor_without = without_effect.noise_floor_dps
    assert res.noise_floor_dps <= 1.5 * floor_without  # the effect is not taken for noise
    assert res.gap_initial_dps > 1.5 * floor_without  # there was a gap to close
    assert res.gap_final_dps <= 1.5 * floor_without
    assert "g_sensitivity_tilt" not in res.effects_added
    assert not res.unexplained_remains


def test_scale_quadratic_in_temperature_is_named_with_plateaus_at_three_temperatures(
) -> None:
    """On RAMPED3 (plateaus at 25, 40 and 55 C) a scale quadratic in temperature is named
    lib_w_dT2, with the gap and floor held to the same record's without it."""
    kind = "scale_temperature_quadratic"
    plain = run_discrepancy(as_trajectory(generate(realistic_part(), SEED, RAMPED3)),
                            first_order_model())
    assert plain.effects_added == []
    part = realistic_part().with_effect(kind)
    res = run_discrepancy(as_trajectory(generate(part, SEED, RAMPED3)), first_order_model())
    assert res.effects_added[:1] == ["lib_w_dT2"], (res.effects_added, res.not_separable)
    assert set(res.iterations[0].regressors) == BEYOND_CATALOG[kind][0]
    assert res.final_model.effects["lib_w_dT2"]["coeff"] == pytest.approx(
        BEYOND_CATALOG[kind][1]["c_per_c2"], rel=0.3)  # coeff = scale x c, scale ~ 1
    assert res.noise_floor_dps <= 1.5 * plain.noise_floor_dps
    assert res.gap_initial_dps > 1.5 * plain.noise_floor_dps
    assert res.gap_final_dps <= 1.5 * plain.noise_floor_dps


def test_twice_the_table_angle_is_not_named_tilt() -> None:
    part = realistic_part().with_effect("bias_angle_2nd", amplitude_dps=0.05)
    res = run_discrepancy(as_trajectory(generate(part, SEED + 1, RAMPED)), first_order_model())
    assert res.effects_added[0] == "lib_angleh2"
    assert "g_sensitivity_tilt" not in res.effects_added
    assert res.final_model.effects["lib_angleh2"]["amplitude_dps"] == pytest.approx(0.05,
                                                                                  rel=0.2)


@pytest.mark.parametrize(("kind", "variable"), [("bias_temperature_rate", "temperature_rate"),
                                                ("bias_angle_2nd", "angle")])
def test_structure_left_unexplained_is_reported_with_its_variable(kind: str, variable: str
                                                                  ) -> None:
    """With naming switched off (no iteration), the gap stays and the report says against
    which variable the residual pattern is strongest."""
    part = realistic_part().with_effect(kind)
    res = run_discrepancy(as_trajectory(generate(part, SEED, RAMPED)), first_order_model(),
                          max_iterations=0)
    assert res.unexplained_remains
    assert res.unexplained[0].variable == variable
    out = result_to_json(res)
    assert out["unexplained_structure_remains"] is True
    assert out["unexplained_structure"][0]["variable"] == variable
    assert variable in out["unexplained_structure_message"]


def test_json_iterations_carry_regressors_and_formula_and_the_model_reads_back(tmp_path
                                                                               ) -> None:
    part = realistic_part().with_effect("scale_temperature_supply")
    traj = as_trajectory(generate(part, SEED, RAMPED))
    res = run_discrepancy(traj, first_order_model())
    out = json.loads(json.dumps(result_to_json(res)))
    it = out["iterations"][0]
    assert set(it["regressors"]) == {"rate", "temperature", "supply"}
    assert it["formula"].startswith("scale factor proportional to")
    path = save_model(res.final_model, tmp_path / "model.yaml")
    back = load_model(path)
    assert set(back.effects) == set(res.final_model.effects)
    assert np.allclose(back.predict(traj), res.final_model.predict(traj))
    again = run_discrepancy(traj, back)  # the extended model explains the record
    assert again.effects_added == []
    assert again.gap_final_dps <= 1.5 * again.noise_floor_dps


def test_null_runs_with_the_library_on_stay_clean() -> None:
    alarms = []
    for seed in range(40, 44):
        res = run_discrepancy(as_trajectory(generate(realistic_part(), seed, RAMPED)),
                              first_order_model())
        if res.effects_added or res.not_separable or res.unexplained_remains:
            alarms.append((seed, res.effects_added))
    # a fixed seed set, clean today; the false-alarm rate itself (documented: at most 5 %)
    # is measured by benchmarks/bench_discrepancy.py --null-trials
    assert not alarms, alarms
