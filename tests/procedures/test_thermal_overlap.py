"""Issue 28, faster procedure options of the `thermal` step, both off by default:

- `overlap_measurement`: measure as soon as every die meets the criterion over a shorter
  span, judge the full window afterwards over the measurement, and measure a part again when
  that window fails (the first attempt kept in `analysis.measured_again`);
- `supply_change_no_wait`: no wait at a supply change at the same temperature when every
  part's predicted self-heating change meets the criterion.

The bench tests run one part on the simulated bench in lockstep (station time is physics
time, no sleeps): each option takes less station time than without it, and a window judged
afterwards that fails has the condition measured again, never silently accepted."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from procedures.analysis.stability import change_settles, judge_span
from procedures.loading.config import load_procedure
from procedures.loading.plan import build_plan
from procedures.runtime.record import RunRecord, Verdict, read_record
from procedures.steps.thermal import ThermalSettings
from reports.cert_inputs import load_inputs
from reports.cert_remeasured import remeasured
from station.sim_run import run_simulated

PROC = Path(__file__).resolve().parent / "data" / "overlap_short.yaml"
GYR130 = Path(__file__).resolve().parents[2] / "config" / "products" / "gyr130.yaml"


def _procedure(tmp: Path, thermal: dict[str, Any], supplies: list[float] | None = None,
               product: Path | None = None) -> Path:
    """overlap_short.yaml with the thermal step's settings changed."""
    data = yaml.safe_load(PROC.read_text())
    data["product"] = str(product or (PROC.parent / data["product"]).resolve())
    data["steps"][1]["steps"][0].update(thermal)
    if supplies is not None:
        data["conditions"]["supplies_v"] = supplies
    path = tmp / f"proc-{len(list(tmp.glob('proc-*')))}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _run(proc: Path, out: Path) -> RunRecord:
    return read_record(_run_folder(proc, out))


def _run_folder(proc: Path, out: Path) -> Path:
    result, _ = run_simulated([{"socket": 1, "serial": "SIM-8301"}], procedure_path=proc,
                              out=out)
    return result.folders[1]


def _measured_at(record: RunRecord, name: str, condition: str) -> int:
    return sum(1 for m in record.measurements if m.name == name and m.condition == condition)


# ------------------------------------------------------------ the pure rules


def test_a_span_is_stable_only_if_every_window_in_it_is() -> None:
    t = np.arange(0.0, 180.0, 0.01)
    flat = np.full(t.size, 25.0)
    assert judge_span(t, flat, 60, 5, 0.1, 0.2).stable
    moving = flat + np.where(t > 90, 0.3 * (1 - np.exp(-(t - 90) / 20)), 0.0)  # a late move
    v = judge_span(t, moving, 60, 5, 0.1, 0.2)
    assert not v.stable and (v.slope_c_per_min > 0.1 or v.band_c > 0.2)
    # the last window alone would have passed: the move is over by the end
    late = t >= t[-1] - 30
    assert judge_span(t[late], moving[late], 30, 5, 0.1, 0.2).stable


def test_a_predicted_change_settles_only_within_band_and_slope() -> None:
    assert change_settles(0.08, 90.0, 0.1, 0.2)  # 0.05 C/min at its start
    assert not change_settles(0.8, 90.0, 0.1, 0.2)  # 4.75 -> 5.25 V on gyr130: ~0.8 C
    assert not change_settles(0.18, 90.0, 0.1, 0.2)  # within the band, but 0.12 C/min
    assert not change_settles(float("nan"), 90.0, 0.1, 0.2)  # no C/W: not predicted


def test_the_entry_span_is_at_most_the_window() -> None:
    assert not ThermalSettings().overlap_measurement
    assert not ThermalSettings().supply_change_no_wait
    with pytest.raises(ValidationError, match="overlap_entry_s"):
        ThermalSettings(window_s=30, overlap_entry_s=40, overlap_measurement=True)
    # without the option a window shorter than the entry span's default stays valid
    assert ThermalSettings(window_s=10).window_s == 10


def test_the_plan_judges_each_condition_after_its_measurement_steps(tmp_path: Path) -> None:
    off, _ = load_procedure(_procedure(tmp_path, {}))
    assert "thermal_judged_after" not in [s.name for s in build_plan(off)]
    on, _ = load_procedure(_procedure(tmp_path, {"overlap_measurement": True}))
    plan = [(s.name, s.condition) for s in build_plan(on)]
    assert plan[1:] == [
        ("thermal", "T25_V5"), ("bias", "T25_V5"), ("rate_table", "T25_V5"),
        ("thermal_judged_after", "T25_V5"),
        ("thermal", "T25_V5.05"), ("bias", "T25_V5.05"), ("rate_table", "T25_V5.05"),
        ("thermal_judged_after", "T25_V5.05"),
    ]


# ------------------------------------------------------------ on the simulated bench


def test_overlap_takes_less_station_time_and_judges_the_window_after(tmp_path: Path) -> None:
    without = _run(_procedure(tmp_path, {}), tmp_path / "without")
    overlap = _run(_procedure(tmp_path, {"overlap_measurement": True}), tmp_path / "with")
    assert without.verdict == overlap.verdict == Verdict.PASS
    assert overlap.timings["total"] < without.timings["total"] - 30.0
    for cond, stab in overlap.analysis.stability.items():
        assert stab.judged == "after" and stab.entry_s == 20.0
        assert stab.stable is True  # judged afterwards, over the measurement
        assert stab.after_slope_c_per_min is not None
        assert abs(stab.after_slope_c_per_min) <= 0.1 and (stab.after_band_c or 1.0) <= 0.2
        assert stab.judged_until_station_s is not None and stab.measurement_start_station_s
        # the span judged covers the measurement (one full window at least)
        assert stab.judged_until_station_s - stab.measurement_start_station_s >= 60.0
        base = without.analysis.stability[cond]
        assert base.judged == "before"
        assert (stab.time_to_stability_s or 0) < (base.time_to_stability_s or 0)
    assert overlap.analysis.measured_again == []


def test_a_window_that_fails_afterwards_is_measured_again(tmp_path: Path) -> None:
    # a band tighter than the slope limit over a window: the 20 s entry span passes while
    # the die still moves more than the band over 60 s; the judgement afterwards catches it
    tight = {"overlap_measurement": True, "slope_c_per_min": 0.3, "band_c": 0.1}
    folder = _run_folder(_procedure(tmp_path, tight), tmp_path / "tight")
    rec = read_record(folder)
    assert rec.verdict == Verdict.PASS
    again = rec.analysis.measured_again
    assert [a.condition for a in again] == ["T25_V5"]
    first = again[0]
    assert first.first_stability is not None and first.first_stability.stable is False
    assert (first.first_stability.after_band_c or 0.0) > 0.1
    assert "not stable over the measurement" in first.why
    assert {m.name for m in first.first} >= {"raw_bias_dps", "raw_scale_error"}
    # the judged record holds the second attempt only, judged before it (a full window)
    assert _measured_at(rec, "raw_bias_dps", "T25_V5") == 1
    assert _measured_at(rec, "raw_scale_error", "T25_V5") == 1
    stab = rec.analysis.stability["T25_V5"]
    assert stab.judged == "before" and stab.stable is True
    assert any("T25_V5 measured again" in e.message for e in rec.events)
    assert rec.analysis.stability["T25_V5.05"].judged == "after"
    notes = [p.getPlainText() for p in remeasured(load_inputs(folder))]
    assert len(notes) == 1 and notes[0].startswith("Measured again: T25_V5: the die was not")


def test_no_wait_at_a_small_supply_change_takes_less_time(tmp_path: Path) -> None:
    without = _run(_procedure(tmp_path, {}), tmp_path / "without")
    no_wait = _run(_procedure(tmp_path, {"supply_change_no_wait": True}), tmp_path / "nw")
    assert no_wait.verdict == Verdict.PASS
    assert no_wait.timings["total"] < without.timings["total"] - 30.0
    first, change = no_wait.analysis.stability["T25_V5"], no_wait.analysis.stability["T25_V5.05"]
    assert first.judged == "before"  # power-on is not a supply change: it waits
    assert change.judged == "predicted" and change.time_to_stability_s == 0.0
    # gyr130: 40 C/W x (5.05^2 - 5^2) V^2 x 0.004 S ~ 0.08 C, within the 0.2 C band
    assert change.predicted_change_c == pytest.approx(0.08, abs=0.02)
    assert any("measured at once" in e.message for e in no_wait.events)


def test_no_wait_is_refused_when_the_change_is_beyond_the_band(tmp_path: Path) -> None:
    rec = _run(_procedure(tmp_path, {"supply_change_no_wait": True}, supplies=[4.75, 5.25]),
               tmp_path / "far")
    change = rec.analysis.stability["T25_V5.25"]
    assert change.judged == "before" and (change.time_to_stability_s or 0.0) >= 60.0
    assert any("does not meet the criterion" in e.message for e in rec.events)


def test_a_mispredicted_supply_change_is_caught_and_measured_again(tmp_path: Path) -> None:
    # the product file understates the parts' self-heating (10 C/W, they heat 40): the
    # predicted change (0.06 C for the load's mean power) meets the criterion; the real one
    # of the part drawing 20 mA (0.4 C) does not, that of the part drawing 4 mA (0.08 C) does
    product = yaml.safe_load(GYR130.read_text())
    product["self_heating_c_per_w"] = 10
    product_path = tmp_path / "gyr130-understated.yaml"
    product_path.write_text(yaml.safe_dump(product))
    both = {"overlap_measurement": True, "supply_change_no_wait": True}
    proc = _procedure(tmp_path, both, supplies=[5.0, 5.25], product=product_path)
    parts = [{"socket": 1, "serial": "SIM-8301", "supply_current_a": 0.02},
             {"socket": 2, "serial": "SIM-8302", "supply_current_a": 0.004}]
    result, _ = run_simulated(parts, procedure_path=proc, out=tmp_path / "mispredicted")
    hot, cool = (read_record(result.folders[s]) for s in (1, 2))
    assert hot.verdict == cool.verdict == Verdict.PASS
    # only the part whose window failed is measured again; the other keeps its first attempt
    assert [a.condition for a in hot.analysis.measured_again] == ["T25_V5.25"]
    assert cool.analysis.measured_again == []
    first = hot.analysis.measured_again[0].first_stability
    assert first is not None and first.judged == "after" and first.stable is False
    assert first.predicted_change_c == pytest.approx(0.06, abs=0.02)
    assert _measured_at(hot, "raw_bias_dps", "T25_V5.25") == 1
    assert hot.analysis.stability["T25_V5.25"].judged == "before"
    kept = cool.analysis.stability["T25_V5.25"]
    assert kept.judged == "after" and kept.stable is True
    assert _measured_at(cool, "raw_bias_dps", "T25_V5.25") == 1
    # the part measured again spent longer on the condition's steps than the other
    assert hot.timings["bias[T25_V5.25]"] > cool.timings["bias[T25_V5.25]"]
