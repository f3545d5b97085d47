"""Turn-on repeatability against synthetic truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from procedures.analysis.errors import AnalysisError
from procedures.analysis.turn_on import c4, turn_on_repeatability


def test_c4_matches_known_values() -> None:
    assert c4(2) == pytest.approx(math.sqrt(2 / math.pi), rel=1e-12)
    assert c4(10) == pytest.approx(0.9727, abs=1e-4)


def test_known_biases_give_their_sample_std() -> None:
    b = [1.0, 1.2, 0.9, 1.1, 1.3]
    r = turn_on_repeatability(b, [0.001] * 5)
    assert r.repeatability_dps == pytest.approx(float(np.std(b, ddof=1)), rel=1e-12)
    assert r.mean_bias_dps == pytest.approx(1.1)
    assert r.resolved and r.n == 5


@pytest.mark.parametrize(("n", "low", "high"), [(8, 0.87, 0.93), (40, 0.93, 0.97)])
def test_against_truth_repeatability_and_coverage(n: int, low: float, high: float) -> None:
    """sigma drawn per trial: the exact interval holds it 95 % of the time at any n; s +/- 2u
    less often with few turn-ons (the skewed chi distribution), near 95 % with many."""
    rng = np.random.default_rng(5 + n)
    trials, hits, exact = 2000, 0, 0
    for _ in range(trials):
        sigma = rng.uniform(0.01, 0.2)
        b = 0.5 + sigma * rng.standard_normal(n)
        r = turn_on_repeatability(b, np.zeros(n))
        hits += abs(r.repeatability_dps - sigma) <= 2 * r.u_repeatability_dps
        exact += r.interval_95_dps[0] <= sigma <= r.interval_95_dps[1]
    assert low <= hits / trials <= high
    assert 0.935 <= exact / trials <= 0.965


def test_noise_floor_and_excess() -> None:
    rng = np.random.default_rng(7)
    sigma, u = 0.05, 0.02
    b = sigma * rng.standard_normal(4000) + u * rng.standard_normal(4000)
    r = turn_on_repeatability(b, np.full(4000, u))
    assert r.noise_floor_dps == pytest.approx(u)
    assert r.excess_dps == pytest.approx(sigma, rel=0.05)
    quiet = turn_on_repeatability(u * rng.standard_normal(20), np.full(20, u))
    assert not quiet.resolved


@pytest.mark.parametrize(
    ("b", "u", "match"),
    [([1.0, 2.0], [0.1, 0.1], "at least 3"), ([1.0, 2.0, 3.0], [0.1, 0.1], "same length"),
     ([1.0, float("nan"), 3.0], [0.1] * 3, "finite")],
)
def test_bad_input_is_refused(b: list, u: list, match: str) -> None:
    with pytest.raises(AnalysisError, match=match):
        turn_on_repeatability(b, u)
