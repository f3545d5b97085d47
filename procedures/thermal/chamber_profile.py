"""Chamber setpoint profiles from a linear programme (no I/O).

The chamber and die model of procedures/thermal/chamber_strategy.py on a STEP_S grid: the ramped
setpoint moves by at most the ramp limit per step, the air follows it with `air_tau_s`, each die
follows the air with its own lag, and a part's reading is its die plus its self-heating. Every
quantity is linear in the ramp rates, so "is there a profile after which every die meets the
stability criterion from window end k on" is a linear feasibility problem.

- `settle_bound_s`: the soonest k for one die with no overshoot bound (a physics bound the
  cycle-time benchmark reports); `load_settle_bound_s`: the same for every die of a load under
  the one chamber they share.
- `plan_lp_profile`: the soonest k for several dies at once, within the overshoot bound, with
  the setpoint back at the target by k (the measurement that follows must not see the chamber
  move) and a margin on the criterion (the model is learned, not known). No reading goes
  beyond its way from now to its final value by more than band_c / 2 and its self-heating's
  change (a die turning back at a peak looks flat for a moment: the criterion would take the
  peak for stable), nor, once judged, farther from it than a die approaching straight would
  be. Among the profiles that settle by then, the one that stays closest to the target. The
  station follows it a step ahead (`ProfilePlan.setpoint_at`) and plans again as the
  readings come in.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linprog
from scipy.sparse import coo_matrix

from procedures.thermal.chamber_strategy import (
    Criterion,
    DieState,
    ThermalLimits,
    ThermalModel,
)

log = logging.getLogger(__name__)

STEP_S = 10.0  # the grid: the ramp rate is constant over a step
MAX_PLAN_STEPS = 480  # 80 min of horizon: the linear programme's size (and time) grows with it
SOLVERS = ("highs", "highs-ipm")  # HiGHS's simplex, then its interior point where it stalls
# The simplex can stall on a degenerate programme: then the next solver. The limit is in
# iterations, not seconds, so a lockstep run plans the same on a loaded machine as on an idle
# one (a load of 8 with `fastest` needs at most about 1,800; a time limit made the plans, and
# so the station minutes, depend on the machine's load); the time limit is a last resort.
SOLVE_MAX_ITERATIONS = 20_000
SOLVE_TIME_LIMIT_S = 30.0
UNDECIDED = (1, 4)  # linprog's status: iteration or time limit reached; numerical trouble
PLAN_MARGIN = 0.85  # the plan meets slope and band limits this much tighter than the step judges


@dataclass(frozen=True)
class ProfilePlan:
    """A planned profile: the chamber's ramped setpoint every STEP_S from when it was planned."""

    target_c: float
    ramped_c: tuple[float, ...]
    settle_s: float  # predicted time from the plan until every die meets the criterion
    die_peak_c: float  # the dies' predicted extreme in the direction of travel
    overshoot_c: float  # the setpoint's largest excursion outside start..target
    hold_s: float  # the profile is at the target for good from here

    def setpoint_at(self, elapsed_s: float) -> float:
        """The setpoint to command `elapsed_s` after planning: the next grid point's ramped
        setpoint (the chamber ramps to it within the step), then the target."""
        i = int(math.floor(elapsed_s / STEP_S + 1e-9)) + 1
        return self.ramped_c[i] if i < len(self.ramped_c) else self.target_c


class _Rows:
    """Sparse constraint rows collected as (row, column, value) triples."""

    def __init__(self) -> None:
        self.r: list[int] = []
        self.c: list[int] = []
        self.v: list[float] = []
        self.high: list[float] = []

    def add(self, terms: list[tuple[int, float]], high: float) -> None:
        row = len(self.high)
        for col, val in terms:
            self.r.append(row)
            self.c.append(col)
            self.v.append(val)
        self.high.append(high)

    def add_block(
        self, cols: NDArray[np.int64], vals: NDArray[np.float64], high: NDArray[np.float64]
    ) -> None:
        """Rows given as arrays shaped (..., row, term) and (..., row), in C order; terms of
        value 0 are padding."""
        n_rows = high.size
        row = len(self.high) + np.repeat(np.arange(n_rows), cols.shape[-1])
        keep = vals.ravel() != 0.0
        self.r.extend(row[keep].tolist())
        self.c.extend(cols.ravel()[keep].tolist())
        self.v.extend(vals.ravel()[keep].tolist())
        self.high.extend(high.ravel().tolist())

    def matrix(self, n_var: int) -> coo_matrix:
        return coo_matrix((self.v, (self.r, self.c)), shape=(len(self.high), n_var))


@dataclass(frozen=True)
class _Problem:
    """Everything fixed while the settle index is searched."""

    model: ThermalModel
    air_c: float
    ramped_c: float
    dies: tuple[DieState, ...]
    target_c: float
    crit: Criterion
    n: int  # steps in the horizon
    setpoint_range: tuple[float, float]
    part_range: tuple[float, float]
    near_final: bool
    back_at_target: bool  # the setpoint at the target from the settle index on

    @property
    def m(self) -> int:
        return max(int(round(self.crit.window_s / STEP_S)), 2)

    def times(self) -> NDArray[np.float64]:
        return np.arange(self.n + 1, dtype=np.float64) * STEP_S


class _Layout:
    """Column indices: ramp rates u, ramped setpoint r, air a, each die's lag part d, then
    each die's window maxima and minima, then |r - target| (the objective)."""

    def __init__(self, p: _Problem, end: int) -> None:
        n = p.n
        self.u, self.r, self.a = 0, n, 2 * n + 1
        self.d = [3 * n + 2 + j * (n + 1) for j in range(len(p.dies))]
        self.n_win = n + 1 - end
        base = 3 * n + 2 + len(p.dies) * (n + 1)
        self.hi = [base + 2 * j * self.n_win for j in range(len(p.dies))]
        self.lo = [h + self.n_win for h in self.hi]
        self.e = base + 2 * len(p.dies) * self.n_win
        self.n_var = self.e + n + 1


def _dynamics(p: _Problem, lay: _Layout) -> tuple[coo_matrix, NDArray[np.float64]]:
    """Equalities: start states, the ramp, the air's and each die's first-order lag."""
    n, eq, rhs = p.n, _Rows(), []
    ka = 1.0 - math.exp(-STEP_S / p.model.air_tau_s)
    i = np.arange(n)

    def fix(col: int, value: float) -> None:
        eq.add([(col, 1.0)], 0.0)
        rhs.append(value)

    fix(lay.r, p.ramped_c)
    fix(lay.a, p.air_c)
    # per step: the ramp (r' = r + u dt), then the air's lag behind the ramped setpoint
    ramp_c = np.stack([lay.r + i + 1, lay.r + i, lay.u + i, lay.u + i], axis=-1)
    ramp_v = np.broadcast_to(np.array([1.0, -1.0, -STEP_S, 0.0]), ramp_c.shape)
    air_c = np.stack([lay.a + i + 1, lay.a + i, lay.r + i, lay.r + i + 1], axis=-1)
    air_v = np.broadcast_to(np.array([1.0, -(1.0 - ka), -ka / 2, -ka / 2]), air_c.shape)
    eq.add_block(np.stack([ramp_c, air_c], axis=1), np.stack([ramp_v, air_v], axis=1),
                 np.zeros((n, 2)))
    rhs += [0.0] * (2 * n)
    for die, d0 in zip(p.dies, lay.d, strict=True):
        kd = 1.0 - math.exp(-STEP_S / die.tau_s)
        fix(d0, die.die_c - die.heat_c)
        lag_c = np.stack([d0 + i + 1, d0 + i, lay.a + i, lay.a + i + 1], axis=-1)
        lag_v = np.broadcast_to(np.array([1.0, -(1.0 - kd), -kd / 2, -kd / 2]), lag_c.shape)
        eq.add_block(lag_c[:, None, :], lag_v[:, None, :], np.zeros((n, 1)))
        rhs += [0.0] * n
    fix(lay.r + n, p.target_c)  # the profile ends at the target
    return eq.matrix(lay.n_var), np.asarray(rhs)


def _windows(p: _Problem, lay: _Layout, end: int, margin: float, rows: _Rows) -> None:
    """Every window ending at or after `end` meets the criterion (slope, band, tolerance).
    Per die one block: for each window its rows in a fixed order (see `_window_rows`)."""
    t = p.times()
    for die, d0, hi0, lo0 in zip(p.dies, lay.d, lay.hi, lay.lo, strict=True):
        cols, vals, high = _window_rows(p, die, d0, hi0, lo0, end, margin, t)
        rows.add_block(cols, vals, high)


def _window_rows(
    p: _Problem, die: DieState, d0: int, hi0: int, lo0: int, end: int, margin: float,
    t: NDArray[np.float64],
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """One die's window rows as (columns, values, right-hand sides), shaped (window, row,
    term) with unused terms 0: the slope's two sides, each sample within the window's maximum
    and minimum, the band, the mean's tolerance (when the criterion has one), the reading
    near its final value (when the plan asks it)."""
    m, crit = p.m, p.crit
    x = np.arange(m + 1) - m / 2.0
    w = x / float(x @ x) / STEP_S * 60.0
    heat = die.heat_at(t)
    ks = np.arange(end, p.n + 1)
    idx = ks[:, None] + np.arange(-m, 1)[None, :]  # (window, m + 1) sample indices
    win_heat = heat[idx]
    j = np.arange(ks.size)
    n_win, k1 = ks.size, m + 1
    blocks_c: list[NDArray[np.int64]] = []
    blocks_v: list[NDArray[np.float64]] = []
    blocks_h: list[NDArray[np.float64]] = []

    def block(cols: NDArray[np.int64], vals: NDArray[np.float64], high: NDArray[np.float64]
              ) -> None:  # (window, row, term) padded to m + 1 terms
        pad = k1 - cols.shape[-1]
        blocks_c.append(np.pad(cols, ((0, 0), (0, 0), (0, pad))))
        blocks_v.append(np.pad(vals, ((0, 0), (0, 0), (0, pad))))
        blocks_h.append(high)

    s0 = win_heat @ w
    slope_c = np.stack([d0 + idx, d0 + idx], axis=1)
    slope_v = np.stack([np.broadcast_to(w, idx.shape), -np.broadcast_to(w, idx.shape)], axis=1)
    block(slope_c, slope_v, np.stack([margin * crit.slope_c_per_min - s0,
                                      margin * crit.slope_c_per_min + s0], axis=1))
    # each sample: d - hi <= -heat, lo - d <= heat (alternating, sample by sample)
    hi_j, lo_j = np.broadcast_to((hi0 + j)[:, None], idx.shape), np.broadcast_to(
        (lo0 + j)[:, None], idx.shape)
    env_c = np.stack([np.stack([d0 + idx, hi_j], -1), np.stack([lo_j, d0 + idx], -1)], axis=2)
    env_v = np.broadcast_to(np.array([[1.0, -1.0], [1.0, -1.0]]), env_c.shape)
    env_h = np.stack([-win_heat, win_heat], axis=2)
    block(env_c.reshape(n_win, 2 * k1, 2), np.array(env_v).reshape(n_win, 2 * k1, 2),
          env_h.reshape(n_win, 2 * k1))
    band_c = np.stack([hi0 + j, lo0 + j], axis=-1)[:, None, :]
    block(band_c, np.broadcast_to(np.array([1.0, -1.0]), band_c.shape).copy(),
          np.full((n_win, 1), margin * crit.band_c))
    if crit.target_c is not None and crit.tolerance_c is not None:
        mean_heat = win_heat.mean(axis=1)
        avg = np.full(idx.shape, 1.0 / k1)
        block(np.stack([d0 + idx, d0 + idx], axis=1), np.stack([avg, -avg], axis=1),
              np.stack([crit.target_c + margin * crit.tolerance_c - mean_heat,
                        -(crit.target_c - margin * crit.tolerance_c - mean_heat)], axis=1))
    near = _near_final_c(p, die)
    if near is not None:
        final = die.final_c(p.target_c)
        near_c = np.stack([d0 + ks, d0 + ks], axis=1)[:, :, None]
        near_v = np.broadcast_to(np.array([1.0, -1.0])[None, :, None], near_c.shape).copy()
        block(near_c, near_v, np.stack([final + near - heat[ks], -(final - near - heat[ks])],
                                       axis=1))
    return (np.concatenate(blocks_c, axis=1), np.concatenate(blocks_v, axis=1),
            np.concatenate(blocks_h, axis=1))


def _near_final_c(p: _Problem, die: DieState) -> float | None:
    """How far from its final value a judged reading may be: band / 2 with `near_final`; for
    a plan, no farther than a die approaching straight would be when its slope meets the
    limit (slope x lag), so the profile never leaves a larger creep than the setpoint would."""
    if p.near_final:
        return p.crit.band_c / 2
    if p.back_at_target:
        return max(p.crit.slope_c_per_min * die.tau_s / 60.0, p.crit.band_c / 2)
    return None


def _bounds(p: _Problem, lay: _Layout, end: int) -> list[tuple[float | None, float | None]]:
    n, rate = p.n, p.model.ramp_c_per_min / 60.0
    bounds: list[tuple[float | None, float | None]] = [(None, None)] * lay.n_var
    for i in range(n):
        bounds[lay.u + i] = (-rate, rate)
    for i in range(n + 1):
        bounds[lay.r + i] = p.setpoint_range
        if p.back_at_target and i >= end:
            bounds[lay.r + i] = (p.target_c, p.target_c)
    t = p.times()
    half = p.crit.band_c / 2
    for die, d0 in zip(p.dies, lay.d, strict=True):
        heat = die.heat_at(t)
        final = die.final_c(p.target_c)
        low, high = p.part_range
        if p.back_at_target:  # no reading beyond its way from now to final (and its heating)
            rise = die.heat_final_c - die.heat_c
            low = max(low, min(die.die_c, final) - half + min(rise, 0.0))
            high = min(high, max(die.die_c, final) + half + max(rise, 0.0))
        for i in range(n + 1):
            bounds[d0 + i] = (low - heat[i], high - heat[i])
        bounds[d0 + n] = (
            max(final - half, p.part_range[0]) - heat[n],
            min(final + half, p.part_range[1]) - heat[n],
        )
    return bounds


def _solve(
    p: _Problem, end: int, margin: float, objective: bool
) -> NDArray[np.float64] | None:
    """The LP's solution with every window from `end` on meeting the criterion (None:
    infeasible); with `objective`, the one with the least sum of |setpoint - target|."""
    lay = _Layout(p, end)
    a_eq, b_eq = _dynamics(p, lay)
    ub = _Rows()
    _windows(p, lay, end, margin, ub)
    cost = np.zeros(lay.n_var)
    if objective:  # e >= |r - target|, for each step
        i = np.arange(p.n + 1)
        cols = np.stack([lay.r + i, lay.e + i], axis=-1)
        vals = np.array([[[1.0, -1.0], [-1.0, -1.0]]])
        high = np.tile(np.array([p.target_c, -p.target_c]), (p.n + 1, 1))
        ub.add_block(np.stack([cols, cols], axis=1), np.broadcast_to(vals, (p.n + 1, 2, 2)),
                     high)
        cost[lay.e : lay.e + p.n + 1] = 1.0
    problem = {
        "c": cost, "A_ub": ub.matrix(lay.n_var).tocsr(), "b_ub": np.asarray(ub.high),
        "A_eq": a_eq.tocsr(), "b_eq": b_eq, "bounds": _bounds(p, lay, end),
    }
    for method in SOLVERS:
        limits = {"maxiter": SOLVE_MAX_ITERATIONS, "time_limit": SOLVE_TIME_LIMIT_S}
        res = linprog(**problem, method=method, options=limits)
        if res.status not in UNDECIDED:
            return np.asarray(res.x) if res.status == 0 else None
    log.warning("chamber profile: no solver decided the linear programme (%s): taken as "
                "infeasible", res.message)
    return None


def _soonest_end(
    p: _Problem, margin: float, latest: int | None = None, hint: int | None = None,
    solutions: dict[int, NDArray[np.float64]] | None = None,
) -> int | None:
    """The first window-end index from which the LP is feasible, or None; with `latest`,
    None also when it is not feasible by then (one solve when it is not). Feasibility only
    grows with the index: a bisection, or with `hint` (the last plan's index, moved on by the
    time since) a search outwards from it in doubling steps, then a bisection: the same
    answer, and two solves when a replan confirms the last plan. With `solutions`, each
    solve also minimises the objective and keeps its solution there (the plan is then
    solved already)."""
    low, high = p.m, p.n - 1 if latest is None else max(min(latest, p.n - 1), p.m)

    answers: dict[int, bool] = {}  # each index solved once (low may be high, or the hint)

    def feasible(end: int) -> bool:
        if end not in answers:
            x = _solve(p, end, margin, solutions is not None)
            if x is not None and solutions is not None:
                solutions[end] = x
            answers[end] = x is not None
        return answers[end]

    if hint is not None and low <= hint <= high:
        low, high = _bracket(feasible, hint, low, high)
        if high < 0:
            return None
    else:
        if not feasible(high):
            return None
        if feasible(low):
            return low
    while high - low > 1:  # low not feasible, high feasible
        mid = (low + high) // 2
        if feasible(mid):
            high = mid
        else:
            low = mid
    return high


def _bracket(feasible: Callable[[int], bool], hint: int, low: int, high: int) -> tuple[int, int]:
    """(not feasible, feasible) indices around the answer, searched outwards from `hint` in
    doubling steps within low..high; (low - 1, low) when `low` itself is feasible, (_, -1)
    when not even `high` is."""
    step = 1
    if feasible(hint):
        good = hint
        while good > low:
            probe = max(good - step, low)
            if not feasible(probe):
                return probe, good
            good, step = probe, step * 2
        return low - 1, low
    bad = hint
    while bad < high:
        probe = min(bad + step, high)
        if feasible(probe):
            return bad, probe
        bad, step = probe, step * 2
    return bad, -1


def settle_bound_s(
    model: ThermalModel,
    limits: ThermalLimits,
    air_c: float,
    die: DieState,
    target_c: float,
    crit: Criterion,
    horizon_s: float | None = None,
    near_final: bool = False,
) -> float:
    """The soonest any setpoint profile within the chamber's limits (ramp rate, setpoint
    limits, the part's limits; no overshoot bound) can make the die meet the stability
    criterion for good, for this die lag and self-heating. The chamber starts settled at
    `air_c`; the profile ends at the target. The criterion alone lets the reading creep at up
    to the slope limit for good (a profile may hold the self-heating's rise off with the air,
    then creep); `near_final` also asks the reading to stay within band_c / 2 of its final
    value from the first window's end. inf: not within the horizon."""
    return load_settle_bound_s(model, limits, air_c, [die], target_c, crit, horizon_s, near_final)


def load_settle_bound_s(
    model: ThermalModel,
    limits: ThermalLimits,
    air_c: float,
    dies: list[DieState],
    target_c: float,
    crit: Criterion,
    horizon_s: float | None = None,
    near_final: bool = False,
) -> float:
    """`settle_bound_s` for a load: the soonest one profile (the parts share the chamber)
    can make every one of `dies` meet the criterion for good. Never sooner than the bound of
    any one of them; later when their self-heating or lags differ, as one setpoint cannot
    answer each die at once."""
    if not dies:
        raise ValueError("no dies to bound")
    travel_s = abs(target_c - air_c) / model.ramp_c_per_min * 60.0
    slowest_s = max(d.tau_s for d in dies)
    horizon = horizon_s or travel_s + 4.0 * slowest_s + 4.0 * model.air_tau_s + crit.window_s
    p = _Problem(
        model, air_c, air_c, tuple(dies), target_c, crit, int(math.ceil(horizon / STEP_S)),
        (limits.setpoint_low_c, limits.setpoint_high_c), (limits.min_part_c, limits.max_part_c),
        near_final, back_at_target=False,
    )
    end = _soonest_end(p, margin=1.0)
    return math.inf if end is None else float(end * STEP_S)


def planning_dies(dies: list[DieState], target_c: float) -> list[DieState]:
    """At most four dies that bound the rest (the programme's time grows faster than its
    size): the slowest and the fastest lag, the farthest to go, the largest self-heating
    change still to come; identical states once."""
    keys = (
        lambda d: d.tau_s,
        lambda d: -d.tau_s,
        lambda d: abs(d.final_c(target_c) - d.die_c),
        lambda d: abs(d.heat_final_c - d.heat_c),
    )
    picked: list[DieState] = []
    for key in keys:
        die = max(dies, key=key)
        if die not in picked:
            picked.append(die)
    return picked


def plan_lp_profile(
    model: ThermalModel,
    limits: ThermalLimits,
    air_c: float,
    ramped_c: float,
    dies: list[DieState],
    target_c: float,
    crit: Criterion,
    margin: float = PLAN_MARGIN,
    not_after_s: float | None = None,
    hint_s: float | None = None,
) -> ProfilePlan | None:
    """The profile after which the slowest of `dies` meets the criterion (tightened by
    `margin`) soonest, the setpoint within the chamber's limits and the overshoot bound of
    start..target, every die within the part's limits, the setpoint at the target from then
    on. None (the caller falls back to one overshoot) when no such profile settles within
    the horizon or by `not_after_s` (the plan to beat), when no overshoot is allowed, when a
    reading is missing (nan), or when the horizon is beyond MAX_PLAN_STEPS. `hint_s`, the
    last plan's settle time from now, is where the search starts (the same plan, sooner)."""
    if not dies:
        raise ValueError("no dies to plan for")
    if limits.max_overshoot_c <= 0:
        return None  # no room beyond start..target: nothing to shape that straight does not
    numbers = [air_c, ramped_c, target_c] + [
        v for d in dies for v in (d.die_c, d.tau_s, d.heat_c, d.heat_final_c, d.heat_tau_s)
    ]
    if not all(math.isfinite(v) for v in numbers):
        return None  # a part without a reading yet: one overshoot (or straight) plans
    dies = planning_dies(dies, target_c)
    low_c, high_c = min(ramped_c, target_c), max(ramped_c, target_c)
    setpoint_range = (
        max(limits.setpoint_low_c, low_c - limits.max_overshoot_c),
        min(limits.setpoint_high_c, high_c + limits.max_overshoot_c),
    )
    slowest = max(d.tau_s for d in dies)
    travel_s = (high_c - low_c) / model.ramp_c_per_min * 60.0
    # lags enough for the farthest die to come within band / 2 of its final value unhelped
    far = max(abs(d.final_c(target_c) - d.die_c) + abs(d.heat_final_c - d.heat_c) for d in dies)
    lags = max(4.0, math.log(max(far, crit.band_c) / (crit.band_c / 2)) + 1.0)
    horizon = travel_s + lags * slowest + 4.0 * model.air_tau_s + crit.window_s
    n = int(math.ceil(horizon / STEP_S))
    if n > MAX_PLAN_STEPS:
        return None  # a slow ramp's long travel: the straight way or one overshoot will do
    p = _Problem(
        model, air_c, ramped_c, tuple(dies), target_c, crit, n, setpoint_range,
        (limits.min_part_c, limits.max_part_c), near_final=False, back_at_target=True,
    )
    latest = None
    if not_after_s is not None and math.isfinite(not_after_s):
        latest = int(not_after_s // STEP_S)
    hint = None if hint_s is None or not math.isfinite(hint_s) else int(round(hint_s / STEP_S))
    solved: dict[int, NDArray[np.float64]] = {}
    end = _soonest_end(p, margin, latest, hint, solved)
    if end is None:
        return None
    x = solved[end]
    return _plan_of(p, _Layout(p, end), x, end, start_c=ramped_c)


def _plan_of(
    p: _Problem, lay: _Layout, x: NDArray[np.float64], end: int, start_c: float
) -> ProfilePlan:
    ramped = np.asarray(x[lay.r : lay.r + p.n + 1])
    sign = 1.0 if p.target_c >= start_c else -1.0
    t = p.times()
    readings = [x[d0 : d0 + p.n + 1] + die.heat_at(t) for die, d0 in zip(p.dies, lay.d,
                                                                         strict=True)]
    every = np.concatenate(readings)
    peak = float(every.max() if sign > 0 else every.min())
    beyond = np.maximum(ramped - max(start_c, p.target_c), min(start_c, p.target_c) - ramped)
    moving = np.nonzero(np.abs(ramped - p.target_c) > 0.05)[0]
    hold_s = float((moving[-1] + 1) * STEP_S) if moving.size else 0.0
    return ProfilePlan(
        target_c=p.target_c,
        ramped_c=tuple(float(v) for v in ramped[: end + 1]),
        settle_s=float(end * STEP_S),
        die_peak_c=peak,
        overshoot_c=float(max(beyond.max(), 0.0)),
        hold_s=hold_s,
    )
