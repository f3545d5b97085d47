"""The ramp's stop method and a part whose bias wanders more than the product's typical
(procedures/steps/ramp_static.py `wander_model`, ramp_stop.py `with_dwell_noise`).

On the simulated bench SIM-0002 (bias instability drawn at 23.9 deg/h, the product's
typical 15) failed stop_table_consistency@ramp_bottom with E_n 3.65 against 3.48: its stop
scale's u came from a noise model whose bias instability was the typical floor, since the
60 s static dwell's fit drops a term under 3 sigma. Its thermal terms move the bias by far
less within a 27 s record (gradient -0.0014 deg/s per C/min, hysteresis 0.014 deg/s
switching over 2 C while the element moves 0.15 C). Kept, the dwell's marginal term is an
unbiased estimate of the wander and the stop's u covers the scatter; a stop that truly
disagrees with the fitted law (a cubic scale the plateaus and the moves see differently)
still fails.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from drivers.sim.config import PartPhysicsConfig, PartSpec
from drivers.sim.gyro import PartModel
from drivers.sim.population import resolve_part
from procedures.analysis.allan import NoiseModel, analyze_allan
from procedures.analysis.consistency import per_condition_limit
from procedures.analysis.stop_method import StopMethodSettings, analyze_stop_method
from procedures.runtime.record import Verdict, read_record
from procedures.steps.ramp_static import wander_model
from procedures.steps.ramp_stop import StopAtEnd, with_dwell_noise
from station.sim_run import run_simulated

ROOT = Path(__file__).resolve().parents[2]
RAMP = ROOT / "config" / "procedures" / "eol-ramp.yaml"
FS = 100.0
TYPICAL_BI_DPS = 15.0 / 3600.0  # config/products/gyr130.yaml's default typical (15 deg/h)
# bench serials drawn with a bias instability above 21 deg/h (the population: 5-25)
WANDERING = [2, 4, 21, 23, 31, 32, 33, 44, 47, 53, 55, 57, 62, 67, 75, 87, 89, 99, 103, 106]


def moves() -> tuple[np.ndarray, np.ndarray]:
    """The ramp's stop record at 100 Hz: 5 s rest, 90 deg out in 3.5 s, 5 s rest, back,
    5 s rest (the true rate; scale 1)."""
    t = np.arange(0.0, 22.3, 1.0 / FS)
    rate = np.zeros_like(t)
    for start, sign in ((5.0, 1.0), (13.5, -1.0)):
        inside = (t >= start) & (t < start + 3.5)
        x = (t[inside] - start) / 3.5
        rate[inside] = sign * 90.0 / 3.5 * (1.0 - np.cos(2 * np.pi * x))
    return t, rate


def stop_z(serial: str, seed: int) -> tuple[float, float]:
    """One 60 s static dwell then, 30 s on, one stop record, from the bench's own noise of
    `serial` (white, three Gauss-Markov terms, rate random walk): the stop scale's error in
    units of its u with the dwell's reported model and with `wander_model`, both floored at
    the typical bias instability as the ramp floors them."""
    part = PartModel(resolve_part(PartSpec(serial=serial, socket=1)), PartPhysicsConfig(),
                     seed=seed, t_s=0.0, air_c=25.0)
    dt = 1.0 / FS
    part._noise(int(300 * FS), dt)  # the noise states settled
    dwell = part._noise(int(60 * FS), dt)
    part._noise(int(30 * FS), dt)
    t, rate = moves()
    y = rate + part._noise(t.size, dt)
    allan = analyze_allan(dwell, FS)
    out = []
    for model in (allan.noise.model, wander_model(allan)):
        r = analyze_stop_method(t, y, 90.0, 0.0, noise=model.with_floor(TYPICAL_BI_DPS),
                                settings=StopMethodSettings(full_scale_dps=250.0))
        assert r.scale is not None and r.u_scale is not None
        out.append((r.scale - 1.0) / r.u_scale)
    return out[0], out[1]


@pytest.mark.slow
def test_the_stop_u_covers_a_part_whose_bias_wanders_more_than_typical() -> None:
    """Twenty bench parts drawn above 21 deg/h, 12 records each: with the dwell's reported
    model (a marginal bias instability dropped, the typical 15 deg/h in its place) the stop
    scale's errors are ~1.17 u rms, u short; with every term the dwell shows, ~1 u."""
    zs = np.array([stop_z(f"SIM-{k:04d}", seed) for k in WANDERING for seed in range(12)])
    rms = np.sqrt(np.mean(zs**2, axis=0))
    assert rms[0] > 1.1  # the cause: u short for the parts that wander most
    assert 0.9 < rms[1] < 1.1, rms


def test_the_wander_model_keeps_the_marginal_terms_the_reported_fit_drops() -> None:
    """SIM-0002's dwells (23.9 deg/h): where the reported fit reads neither a bias
    instability nor a rate random walk (neither 3 sigma above zero), the wander model keeps
    the slow terms it estimates (the bench's Gauss-Markov wander reads as either), the white
    noise as reported; the stop's u from it is wider than from the typical floor."""
    params = resolve_part(PartSpec(serial="SIM-0002", socket=1))
    t, rate = moves()
    widened = []
    for seed in range(40):
        part = PartModel(params, PartPhysicsConfig(), seed=seed, t_s=0.0, air_c=25.0)
        part._noise(int(300 * FS), 1.0 / FS)
        allan = analyze_allan(part._noise(int(60 * FS), 1.0 / FS), FS)
        reported, kept = allan.noise.model, wander_model(allan)
        assert kept.arw_deg_per_sqrt_s == pytest.approx(reported.arw_deg_per_sqrt_s, rel=0.1)
        if reported.bias_instability_dps or reported.rrw_dps_per_sqrt_s:
            continue
        assert kept.bias_instability_dps > 0 or kept.rrw_dps_per_sqrt_s > 0
        us = [analyze_stop_method(t, rate, 90.0, 0.0, noise=m.with_floor(TYPICAL_BI_DPS)).u_scale
              for m in (reported, kept)]
        widened.append(us[1] / us[0])  # type: ignore[operator]
    assert len(widened) >= 10, "most dwells of a 24 deg/h part leave its slow terms unresolved"
    assert min(widened) > 0.99 and float(np.median(widened)) > 1.1


def stop_at_end(y: np.ndarray, t: np.ndarray) -> StopAtEnd:
    data = {"time_s": t, "rate_dps": y, "status": np.zeros(t.size, dtype=np.int64),
            "temp_c": np.full(t.size, 45.0)}
    r = analyze_stop_method(t, y, 90.0, 1e-4, noise=NoiseModel(1e-3, TYPICAL_BI_DPS))
    return StopAtEnd("top", r, 45.0, 0.0, 5.0, 100.0, data, (90.0, 1e-4))


def test_the_top_record_is_analysed_again_with_the_dwells_model() -> None:
    """The top's record, made before the static dwell, is judged with the dwell's model:
    a part that wanders twice the typical gets a wider u; without a dwell it is unchanged."""
    t, rate = moves()
    y = 1.001 * rate + np.random.default_rng(3).normal(0.0, 0.01, t.size)
    stop = stop_at_end(y, t)
    product = SimpleNamespace(bias_instability_deg_per_h=15.0, range_dps=250.0,
                              rate_random_walk_deg_per_h_per_sqrt_h=0.0)
    ctx: Any = SimpleNamespace(product=product)
    part: Any = SimpleNamespace(noise=None)
    assert with_dwell_noise(ctx, part, stop, None) is stop
    again = with_dwell_noise(ctx, part, stop, NoiseModel(1e-3, 2 * TYPICAL_BI_DPS))
    assert again.result.scale == pytest.approx(stop.result.scale, rel=1e-12)
    assert stop.result.u_scale is not None and again.result.u_scale is not None
    assert again.result.u_scale > 1.3 * stop.result.u_scale
    # a model below the floor: the typical value stands, as before
    low = with_dwell_noise(ctx, part, stop, NoiseModel(1e-3, 0.0))
    assert low.result.u_scale == pytest.approx(stop.result.u_scale, rel=1e-9)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_stop_that_truly_disagrees_with_the_fit_still_fails(tmp_path: Path) -> None:
    """A bench part whose scale grows with the cube of the rate (k3 1e-7 /(deg/s)^2,
    nonlinearity within its limit): the plateaus up to 200 deg/s fit a scale some 0.15 %
    above the one the stop's slow moves (peak 51 deg/s) see. Both ends fail by far, the u
    from the dwell's model notwithstanding, and the part is not programmed."""
    parts = [{"socket": 1, "serial": "SIM-0002",
              "effects": {"k3_cubic": {"k3_per_dps2": 1e-7}}}]
    result, _truth = run_simulated(parts, procedure_path=RAMP, out=tmp_path)
    rec = read_record(result.folders[1])
    assert rec.verdict is Verdict.FAIL
    failed = set(rec.failed_measurements)
    assert {"stop_table_consistency@ramp_top", "stop_table_consistency@ramp_bottom"} <= failed
    limit = per_condition_limit(0.001, 2)
    en = [m.value for m in rec.measurements if m.name == "stop_table_consistency"]
    # the stop below the law (measured: E_n -7.8 and -7.3)
    assert len(en) == 2 and all(v is not None and v < -1.5 * limit for v in en), en
    assert rec.analysis.programming is not None and not rec.analysis.programming.programmed
