from __future__ import annotations

import pytest

from procedures.runtime.conditions import Condition, chamber_transitions, plan_conditions
from procedures.runtime.limits import Limit, Limits, judge, outcome_of, overall
from procedures.runtime.record import Outcome


def test_outcomes_with_marginal_band() -> None:
    lim = Limit(low=-10, high=10, marginal_low=-8, marginal_high=8)
    assert outcome_of(0.0, lim) is Outcome.PASS
    assert outcome_of(9.0, lim) is Outcome.MARGINAL
    assert outcome_of(-8.5, lim) is Outcome.MARGINAL
    assert outcome_of(10.5, lim) is Outcome.FAIL
    assert outcome_of(-10.01, lim) is Outcome.FAIL
    assert outcome_of(float("nan"), lim) is Outcome.FAIL
    assert outcome_of(None, lim) is Outcome.NOT_MEASURED
    assert outcome_of(1e9, None) is Outcome.PASS


def test_one_sided_and_bad_order() -> None:
    lim = Limit(high=2.5, marginal_high=2.0)
    assert outcome_of(-100.0, lim) is Outcome.PASS
    assert outcome_of(2.2, lim) is Outcome.MARGINAL
    with pytest.raises(ValueError):
        Limit(low=1, high=0)
    with pytest.raises(ValueError):
        Limit()


def test_judge_copies_limits_and_overall() -> None:
    limits = Limits(raw_bias_dps=Limit(low=-1, high=1, marginal_high=0.5, units="deg/s"))
    m = judge("raw_bias_dps", 0.7, limits, condition="T25_V5")
    assert (m.low, m.high, m.marginal_high, m.units) == (-1, 1, 0.5, "deg/s")
    assert m.outcome is Outcome.MARGINAL
    bad = judge("raw_bias_dps", 3.0, limits)
    ok, failed, marginal = overall([m, bad])
    assert not ok and failed == ["raw_bias_dps"] and marginal == ["raw_bias_dps@T25_V5"]


def test_plan_keeps_both_supplies_at_one_temperature() -> None:
    plan = plan_conditions([25, 45], [4.75, 5.25], start_temp_c=24.0)
    assert [c.temperature_c for c in plan] == [25, 25, 45, 45]
    # supplies alternate so consecutive temperatures share a supply level
    assert plan[1].supply_v == plan[2].supply_v
    assert chamber_transitions(plan, 25.0) == 1
    assert chamber_transitions(plan, 24.0) == 2  # the first move counts too
    worst = [Condition(25, 4.75), Condition(45, 4.75), Condition(25, 5.25), Condition(45, 5.25)]
    assert chamber_transitions(worst, 25.0) == 3


def test_plan_starts_where_chamber_is() -> None:
    plan = plan_conditions([25, 45], [4.75, 5.25], start_temp_c=44.0)
    assert plan[0] == Condition(45, 4.75) and plan[-1].temperature_c == 25
    three = plan_conditions([0, 25, 50], [5.0], start_temp_c=60)
    assert [c.temperature_c for c in three] == [50, 25, 0]
    listed = plan_conditions([45, 25], [5.0], order="as_listed", start_temp_c=25)
    assert [c.temperature_c for c in listed] == [45, 25]
    assert plan[0].name == "T45_V4.75"
