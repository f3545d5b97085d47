"""The article's stop method inside the ramp (procedures/steps/ramp_stop.py): its
comparison with the ramp fit's scale law, the limit it is judged against, and eol-ramp on
the simulated bench in lockstep: a stop-method record at each end of the span, its scale
within U of the bench's truth there, consistent with the ramp fit; a disagreement beyond
the limit fails the part as the rate-table procedure's check does."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from procedures.analysis.consistency import per_condition_limit
from procedures.analysis.ramp_fit import RampFit
from procedures.analysis.stop_method import analyze_stop_method
from procedures.analysis.temp_supply_fit import COEFFICIENT_NAMES, FirstOrderCoefficients
from procedures.loading.config import (
    consistency_judgements,
    load_procedure,
    load_product,
    product_for_procedure,
)
from procedures.runtime.record import RunRecord, Verdict, read_record
from procedures.steps.ramp_stop import RampStopSettings, stop_vs_ramp
from station.sim_run import run_simulated

ROOT = Path(__file__).resolve().parents[2]
RAMP = ROOT / "config" / "procedures" / "eol-ramp.yaml"
GYR130 = ROOT / "config" / "products" / "gyr130.yaml"
RATE_TABLE = ROOT / "config" / "procedures" / "eol-rate-table.yaml"


def stop_record(scale: float, bias: float, seed: int = 1) -> tuple[Any, Any]:
    """A 100 Hz stop-method record: 5 s rest, 90 deg out in 3.5 s, 5 s rest, back, 5 s rest."""
    fs, move = 100.0, 3.5
    t = np.arange(0.0, 30.0, 1.0 / fs)
    rate = np.zeros_like(t)
    for start, sign in ((5.0, 1.0), (13.5, -1.0)):
        inside = (t >= start) & (t < start + move)
        x = (t[inside] - start) / move
        rate[inside] = sign * 90.0 / move * (1.0 - np.cos(2 * np.pi * x))  # integrates to 90
    noise = np.random.default_rng(seed).normal(0.0, 0.01, t.size)
    return t, scale * rate + bias + noise


def fit_with(scale: float, u_scale: float) -> RampFit:
    """A ramp fit whose scale law is `scale` (1 + 2e-4/C dT - 1e-3/V dV) about 25 C, 5 V,
    the scale's k=1 uncertainty `u_scale` and no other."""
    co = FirstOrderCoefficients(0.1, 0.0, 0.0, scale, 2e-4, -1e-3, 25.0, 5.0)
    cov = np.zeros((6, 6))
    cov[3, 3] = u_scale**2
    zero = dict.fromkeys(COEFFICIENT_NAMES, 0.0)
    return RampFit(co, zero, cov, dict(zero), 20.0, 1.0, 25.0, 0.0, 0.0, 0.0, 1.0,
                   np.zeros(3), np.zeros(3))


def test_the_stop_scale_is_compared_with_the_fitted_law_at_its_temperature_and_supply(
) -> None:
    """E_n = (stop scale - law) / sqrt(u_stop^2 + u_law^2), the law at the record's element
    temperature and supply with its own u carried through."""
    fit = fit_with(0.998, 2e-5)
    law_44 = 0.998 * (1 + 2e-4 * 19.0 - 1e-3 * (4.75 - 5.0))
    t, y = stop_record(law_44, -3.5)
    stop = analyze_stop_method(t, y, 90.0, 1e-4)
    assert stop.scale is not None and stop.u_scale is not None
    cons, law, u_law = stop_vs_ramp(stop, fit, 44.0, 4.75)
    assert law == pytest.approx(law_44, rel=1e-12)
    assert u_law == pytest.approx(2e-5 * (1 + 2e-4 * 19.0 - 1e-3 * -0.25), rel=1e-9)
    want = (stop.scale - law_44) / math.hypot(stop.u_scale, u_law)
    assert cons.normalised_difference == pytest.approx(want, rel=1e-9)
    assert abs(cons.normalised_difference) < 3.0  # the record is of this very scale
    # a part whose scale the ramp got 0.5 % wrong: far beyond any consistency limit
    off, _, _ = stop_vs_ramp(stop, fit_with(0.998 * 1.005, 2e-5), 44.0, 4.75)
    assert off.normalised_difference < -per_condition_limit(0.001, 2)


def test_the_ramps_stop_ends_count_as_consistency_judgements() -> None:
    """eol-ramp judges twice per part (top, bottom): the per-end limit is derived for two
    judgements, so a good part is rejected at the product's stated rate over both."""
    product, _ = load_product(GYR130)
    ramp, _ = load_procedure(RAMP)
    assert consistency_judgements(ramp) == 2
    assert consistency_judgements(load_procedure(RATE_TABLE)[0]) == 4  # as before
    limit = product_for_procedure(product, ramp).limits.stop_table_consistency
    assert product.consistency is not None and limit is not None
    assert limit.high == pytest.approx(per_condition_limit(product.consistency.false_reject_rate,
                                                           2))


def test_the_stop_settings_are_bounded() -> None:
    assert RampStopSettings().ends == ["top", "bottom"]
    assert RampStopSettings().record_s() == pytest.approx(5 * 3 + 3.5 * 3 + 2.0)
    for bad in ({"bias_window_s": 6.0}, {"ends": ["top", "top"]}, {"ends": []},
                {"moves_per_direction": 0}, {"stop_angle_deg": 400}, {"static_s": 0}):
        with pytest.raises(ValidationError):
            RampStopSettings.model_validate(bad)


def run(tmp_path: Path, serials: list[str], procedure: Path = RAMP,
        ) -> list[tuple[RunRecord, dict[str, Any], Path]]:
    parts = [{"socket": i + 1, "serial": s} for i, s in enumerate(serials)]
    result, truth = run_simulated(parts, procedure_path=procedure, out=tmp_path)
    return [(read_record(result.folders[s]), truth["sockets"][str(s)], result.folders[s])
            for s in sorted(result.folders)]


def true_scale(params: dict[str, float], temp_c: float, supply_v: float) -> float:
    """The bench's scale at an element temperature and supply (reference 25 C, 5 V)."""
    return params["scale"] * (1 + params["scale_temp_coeff_per_c"] * (temp_c - 25.0)
                              + params["scale_supply_coeff_per_v"] * (supply_v - 5.0))


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_eol_ramp_measures_the_stop_method_at_both_ends_within_u_of_the_truth(
        tmp_path: Path) -> None:
    """Each end's stop scale against the bench's truth at its element temperature and
    supply, in units of its u (k=1): all within 3 u and all but one within U = 2 u (the
    bias wanders within a record: SIM-7002's 19 deg/h puts its ends 1.7 and 2.5 u off),
    and the judgement against the ramp fit within the limit derived for two ends."""
    zs: list[float] = []
    for rec, truth, folder in run(tmp_path, ["SIM-7001", "SIM-7002"]):
        assert rec.verdict is Verdict.PASS, rec.reason
        section = rec.analysis.ramp_stop
        assert section is not None and [e.end for e in section.ends] == ["top", "bottom"]
        judged = {m.condition: m for m in rec.measurements
                  if m.name == "stop_table_consistency"}
        assert set(judged) == {"ramp_top", "ramp_bottom"}
        for end in section.ends:
            stop = end.stop
            assert len(stop.moves) == 2  # one move each way
            assert [math.copysign(1, m.measured_angle_deg or 0) for m in stop.moves] == [1, -1]
            assert stop.scale is not None and stop.u_scale is not None
            assert end.element_temp_c is not None and end.supply_v is not None
            # near the span's ends, the dies slow
            assert end.die_temp_c is not None and end.die_rate_c_per_min is not None
            near = 45.0 if end.end == "top" else 25.0
            assert abs(end.die_temp_c - near) < 3.0 and abs(end.die_rate_c_per_min) <= 1.0
            want = true_scale(truth["parameters"], end.element_temp_c, end.supply_v)
            zs.append(abs(stop.scale - want) / stop.u_scale)
            # the ramp fit's law there, and the judgement within the derived limit
            assert end.ramp_scale is not None and end.u_ramp_scale is not None
            assert abs(end.ramp_scale - want) <= 2 * end.u_ramp_scale + 2 * stop.u_scale
            m = judged[end.label]
            assert m.value == pytest.approx(end.normalised_difference)
            assert m.high is not None and m.low is not None and m.low <= m.value <= m.high
            assert m.high == pytest.approx(per_condition_limit(0.001, 2), rel=1e-6)
        written = json.loads((folder / "record.json").read_text())
        assert None not in written["analysis"]["ramp_stop"]["ends"][0].values()
        assert float(rec.timings["total"]) < 25 * 60
    assert len(zs) == 4 and max(zs) <= 3.0 and sum(z <= 2.0 for z in zs) >= len(zs) - 1


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_stop_scale_beyond_the_limit_fails_the_part(tmp_path: Path) -> None:
    """A limit no honest E_n meets (|E_n| <= 0.001): the part FAILs naming the ramp's ends,
    never programmed, as eol-rate-table's stop-vs-table judgement fails a part."""
    data = yaml.safe_load(GYR130.read_text(encoding="utf-8"))
    data.pop("consistency")
    data["limits"]["stop_table_consistency"] = {"low": -0.001, "high": 0.001}
    product = tmp_path / "tight.yaml"
    product.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    proc = yaml.safe_load(RAMP.read_text(encoding="utf-8"))
    proc["product"] = str(product)
    path = tmp_path / "ramp.yaml"
    path.write_text(yaml.safe_dump(proc, sort_keys=False), encoding="utf-8")
    [(rec, _truth, _folder)] = run(tmp_path / "runs", ["SIM-7001"], path)
    assert rec.verdict is Verdict.FAIL
    assert set(rec.failed_measurements) <= {"stop_table_consistency@ramp_top",
                                            "stop_table_consistency@ramp_bottom"}
    assert rec.failed_measurements
    assert rec.analysis.programming is not None and not rec.analysis.programming.programmed
