"""Bias and scale over a heating-and-cooling temperature ramp, with the lag as a regressor.

Niu et al. 2013 ("Fast thermal calibration of low-grade inertial sensors and IMUs",
Sensors 13(9):12192) calibrate on a ramp that heats and then cools, so that what the part
reads while its temperature moves (the lag of its sensing element behind its sensor, the
gradient across the die, the hysteresis between heating and cooling) cancels between the
two halves. Each plateau of the rate table is one row (its reference rate `ref`, the part's
mean output, the die SENSOR's mean temperature T and its rate Tdot, the supply V):

    out = b0 + bT dT + bV dV + g Tdot + (h/2) play
          + ref (s0 + s0 sT dT + s0 sV dV + k Tdot)

with dT = T - T0 and dV = V - V0. The sensing element lags the sensor by tau, so its
temperature is about T - tau Tdot: the scale's rate term is k = -s0 sT tau, which gives each
part's lag; the bias's rate term g mixes the gradient bias with the lag (bT tau), a nuisance
here. `play` is the hysteresis state, +1 after heating and -1 after cooling, from a play
(backlash) operator of half-width w on the sensor's temperature. One weighted least-squares
fit over every plateau, generalised: the plateaus share the part's bias wander (its bias
instability and rate random walk, procedures/analysis/bias_wander.py) as much as they are
close in time; the covariance is rescaled by the residual scatter when that is larger than
the stated uncertainties.

The rate term corrects the lag to first order. What it leaves, tau^2 Tddot in the element's
temperature, is projected onto the coefficients at the largest lag the data allow (tau + 2 u,
or the product's bound where the scale does not depend enough on temperature to tell the
lag) and added to each coefficient's U (k = 2). A lag beyond `max_tau_s` with 95 %
confidence is beyond what the ramp corrects: the fit refuses the part (RampLagTooLarge).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from procedures.analysis.bias_wander import window_mean_covariance
from procedures.analysis.element_lag import element_at_windows
from procedures.analysis.errors import AnalysisError
from procedures.analysis.temp_supply_fit import (
    COEFFICIENT_NAMES,
    FirstOrderCoefficients,
    weighted_lsq,
)

F64 = NDArray[np.float64]
PARAMS = ("b0", "bT", "bV", "g", "half_h", "s0", "a", "c", "k")
MIN_PLATEAUS = 12
MAX_PASSES = 6
TAU_SIGNIFICANCE = 3.0  # sT must be this many u from 0 for the scale to tell the lag


class RampLagTooLarge(AnalysisError):
    """The part's element lag is beyond what the ramp's rate term corrects."""


@dataclass(frozen=True)
class RampPlateaus:
    """One row per plateau; u_* are k=1, Tdot in C/s, direction-free."""

    time_s: F64
    ref_dps: F64
    u_ref_dps: F64
    out_dps: F64
    u_out_dps: F64
    temp_c: F64
    tdot_c_per_s: F64
    supply_v: F64

    @classmethod
    def of(cls, **columns: ArrayLike) -> RampPlateaus:
        arrays = {k: np.asarray(v, dtype=np.float64) for k, v in columns.items()}
        sizes = {a.size for a in arrays.values()}
        if len(sizes) != 1:
            raise AnalysisError(f"plateau columns of different lengths: {sorted(sizes)}")
        if not all(np.all(np.isfinite(a)) for a in arrays.values()):
            raise AnalysisError("a plateau holds NaN or infinite values")
        return cls(**arrays)


@dataclass(frozen=True)
class TemperatureTrack:
    """The sensor's temperature through the ramp (e.g. 1 s means), for the element's."""

    time_s: F64
    temp_c: F64


@dataclass(frozen=True)
class RampSettings:
    reference_temperature_c: float
    reference_supply_v: float
    hysteresis_width_c: float = 1.0  # the play operator's half-width w
    max_tau_s: float = 40.0  # refuse a lag beyond this (95 % confident)
    tau_bound_s: float = 35.0  # the lag assumed where the scale cannot tell it
    # the bias wander shared between plateaus (procedures/analysis/bias_wander.py)
    bias_instability_dps: float = 0.0
    rrw_dps_per_sqrt_s: float = 0.0
    plateau_s: float = 6.0  # each plateau's averaging time (its window about time_s)
    tau_prior_s: float = 20.0  # the product's typical lag (the filter's where not told)


@dataclass(frozen=True)
class RampFit:
    coefficients: FirstOrderCoefficients
    u_k1: dict[str, float]  # statistical, per COEFFICIENT_NAMES
    covariance: F64  # statistical, over COEFFICIENT_NAMES (k=1)
    lag_error: dict[str, float]  # |shift| from the uncorrected tau^2 Tddot, per name
    tau_s: float  # the element's lag (nan where the scale cannot tell it)
    u_tau_s: float
    tau_bound_s: float  # the lag the lag error was computed at
    gradient_dps_per_c_per_min: float  # g + bT tau, per C/min
    hysteresis_dps: float
    u_hysteresis_dps: float
    chi2_per_dof: float
    residual_dps: F64
    play: F64

    def uncertainty_k2(self, name: str) -> float:
        """2 u plus the lag-correction error (a bound, added linearly)."""
        return 2.0 * self.u_k1[name] + self.lag_error[name]


def law_uncertainties(fit: RampFit, temp_c: float, supply_v: float) -> tuple[float, float]:
    """k=1 uncertainties of the fitted bias and scale laws at (temp_c, supply_v): the
    coefficients' covariance through the laws, plus half the lag-correction error."""
    co = fit.coefficients
    dt = temp_c - co.reference_temperature_c
    dv = supply_v - co.reference_supply_v
    jb = np.array([1.0, dt, dv, 0.0, 0.0, 0.0])
    js = np.array([0.0, 0.0, 0.0, 1.0 + co.scale_temp_coeff_per_c * dt
                   + co.scale_supply_coeff_per_v * dv, co.scale * dt, co.scale * dv])
    lag = np.array([fit.lag_error[n] for n in COEFFICIENT_NAMES])
    out = []
    for j in (jb, js):
        out.append(math.sqrt(float(j @ fit.covariance @ j)) + 0.5 * float(np.abs(j) @ lag))
    return out[0], out[1]


def play_state(temp_c: F64, width_c: float, start: float = 0.0) -> F64:
    """Hysteresis state in [-1, 1] from a play operator of half-width `width_c`: +1 once
    heated by 2 w since the last reversal, -1 once cooled by 2 w; `start` at the first
    sample (the ramp's first plateau follows the self-heating rise since power-on: +1)."""
    y = float(temp_c[0]) - start * width_c
    out = np.empty_like(temp_c)
    for i, t in enumerate(temp_c):
        y = min(max(y, float(t) - width_c), float(t) + width_c)
        out[i] = (float(t) - y) / width_c
    return out


def second_derivative(time_s: F64, tdot: F64) -> F64:
    """d(Tdot)/dt at each plateau (central differences over the plateau times)."""
    if time_s.size < 3:
        return np.zeros_like(tdot)
    return np.asarray(np.gradient(tdot, time_s), dtype=np.float64)


def design(p: RampPlateaus, s: RampSettings, play: F64) -> F64:
    dt = p.temp_c - s.reference_temperature_c
    dv = p.supply_v - s.reference_supply_v
    r = p.ref_dps
    one = np.ones_like(dt)
    return np.column_stack(
        [one, dt, dv, p.tdot_c_per_s, play, r, r * dt, r * dv, r * p.tdot_c_per_s]
    )


def _check_design(p: RampPlateaus) -> None:
    if p.time_s.size < MIN_PLATEAUS:
        raise AnalysisError(
            f"{p.time_s.size} plateaus; the ramp fit needs at least {MIN_PLATEAUS}"
        )
    if np.ptp(p.supply_v) < 0.05:
        raise AnalysisError("the supply did not alternate: the ramp cannot fit the supply terms")
    if not (np.any(p.tdot_c_per_s > 0) and np.any(p.tdot_c_per_s < 0)):
        raise AnalysisError(
            "the die did not both heat and cool: the ramp's two halves are what cancel "
            "the lag; run the ramp up and down"
        )


def noise_covariance(p: RampPlateaus, s: RampSettings, scale_guess: float) -> F64:
    """Each plateau's own noise and the reference's, plus the bias wander the plateaus
    share (close in time: most of it), so that the fit neither averages the wander away
    nor understates the bias terms' uncertainty."""
    white = p.u_out_dps**2 + (scale_guess * p.u_ref_dps) ** 2
    cov = np.diag(white)
    if s.bias_instability_dps > 0 or s.rrw_dps_per_sqrt_s > 0:
        half = 0.5 * s.plateau_s
        cov = cov + window_mean_covariance(p.time_s - half, p.time_s + half,
                                           s.bias_instability_dps, s.rrw_dps_per_sqrt_s)
    return np.asarray(cov, dtype=np.float64)


def _solve(x: F64, p: RampPlateaus, cov_y: F64) -> tuple[F64, F64, F64, float]:
    """Generalised least squares under `cov_y`: parameters, covariance (rescaled by the
    scatter when larger), residuals, chi2/dof."""
    chol = np.linalg.cholesky(cov_y)
    xw = np.linalg.solve(chol, x)
    yw = np.linalg.solve(chol, p.out_dps)
    par, cov, chi2 = weighted_lsq(
        xw, yw, np.ones_like(yw), 1e14,
        "the ramp's plateaus do not separate temperature, supply and rate: widen the span, "
        "alternate the supply, use rates of both signs",
    )
    dof = max(x.shape[0] - x.shape[1], 1)
    red = chi2 / dof
    return par, cov * max(1.0, red), p.out_dps - x @ par, red


def _to_coefficients(par: F64, cov: F64) -> tuple[F64, F64]:
    """(b0, bT, bV, s0, sT, sV, tau) and their covariance, through the Jacobian."""
    b0, bt, bv, _, _, s0, a, c, k = (float(v) for v in par)
    vals = np.array([b0, bt, bv, s0, a / s0, c / s0, -k / a if a else math.nan])
    j = np.zeros((7, 9))
    j[0, 0] = j[1, 1] = j[2, 2] = j[3, 5] = 1.0
    j[4, 5], j[4, 6] = -a / s0**2, 1.0 / s0
    j[5, 5], j[5, 7] = -c / s0**2, 1.0 / s0
    if a:
        j[6, 6], j[6, 8] = k / a**2, -1.0 / a
    return vals, j @ cov @ j.T


def _lag_shift(x: F64, p: RampPlateaus, par: F64, tau_s: float, cov_y: F64) -> F64:
    """The coefficients' shift from what the rate term leaves: the element at T - tau Tdot
    + tau^2 Tddot, the gradient on the element's rate Tdot - tau Tddot."""
    tdd = second_derivative(p.time_s, p.tdot_c_per_s)
    bt, g, a = float(par[1]), float(par[3]), float(par[6])
    missing = (bt + a * p.ref_dps) * tau_s**2 * tdd + g * tau_s * tdd
    w = np.linalg.inv(cov_y)
    shift = np.linalg.solve(x.T @ w @ x, x.T @ (w @ missing))
    vals, _ = _to_coefficients(par + shift, np.zeros((9, 9)))
    base, _ = _to_coefficients(par, np.zeros((9, 9)))
    return np.abs(vals[:6] - base[:6])


def _tau(vals: F64, cov: F64, s: RampSettings, filtered_s: float
         ) -> tuple[float, float, float]:
    """(tau, u_tau, the lag the lag error is computed at); RampLagTooLarge beyond max.
    `filtered_s`: the lag the temperatures were already carried through; the rate term
    gives the rest."""
    st, u_st = float(vals[4]), math.sqrt(float(cov[4, 4]))
    if abs(st) < TAU_SIGNIFICANCE * u_st:
        return math.nan, math.nan, max(s.tau_bound_s, filtered_s)
    tau, u_tau = filtered_s + float(vals[6]), math.sqrt(float(cov[6, 6]))
    if tau - 2.0 * u_tau > s.max_tau_s:
        raise RampLagTooLarge(
            f"the sensing element lags the temperature sensor by {tau:.0f} +/- "
            f"{2 * u_tau:.0f} s (k=2), beyond the {s.max_tau_s:g} s the ramp's rate term "
            "corrects: its coefficients would be wrong; refused (check the part's "
            "die attach, or calibrate it at stable temperatures)"
        )
    return tau, u_tau, max(tau + 2.0 * u_tau, 0.0)


def on_element(p: RampPlateaus, track: TemperatureTrack, tau_s: float, half_s: float
               ) -> RampPlateaus:
    """The plateaus with the element's temperature and rate (lag tau) for the sensor's."""
    temps, rates = element_at_windows(track.time_s, track.temp_c, tau_s, p.time_s, half_s)
    return RampPlateaus(p.time_s, p.ref_dps, p.u_ref_dps, p.out_dps, p.u_out_dps, temps,
                        rates, p.supply_v)


@dataclass(frozen=True)
class _Pass:
    q: RampPlateaus
    play: F64
    x: F64
    par: F64
    cov: F64
    resid: F64
    red: float
    vals: F64
    vcov: F64


def _one_pass(p: RampPlateaus, s: RampSettings, track: TemperatureTrack | None,
              filtered_s: float, cov_y: F64) -> _Pass:
    q = p if track is None else on_element(p, track, filtered_s, 0.5 * s.plateau_s)
    play = play_state(q.temp_c, s.hysteresis_width_c, float(np.sign(q.tdot_c_per_s[0])))
    x = design(q, s, play)
    par, cov, resid, red = _solve(x, q, cov_y)
    if par[5] <= 0:
        raise AnalysisError("the fitted scale is not positive: check the part's orientation")
    vals, vcov = _to_coefficients(par, cov)
    return _Pass(q, play, x, par, cov, resid, red, vals, vcov)


def _iterate(p: RampPlateaus, s: RampSettings, track: TemperatureTrack | None,
             cov_y: F64) -> tuple[_Pass, float]:
    """With a track: carry the temperatures through the lag the rate term tells, until
    it tells no more (at most MAX_PASSES); returns the last pass and the lag filtered."""
    filtered = 0.0
    fit = _one_pass(p, s, None, 0.0, cov_y)
    if track is None:
        return fit, filtered
    for _ in range(MAX_PASSES):
        tau, _, _ = _tau(fit.vals, fit.vcov, s, filtered)
        nxt = s.tau_prior_s if math.isnan(tau) else min(max(tau, 0.0), 3.0 * s.max_tau_s)
        if abs(nxt - filtered) < 0.05:
            break
        filtered = nxt
        fit = _one_pass(p, s, track, filtered, cov_y)
    return fit, filtered


def fit_ramp(p: RampPlateaus, s: RampSettings, track: TemperatureTrack | None = None
             ) -> RampFit:
    """The first-order calibration from a ramp's plateaus (see the module docstring);
    with the sensor's `track`, the temperatures are carried through the part's own lag."""
    _check_design(p)
    guess = float(np.median(np.abs(p.out_dps) / np.maximum(np.abs(p.ref_dps), 1e-9)))
    cov_y = noise_covariance(p, s, guess)
    f, filtered = _iterate(p, s, track, cov_y)
    tau, u_tau, bound = _tau(f.vals, f.vcov, s, filtered)
    lag = _lag_shift(f.x, f.q, f.par, abs(bound - filtered), cov_y)
    coeffs = FirstOrderCoefficients(
        **{n: float(f.vals[i]) for i, n in enumerate(COEFFICIENT_NAMES)},
        reference_temperature_c=s.reference_temperature_c,
        reference_supply_v=s.reference_supply_v,
    )
    rest = 0.0 if math.isnan(tau) else tau - filtered
    return RampFit(
        coefficients=coeffs,
        u_k1={n: math.sqrt(float(f.vcov[i, i])) for i, n in enumerate(COEFFICIENT_NAMES)},
        covariance=np.asarray(f.vcov[:6, :6], dtype=np.float64),
        lag_error={n: float(lag[i]) for i, n in enumerate(COEFFICIENT_NAMES)},
        tau_s=tau,
        u_tau_s=u_tau,
        tau_bound_s=bound,
        gradient_dps_per_c_per_min=(float(f.par[3]) + float(f.par[1]) * rest) / 60.0,
        hysteresis_dps=2.0 * float(f.par[4]),
        u_hysteresis_dps=2.0 * math.sqrt(float(f.cov[4, 4])),
        chi2_per_dof=f.red,
        residual_dps=f.resid,
        play=f.play,
    )
