"""The Fitter's caches (whitened columns per term, per-sample columns while the lag is
profiled, the library's per-record factors) make the workflow faster without changing what it
finds: on fixed seeds, the named effects, their parameters, the gaps and the floor are those
of the same workflow with every cache bypassed (each solve whitening its whole design and
building every column afresh, as before the caches)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers_model import as_trajectory
from synth_gyro import RAMPED, SHORT, generate, realistic_part

from procedures.model import library
from procedures.model.discrepancy import DiscrepancyResult, run_discrepancy
from procedures.model.fit import Fitter
from procedures.model.gyro_model import first_order_model


def _uncached(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(Fitter, "_white_columns", lambda self, key, cols: self._whiten(cols))
    monkeypatch.setattr(Fitter, "_kept_sample_columns",
                        lambda self, e, nl: self._sample_columns(e, nl))
    monkeypatch.setattr(library, "_factor_values", library._compute_factor)


def _same(a: DiscrepancyResult, b: DiscrepancyResult) -> None:
    assert a.effects_added == b.effects_added
    assert [c.effect for c in a.last_candidates] == [c.effect for c in b.last_candidates]
    for x, y in zip(a.iterations, b.iterations, strict=True):
        assert x.parameters.keys() == y.parameters.keys()
        for k in x.parameters:
            assert x.parameters[k] == pytest.approx(y.parameters[k], rel=1e-6, abs=1e-12)
        assert x.evidence["f_statistic"] == pytest.approx(y.evidence["f_statistic"], rel=1e-6)
    assert a.noise_floor_dps == pytest.approx(b.noise_floor_dps, rel=1e-9)
    assert a.gap_initial_dps == pytest.approx(b.gap_initial_dps, rel=1e-9)
    assert a.gap_final_dps == pytest.approx(b.gap_final_dps, rel=1e-6)
    assert np.allclose(a.residual_final_dps, b.residual_final_dps, rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    ("kind", "profile", "seed"),
    [("sensor_lag", SHORT, 12),  # the lag profiled: every trial tau re-filters the design
     ("bias_temperature_rate", RAMPED, 21)],  # a library term named
)
def test_caches_do_not_change_the_result(kind: str, profile, seed: int,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    traj = as_trajectory(generate(realistic_part().with_effect(kind), seed, profile))
    fast = run_discrepancy(traj, first_order_model())
    assert fast.effects_added  # something was named, so the comparison covers an iteration
    with monkeypatch.context() as m:
        _uncached(m)
        # a fresh trajectory object: nothing computed for the first one is reused
        slow = run_discrepancy(as_trajectory(generate(
            realistic_part().with_effect(kind), seed, profile)), first_order_model())
    _same(fast, slow)
