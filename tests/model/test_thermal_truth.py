"""tests/model/thermal_truth.py, the bench's truth as a folder shows it (issue 29): the
element's temperature it evaluates the effects on, and the threshold of an expected effect."""

from __future__ import annotations

import math

import numpy as np
import thermal_truth as tt
from scipy import stats

from procedures.model.trajectory import Segment, Trajectory


def _ramp(rate_c_per_s: float) -> Trajectory:
    t = np.arange(0.0, 300.0, 0.1)
    t = t[(t % 60.0) < 56.0]  # gaps: the die goes on through them
    n = t.size
    return Trajectory(time_s=t, gyro_dps=np.zeros(n), ref_rate_dps=np.full(n, 10.0),
                      ref_angle_deg=np.zeros(n), temp_c=25.0 + rate_c_per_s * t,
                      supply_v=np.full(n, 5.0), time_since_power_on_s=t,
                      segments=(Segment("transition", 0.0, 300.0),))


def test_the_element_trails_a_ramp_by_tau_times_its_rate_from_power_on() -> None:
    traj = _ramp(0.05)
    element = tt.element_temperature(traj, 20.0)
    expected = traj.temp_c - 0.05 * 20.0 * -np.expm1(-traj.time_s / 20.0)
    assert np.allclose(element, expected, atol=1e-9)
    assert np.array_equal(tt.element_temperature(traj, 0.0), traj.temp_c)


def test_the_lag_of_a_scale_law_is_w_times_how_far_the_element_trails() -> None:
    traj = _ramp(0.05)
    part = tt.PartTruth(20.0, 0.0, 0.0, 1.0, 0.0, 1.0, -2e-4)
    effects = {name: (regs, signal) for name, regs, signal in tt.signals(traj, part)}
    regs, signal = effects["lag (scale)"]
    assert regs == ("rate", "temperature_rate")
    assert math.isclose(signal[-1], 10.0 * -2e-4 * -1.0, rel_tol=1e-6)  # 1 C behind
    assert not np.any(effects["rate bias"][1])  # no bias law, no gradient
    assert "hysteresis" not in effects


def test_the_threshold_is_power_at_the_strictest_holm_step() -> None:
    """z* for 35 library terms at alpha 0.01, share 0.1: chi^2_1 beyond 17.5, 90 % power."""
    crit = stats.chi2.isf(0.01 * 0.1 / 35, 1)
    z = tt.threshold_z(0.01, 35)
    assert math.isclose(stats.ncx2.sf(crit, 1, z**2), tt.POWER, rel_tol=1e-6)
    assert 5.4 < z < 5.5 and tt.threshold_z(0.01, 70) > z
