from __future__ import annotations

import numpy as np
import pytest

from procedures.analysis.consistency import Consistency, normalised_difference, stop_vs_rate_table
from procedures.analysis.errors import AnalysisError
from procedures.analysis.rate_table import fit_rate_table
from procedures.analysis.stop_method import analyze_stop_method
from tests.analysis.synth import raised_cosine

RATES = np.array([-250.0, -100, -20, 0, 20, 100, 250])


def test_normalised_difference_arithmetic() -> None:
    c = normalised_difference(1.0010, 0.0003, 1.0000, 0.0004)
    assert c.difference == pytest.approx(0.001)
    assert c.u_difference == pytest.approx(0.0005)
    assert c.normalised_difference == pytest.approx(2.0)
    assert c.consistent  # |E_n| <= 2
    assert not normalised_difference(1.0011, 0.0003, 1.0, 0.0004).consistent
    with pytest.raises(AnalysisError):
        normalised_difference(1.0, 0.0, 1.0, 0.0)


def _both(rng: np.random.Generator, scale_stop: float, scale_table: float) -> Consistency:
    fs = 50.0
    t = np.arange(0.0, 21.0, 1.0 / fs)
    motion = raised_cosine(t, 4.5, 3.5, 90.0) + raised_cosine(t, 12.5, 3.5, -90.0)
    y = 8.6 + scale_stop * motion + 0.1 * rng.standard_normal(t.size)
    ref = 90.0 + 0.05 * rng.standard_normal()
    stop = analyze_stop_method(t, y, ref, 0.05)
    out = scale_table * RATES + 8.6 + 0.003 * rng.standard_normal(RATES.size)
    table = fit_rate_table(RATES, np.full(RATES.size, 1e-4), out, np.full(RATES.size, 0.003),
                           250.0)
    return stop_vs_rate_table(stop, table)


def test_same_part_agrees_within_combined_uncertainty() -> None:
    rng = np.random.default_rng(0)
    z = [_both(rng, 1.0567, 1.0567).normalised_difference for _ in range(300)]
    assert 0.92 <= np.mean(np.abs(z) <= 2.0) <= 0.98  # 300 trials: sd 1.3 %
    assert abs(np.mean(z)) < 0.2


def test_a_real_scale_difference_is_flagged() -> None:
    c = _both(np.random.default_rng(1), 1.0567 * (1 + 2e-3), 1.0567)  # 0.2 % apart
    assert not c.consistent and c.normalised_difference > 3
