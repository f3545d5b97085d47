"""The linear programme's chamber profiles: within every limit, stable when followed, sooner
than the overshoot family, never sooner than the physics bound."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from procedures.analysis.stability import judge_stability
from procedures.thermal.chamber_profile import (
    STEP_S,
    ProfilePlan,
    plan_lp_profile,
    settle_bound_s,
)
from procedures.thermal.chamber_strategy import (
    Criterion,
    DieState,
    ThermalLimits,
    ThermalModel,
    plan_profile,
)

BENCH = ThermalModel(air_tau_s=60.0, die_tau_s=300.0, ramp_c_per_min=5.0)
CRIT = Criterion(window_s=60.0, slope_c_per_min=0.1, band_c=0.2)
LIMITS = ThermalLimits(max_overshoot_c=15.0, setpoint_high_c=85.0, max_part_c=85.0)
# (air, dies, target): power-on, a supply step up and down, a temperature change
CASES = {
    "power-on": (25.0, [DieState(25.0, 300.0, 0.0, 2.0)], 25.0),
    "supply up": (25.0, [DieState(26.64, 300.0, 1.64, 2.0)], 25.0),
    "supply down": (45.0, [DieState(47.0, 300.0, 2.0, 1.64)], 45.0),
    "25 to 45": (25.0, [DieState(27.0, 300.0, 2.0, 2.0), DieState(27.0, 380.0, 2.0, 2.4)], 45.0),
}


def follow(plan: ProfilePlan, air_c: float, dies: list[DieState], model: ThermalModel,
           seconds: float, command_every_s: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """The readings (one row per die, every 0.1 s) when the station commands the plan every
    `command_every_s` and the chamber ramps to it: an independent fine-step simulation."""
    dt = 0.1
    t = np.arange(0.0, seconds, dt)
    ramped, air = plan.ramped_c[0], air_c
    die = np.array([d.die_c - d.heat_c for d in dies])
    out = np.empty((len(dies), t.size))
    commanded = plan.setpoint_at(0.0)
    step = model.ramp_c_per_min / 60.0 * dt
    for i, now in enumerate(t):
        if i % round(command_every_s / dt) == 0:
            commanded = plan.setpoint_at(float(now))
        out[:, i] = die + np.array([d.heat_at(np.array([now]))[0] for d in dies])
        ramped += max(-step, min(step, commanded - ramped))
        air += (ramped - air) * (1.0 - math.exp(-dt / model.air_tau_s))
        die += (air - die) * (1.0 - np.exp(-dt / np.array([d.tau_s for d in dies])))
    return t, out


@pytest.mark.parametrize("name", list(CASES))
def test_following_the_profile_meets_the_criterion_from_its_settle_time_on(name: str) -> None:
    air, dies, target = CASES[name]
    plan = plan_lp_profile(BENCH, LIMITS, air, air, dies, target, CRIT)
    assert plan is not None
    t, readings = follow(plan, air, dies, BENCH, plan.settle_s + 900.0)
    for row in readings:
        for end in np.arange(plan.settle_s + STEP_S, t[-1], 20.0):
            sel = (t > end - CRIT.window_s - 1.0) & (t <= end)
            v = judge_stability(t[sel], row[sel], CRIT.window_s, CRIT.slope_c_per_min,
                                CRIT.band_c)
            assert v.stable, f"{name}: window to {end:.0f} s: {v}"
    # the profile is back at the target when measurement would start
    assert plan.setpoint_at(plan.settle_s) == pytest.approx(target)


@pytest.mark.parametrize("name", list(CASES))
def test_the_profile_never_beats_the_bound_and_beats_one_overshoot_at_a_supply_change(
    name: str,
) -> None:
    """Judged by the same criterion (no margin): at one temperature (power-on, a supply
    change) the free profile settles sooner than the best single overshoot; across a
    temperature change the overshoot may be sooner, as it lets the reading overshoot its
    final value (the station takes the sooner of the two)."""
    air, dies, target = CASES[name]
    plan = plan_lp_profile(BENCH, LIMITS, air, air, dies, target, CRIT, margin=1.0)
    grid = plan_profile(BENCH, LIMITS, air, air, dies, target, CRIT)
    assert plan is not None
    if target == air:
        assert plan.settle_s < 0.75 * grid.settle_s
    bound = max(settle_bound_s(BENCH, LIMITS, air, d, target, CRIT) for d in dies)
    assert bound <= plan.settle_s


@pytest.mark.parametrize("seed", range(5))
def test_the_profile_stays_inside_the_chamber_ramp_overshoot_and_part_limits(seed: int) -> None:
    rng = np.random.default_rng(seed)
    target = float(rng.uniform(-20.0, 80.0))
    start = float(rng.uniform(-20.0, 80.0))
    over = float(rng.uniform(0.0, 10.0))
    high = max(start, target) + float(rng.uniform(0.0, 8.0))
    low = min(start, target) - float(rng.uniform(0.0, 8.0))
    limits = ThermalLimits(setpoint_low_c=low, setpoint_high_c=high, max_overshoot_c=over,
                           max_part_c=high + 5.0, min_part_c=low - 5.0)
    dies = [DieState(start + 2.0, float(tau), 2.0, 2.5) for tau in rng.uniform(150, 450, 3)]
    plan = plan_lp_profile(BENCH, limits, start, start, dies, target, CRIT)
    assert plan is not None
    r = np.asarray(plan.ramped_c)
    assert r[0] == pytest.approx(start)
    assert np.all(np.abs(np.diff(r)) <= BENCH.ramp_c_per_min / 60.0 * STEP_S + 1e-6)
    assert np.all(r <= min(high, max(start, target) + over) + 1e-6)
    assert np.all(r >= max(low, min(start, target) - over) - 1e-6)
    assert plan.overshoot_c <= over + 1e-6
    assert low - 5.0 - 1e-6 <= plan.die_peak_c <= high + 5.0 + 1e-6


def test_no_profile_when_the_reading_must_end_beyond_the_part_maximum() -> None:
    limits = ThermalLimits(max_overshoot_c=10.0, setpoint_high_c=85.0, max_part_c=46.0)
    dies = [DieState(27.0, 300.0, 2.0, 2.0)]  # 45 C air: the reading ends at 47 C
    assert plan_lp_profile(BENCH, limits, 25.0, 25.0, dies, 45.0, CRIT) is None


def test_no_profile_without_a_reading() -> None:
    """A part whose stream has no samples yet reads nan: the station falls back, never raises."""
    silent = [DieState(math.nan, 300.0, 0.0, 2.0), DieState(25.0, 300.0, math.nan, 2.0)]
    for die in silent:
        assert plan_lp_profile(BENCH, LIMITS, 25.0, 25.0, [die], 25.0, CRIT) is None


def test_a_replan_searching_from_the_last_plan_finds_the_bisections_answer(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The hint (where the last plan would settle) changes how many solves, never the plan;
    a hint the replan confirms takes two (one where it is the first index a window allows)."""
    import procedures.thermal.chamber_profile as cp

    air, dies, target = CASES["supply up"]
    base = plan_lp_profile(BENCH, LIMITS, air, air, dies, target, CRIT)
    assert base is not None
    solves = []
    real = cp._solve
    monkeypatch.setattr(cp, "_solve", lambda *a, **k: solves.append(1) or real(*a, **k))
    for hint in (0.0, base.settle_s - 30.0, base.settle_s - STEP_S, base.settle_s,
                 base.settle_s + STEP_S, base.settle_s + 30.0, 5000.0):
        for not_after in (None, base.settle_s - STEP_S, base.settle_s + 60.0):
            plain = plan_lp_profile(BENCH, LIMITS, air, air, dies, target, CRIT,
                                    not_after_s=not_after)
            solves.clear()
            hinted = plan_lp_profile(BENCH, LIMITS, air, air, dies, target, CRIT,
                                     not_after_s=not_after, hint_s=hint)
            assert (plain is None) == (hinted is None)
            if plain is not None and hinted is not None:
                assert hinted.settle_s == plain.settle_s
                assert hinted.ramped_c == pytest.approx(plain.ramped_c, abs=1e-6)
                if hint == base.settle_s:
                    # the hint (its solution is the plan), its neighbour below (none when
                    # the hint is the first index a window allows)
                    first = round(CRIT.window_s / STEP_S)
                    assert len(solves) == (1 if hint == first * STEP_S else 2)


def test_a_stalled_solver_hands_over_and_an_undecided_programme_is_not_taken_as_feasible(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture,
) -> None:
    """HiGHS's simplex can stall on a degenerate programme (seen on a load's bound): the
    solve is limited (in iterations, then time) and the interior point method decides; when
    neither does, the programme counts as infeasible (the station falls back), with a
    warning."""
    from scipy.optimize import OptimizeResult

    import procedures.thermal.chamber_profile as cp

    air, dies, target = CASES["supply up"]
    expected = settle_bound_s(BENCH, LIMITS, air, dies[0], target, CRIT)
    real = cp.linprog
    methods: list[str] = []

    def stalling(*a: Any, method: str, options: dict[str, float], **k: Any) -> Any:
        methods.append(method)
        assert options["time_limit"] == cp.SOLVE_TIME_LIMIT_S
        assert options["maxiter"] == cp.SOLVE_MAX_ITERATIONS  # lockstep: the same plan at any load
        if method == "highs":
            return OptimizeResult(status=1, x=None, message="Time limit reached")
        return real(*a, method=method, options=options, **k)

    monkeypatch.setattr(cp, "linprog", stalling)
    assert settle_bound_s(BENCH, LIMITS, air, dies[0], target, CRIT) == expected
    assert "highs-ipm" in methods

    monkeypatch.setattr(cp, "linprog", lambda *a, **k: OptimizeResult(
        status=1, x=None, message="Time limit reached"))
    with caplog.at_level("WARNING", logger="procedures.thermal.chamber_profile"):
        assert plan_lp_profile(BENCH, LIMITS, air, air, dies, target, CRIT) is None
    assert "no solver decided" in caplog.text


def test_an_index_is_solved_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """A search whose first and last index are one (the plan to beat settles as soon as a
    window can) solves that index once, not once as each end of the search."""
    import procedures.thermal.chamber_profile as cp

    air, dies, target = CASES["supply up"]
    window_s = CRIT.window_s
    solves: list[int] = []
    real = cp._solve
    monkeypatch.setattr(cp, "_solve", lambda p, end, *a: solves.append(end) or real(p, end, *a))
    plan = plan_lp_profile(BENCH, LIMITS, air, air, dies, target, CRIT, not_after_s=window_s)
    assert plan is not None and plan.settle_s == window_s
    assert solves == [round(window_s / STEP_S)]
