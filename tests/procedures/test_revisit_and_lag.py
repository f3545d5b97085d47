"""The revisit condition (conditions.revisit_c) and the element-lag temperature of a condition's
windows (ConditionResult.temperature_for), and the fit's record of a point."""

from __future__ import annotations

import numpy as np
import pytest

from procedures.analysis.hysteresis import correction
from procedures.analysis.temp_supply_fit import ConditionMeasurement
from procedures.runtime.conditions import Condition, plan_conditions, with_revisit
from procedures.runtime.run_parts import ConditionResult
from procedures.steps.fit import fit_point


def test_no_revisit_leaves_the_plan() -> None:
    plan = plan_conditions([25.0, 45.0], [4.75, 5.25], start_temp_c=25.0)
    assert with_revisit(plan, None, 25.0) == plan


def test_the_revisit_goes_against_the_way_the_last_temperature_was_reached() -> None:
    up = plan_conditions([25.0, 45.0], [4.75, 5.25], start_temp_c=25.0)
    assert with_revisit(up, 3.0, 25.0)[-1] == Condition(42.0, up[-1].supply_v)
    down = plan_conditions([25.0, 45.0], [4.75, 5.25], start_temp_c=50.0)
    assert down[-1].temperature_c == 25.0
    assert with_revisit(down, 3.0, 50.0)[-1] == Condition(28.0, down[-1].supply_v)
    # one temperature: reached from the chamber's start (heating when unknown)
    single = plan_conditions([45.0], [5.0])
    assert with_revisit(single, 3.0, 60.0)[-1].temperature_c == 48.0
    assert with_revisit(single, 3.0)[-1].temperature_c == 42.0


def test_the_element_lags_the_sensor_by_slope_times_tau() -> None:
    res = ConditionResult("T45_V5", 45.0, 5.0)
    t = np.linspace(0.0, 10.0, 1001)
    res.note_temperature("scale", 50.0 + 0.01 * t, t)  # 0.6 C/min
    res.note_temperature("bias", np.full(11, 49.9))  # untimed: no slope
    assert res.slope_for("scale") == pytest.approx(0.01)
    assert res.temperature_for("scale") == pytest.approx(50.05)
    assert res.temperature_for("scale", 20.0) == pytest.approx(50.05 - 0.2)
    assert res.temperature_for("bias", 20.0) == pytest.approx(49.9)


def test_a_point_without_a_correction_keeps_the_records_shape() -> None:
    """A product without thermal_typical: analysis.fit.conditions[] as before (no new keys)."""
    b = ConditionMeasurement(30.0, 4.75, 0.1, 0.005, 1.0, 1e-5)
    plain = fit_point("T25_V4.75", b, b, None).model_dump(mode="json")
    assert not any(k.startswith(("hysteresis", "u_hysteresis")) for k in plain)
    corrected = fit_point("T25_V4.75", b, b, correction(1.0, 0.01, 0.004))
    assert corrected.model_dump(mode="json")["hysteresis_correction_dps"] == pytest.approx(-0.005)
