"""The article's stop method: integrate the bias-corrected rate over moves between two stops.

Steps (reference/METHOD.md): find the static and moving parts of the record by hysteresis on
the bias-corrected rate; take the bias from the first static window; integrate each move from
before the motion starts to after it stops (margins), so that a bounce at the stop is inside
the integral; scale correction = reference angle / measured angle for each move, and their
mean. A move holding an over-range or saturated sample gets no scale.

Uncertainty of each correction and of the mean combines, with their correlations: the error
of each bias-corrected angle (the noise integrated over the move minus the move's time x the
bias window's mean noise), and the reference angle's own uncertainty (common to all moves).
The angle errors' covariance comes from the noise model (`angle_error_covariance`): for white
noise it is the noise over each move plus the bias uncertainty x time (common to all moves,
cancelling to first order between an out and a back move); bias instability and rate random
walk add the bias's drift between its window and each move, which grows with their distance
and does not cancel. A noise model from the bias window alone cannot see that drift (the
window is a few seconds long): pass the part's own model from a longer record (`noise`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import chi2 as chi2_dist

from drivers.protocols import SampleStatus
from procedures.analysis._checks import finite_1d, monotonic_time, non_negative, positive
from procedures.analysis.allan import FLICKER_AVAR_FACTOR, NoiseModel
from procedures.analysis.bias import BiasEstimate, estimate_bias
from procedures.analysis.errors import AnalysisError

CLIP_BITS = int(SampleStatus.OVER_RANGE | SampleStatus.SATURATED)
MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class StopMethodSettings:
    """Detection settings; the defaults suit 50-1000 Hz records of 90 deg moves in 2-5 s."""

    enter_sigma: float = 8.0  # a move is declared where |rate - bias| exceeds this many sigma
    leave_sigma: float = 3.0  # ... and extends until it falls below this many sigma
    min_enter_dps: float = 1.0  # floors for quantised, nearly noise-free records
    min_leave_dps: float = 0.2
    min_static_s: float = 0.5  # a pause shorter than this (a bounce) does not end a move
    margin_s: float = 0.25  # integration starts this long before the motion, ends after it
    min_bias_window_s: float = 1.0
    min_move_fraction: float = 0.2  # |angle| below this x reference: a disturbance, not a move
    full_scale_dps: float | None = None  # samples beyond it are over-range even if unflagged
    # relative allowance per move in the consistency check between moves: a real part's scale
    # differs a little between directions and rates (asymmetry, nonlinearity: 0.01-0.1 % of
    # full scale, the article's 0.946 vs 0.944), which the noise-only uncertainties leave out
    move_tolerance: float = 0.005
    # a record that begins in the tail of an earlier motion (the station cuts its window by
    # mapping station time to the fixture's clock, an estimate that can start the window a
    # little early) is used from the end of that motion instead of being refused
    trim_leading_motion: bool = False


@dataclass(frozen=True)
class StopMove:
    """One move between the stops; u_* are standard (k=1) uncertainties."""

    start_s: float
    end_s: float
    measured_angle_deg: float
    u_measured_angle_deg: float  # noise, bias and the bias's drift; not the reference
    direction: int  # +1 or -1, the sign of the measured angle
    peak_rate_dps: float
    n_over_range: int
    complete: bool  # False when the record starts or ends inside the move
    scale_correction: float | None  # None when clipped or incomplete: refused
    u_scale_correction: float | None

    @property
    def clipped(self) -> bool:
        return self.n_over_range > 0

    @property
    def usable(self) -> bool:
        return self.scale_correction is not None

    def require_scale_correction(self) -> float:
        """This move's scale correction, or an AnalysisError saying why it has none."""
        if self.scale_correction is None:
            why = "it has over-range samples" if self.clipped else "the record cuts it off"
            raise AnalysisError(
                f"the move at {self.start_s:.3g}-{self.end_s:.3g} s gives no scale: {why}"
            )
        return self.scale_correction


@dataclass(frozen=True)
class StopMethodResult:
    bias: BiasEstimate
    moves: tuple[StopMove, ...]
    static_segments_s: tuple[tuple[float, float], ...]
    scale_correction: float | None  # mean over usable moves; None if there is none
    u_scale_correction: float | None  # k=1, correlations between moves included
    reference_angle_deg: float
    u_reference_angle_deg: float
    noise_sigma_dps: float
    n_over_range: int
    warnings: tuple[str, ...] = field(default=())
    over_range_intervals_s: tuple[tuple[float, float], ...] = field(default=())  # flagged spans
    # consistency of the usable moves' corrections against their (angle) uncertainties:
    # chi-square with n-1 degrees of freedom; None with fewer than two usable moves
    moves_chi2: float | None = None
    moves_dof: int = 0
    birge_ratio: float | None = None  # sqrt(chi2 / dof)
    moves_consistent: bool | None = None  # False: u_scale_correction widened by birge_ratio

    @property
    def bias_dps(self) -> float:
        return self.bias.bias_dps

    @property
    def bias_correction_dps(self) -> float:
        return self.bias.bias_correction_dps

    @property
    def scale(self) -> float | None:
        return None if self.scale_correction is None else 1.0 / self.scale_correction

    @property
    def u_scale(self) -> float | None:
        if self.scale_correction is None or self.u_scale_correction is None:
            return None
        return self.u_scale_correction / self.scale_correction**2

    @property
    def u_scale_correction_k2(self) -> float | None:
        return None if self.u_scale_correction is None else 2.0 * self.u_scale_correction

    def require_scale_correction(self) -> float:
        """The mean scale correction, or an AnalysisError saying why there is none."""
        if self.scale_correction is None:
            reasons = "; ".join(self.warnings) or "no move found"
            raise AnalysisError(f"stop method gives no scale correction: {reasons}")
        return self.scale_correction


def detect_moves(
    time_s: NDArray[np.float64],
    rate_dps: NDArray[np.float64],
    settings: StopMethodSettings,
) -> tuple[list[tuple[int, int]], float, float]:
    """Index ranges [i0, i1] of the moves, margins included, plus the bias and sigma used."""
    # noise from sample-to-sample steps: smooth motion barely moves their median
    steps = np.diff(rate_dps)
    sigma = MAD_TO_SIGMA * float(np.median(np.abs(steps - np.median(steps)))) / math.sqrt(2.0)
    bias = _static_level(rate_dps, max(sigma, settings.min_leave_dps))
    e_all = rate_dps - bias
    for _ in range(3):  # static level and noise from the samples that are clearly static
        enter = max(settings.enter_sigma * sigma, settings.min_enter_dps)
        static = np.abs(e_all) < enter
        if static.sum() < 3:
            break
        bias = float(np.median(rate_dps[static]))
        e_all = rate_dps - bias
        dev = np.abs(e_all[np.abs(e_all) < enter])
        sigma = MAD_TO_SIGMA * float(np.median(dev)) if dev.size else sigma
    enter = max(settings.enter_sigma * sigma, settings.min_enter_dps)
    leave = max(settings.leave_sigma * sigma, settings.min_leave_dps)

    active = np.abs(e_all) >= leave
    runs = _runs(active)
    strong = np.abs(e_all) >= enter
    runs = [(a, b) for a, b in runs if strong[a : b + 1].any()]
    merged: list[tuple[int, int]] = []
    for a, b in runs:
        if merged and time_s[a] - time_s[merged[-1][1]] < settings.min_static_s:
            merged[-1] = (merged[-1][0], b)
        else:
            merged.append((a, b))
    out: list[tuple[int, int]] = []
    n = time_s.size
    for k, (a, b) in enumerate(merged):
        lo_t = time_s[a] - settings.margin_s
        hi_t = time_s[b] + settings.margin_s
        if k > 0:  # never reach past half-way to a neighbour
            lo_t = max(lo_t, 0.5 * (time_s[merged[k - 1][1]] + time_s[a]))
        if k + 1 < len(merged):
            hi_t = min(hi_t, 0.5 * (time_s[b] + time_s[merged[k + 1][0]]))
        i0 = int(np.searchsorted(time_s, lo_t, side="left"))
        i1 = int(np.searchsorted(time_s, hi_t, side="right")) - 1
        out.append((max(i0, 0), min(i1, n - 1)))
    return out, bias, sigma


def _static_level(rate_dps: NDArray[np.float64], sigma: float) -> float:
    """The most populated level of the record: at rest the output clusters within a few
    sigma, while moves spread over the range, so this holds even when moves fill most of it."""
    lo, hi = float(rate_dps.min()), float(rate_dps.max())
    n_bins = int(min(max((hi - lo) / (2.0 * sigma), 1), 20_000))
    counts, edges = np.histogram(rate_dps, bins=n_bins)
    k = int(np.argmax(counts))
    return 0.5 * float(edges[k] + edges[k + 1])


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(padded)
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1) - 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


def analyze_stop_method(
    time_s: ArrayLike,
    rate_dps: ArrayLike,
    reference_angle_deg: float = 90.0,
    u_reference_angle_deg: float = 0.0,
    status: ArrayLike | None = None,
    settings: StopMethodSettings | None = None,
    noise: NoiseModel | None = None,
) -> StopMethodResult:
    """Bias and scale correction from a stop-method record (time, rate and optional status).

    `noise` is the part's noise model from a longer static record; without it the model is
    fitted to the leading rest alone, which sees white noise only (see the module notes).
    """
    cfg = settings or StopMethodSettings()
    t, y = _record(time_s, rate_dps)
    ref = positive(reference_angle_deg, "reference_angle_deg")
    u_ref = non_negative(u_reference_angle_deg, "u_reference_angle_deg")
    rec = _locate_moves(t, y, _clip_mask(y, status, cfg.full_scale_dps), cfg)
    t, y, clip = rec.t, rec.y, rec.clip
    fs = (t.size - 1) / (t[-1] - t[0])
    bias = estimate_bias(y[: rec.first], fs, noise)
    bias_window = (float(t[0]), float(t[rec.first]))  # first samples, one period each

    warnings: list[str] = []
    if rec.trimmed_s:
        warnings.append(
            f"the record began in motion: its first {rec.trimmed_s:.3g} s (up to the end of "
            "that motion) were left out"
        )
    meter = _MoveMeter(t, y, clip, bias, ref, u_ref, warnings)
    moves, usable, cov = meter.measure(rec.ranges, bias_window, cfg.min_move_fraction)
    mean_corr, u_mean = _mean_correction(usable, ref, u_ref, cov)
    if mean_corr is None:
        warnings.append("no usable move: no scale correction")
    chi2, dof, birge, consistent = _move_consistency(usable, ref, cov, cfg.move_tolerance)
    if consistent is False and u_mean is not None and birge is not None:
        warnings.append(_disagreement(usable, ref, cfg.move_tolerance, chi2, dof, birge))
        u_mean *= birge
    return StopMethodResult(
        bias=bias,
        moves=tuple(moves),
        static_segments_s=_static_segments(t, [(m.start_s, m.end_s) for m in moves]),
        scale_correction=mean_corr,
        u_scale_correction=u_mean,
        reference_angle_deg=ref,
        u_reference_angle_deg=u_ref,
        noise_sigma_dps=rec.sigma,
        n_over_range=int(clip.sum()),
        warnings=tuple(warnings),
        over_range_intervals_s=tuple((float(t[a]), float(t[b])) for a, b in _runs(clip)),
        moves_chi2=chi2,
        moves_dof=dof,
        birge_ratio=birge,
        moves_consistent=consistent,
    )


def _record(
    time_s: ArrayLike, rate_dps: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The time and rate columns, checked: finite, as long as each other, time increasing."""
    t = finite_1d(time_s, "time_s", 16)
    y = finite_1d(rate_dps, "rate_dps", 16)
    if t.size != y.size:
        raise AnalysisError(f"time_s has {t.size} samples but rate_dps has {y.size}")
    monotonic_time(t)
    return t, y


class _Located(NamedTuple):
    """The record the moves were found in (cut after a leading motion), and the moves."""

    t: NDArray[np.float64]
    y: NDArray[np.float64]
    clip: NDArray[np.bool_]
    ranges: list[tuple[int, int]]
    sigma: float
    first: int  # index of the first move's start: the rest before it gives the bias
    trimmed_s: float  # how much of a leading motion was cut off (0: none)


def _locate_moves(
    t: NDArray[np.float64],
    y: NDArray[np.float64],
    clip: NDArray[np.bool_],
    cfg: StopMethodSettings,
) -> _Located:
    """The moves, after a rest at the first stop long enough for the bias; a leading motion
    cut off first when the settings allow it."""
    ranges, _, sigma = detect_moves(t, y, cfg)
    if not ranges:
        raise AnalysisError(
            "no move found in the record: the rate never left the static noise band; "
            "check that the part was rotated between the stops while sampling"
        )
    trimmed_s = 0.0
    first = ranges[0][0]
    if cfg.trim_leading_motion and (first == 0 or t[first] - t[0] < cfg.min_bias_window_s):
        cut = ranges[0][1] + 1
        if len(ranges) > 1 and t.size - cut >= 16:
            trimmed_s = float(t[cut] - t[0])
            t, y, clip = t[cut:], y[cut:], clip[cut:]
            ranges, _, sigma = detect_moves(t, y, cfg)
            if not ranges:
                raise AnalysisError("no move found after the motion the record began with")
            first = ranges[0][0]
    if first == 0 or t[first] - t[0] < cfg.min_bias_window_s:
        raise AnalysisError(
            f"the record must start with at least {cfg.min_bias_window_s:g} s at rest at the "
            f"first stop (found {t[first] - t[0]:.3g} s before the first move): "
            "start sampling, wait 5 s, then rotate"
        )
    return _Located(t, y, clip, ranges, sigma, first, trimmed_s)


class _MoveMeter:
    """Each move's bias-corrected angle, its uncertainty and scale correction; what it
    refuses or ignores goes to `warnings`."""

    def __init__(
        self,
        t: NDArray[np.float64],
        y: NDArray[np.float64],
        clip: NDArray[np.bool_],
        bias: BiasEstimate,
        ref: float,
        u_ref: float,
        warnings: list[str],
    ) -> None:
        self.t, self.y, self.clip = t, y, clip
        self.bias, self.ref, self.u_ref = bias, ref, u_ref
        self.warnings = warnings

    def measure(
        self,
        ranges: list[tuple[int, int]],
        bias_window: tuple[float, float],
        min_move_fraction: float,
    ) -> tuple[list[StopMove], list[tuple[int, float]], NDArray[np.float64]]:
        """The moves, the usable ones as (index into the covariance, angle), and the angle
        errors' covariance of the moves kept (disturbances too small to be moves left out)."""
        t, ref = self.t, self.ref
        angles = [
            (i0, i1, float(np.trapezoid(self.y[i0 : i1 + 1] - self.bias.bias_dps,
                                        t[i0 : i1 + 1])))
            for i0, i1 in ranges
        ]
        kept = [m for m in angles if abs(m[2]) >= min_move_fraction * ref]
        cov = angle_error_covariance(
            self.bias.noise, bias_window, [(float(t[i0]), float(t[i1])) for i0, i1, _ in kept]
        )
        moves: list[StopMove] = []
        usable: list[tuple[int, float]] = []
        for i0, i1, angle in angles:
            if abs(angle) < min_move_fraction * ref:
                self.warnings.append(
                    f"ignored a disturbance of {angle:.3g} deg at {t[i0]:.3g}-{t[i1]:.3g} s "
                    "(too small to be a move between the stops)"
                )
                continue
            j = len(moves)
            moves.append(self._move(i0, i1, angle, math.sqrt(float(cov[j, j]))))
            if moves[-1].usable:
                usable.append((j, angle))
        return moves, usable, cov

    def _move(self, i0: int, i1: int, angle: float, u_angle: float) -> StopMove:
        t, ref = self.t, self.ref
        n_clip = int(self.clip[i0 : i1 + 1].sum())
        complete = i0 > 0 and i1 < t.size - 1
        corr: float | None = None
        u_corr: float | None = None
        if n_clip:
            self.warnings.append(
                f"move at {t[i0]:.3g}-{t[i1]:.3g} s has {n_clip} over-range sample(s): its scale "
                "is refused; rotate more slowly so the rate stays inside the range"
            )
        elif not complete:
            self.warnings.append(
                f"the record {'starts' if i0 == 0 else 'ends'} inside the move at "
                f"{t[i0]:.3g}-{t[i1]:.3g} s: keep sampling at rest before and after each move"
            )
        else:
            corr = math.copysign(ref, angle) / angle
            u_corr = abs(corr) * math.hypot(self.u_ref / ref, u_angle / angle)
        return StopMove(
            start_s=float(t[i0]),
            end_s=float(t[i1]),
            measured_angle_deg=angle,
            u_measured_angle_deg=u_angle,
            direction=1 if angle > 0 else -1,
            peak_rate_dps=float(np.max(np.abs(self.y[i0 : i1 + 1] - self.bias.bias_dps))),
            n_over_range=n_clip,
            complete=complete,
            scale_correction=corr,
            u_scale_correction=u_corr,
        )


def _disagreement(
    usable: list[tuple[int, float]],
    ref: float,
    tolerance: float,
    chi2: float | None,
    dof: int,
    birge: float,
) -> str:
    """The warning for moves whose corrections disagree beyond their uncertainties."""
    corrs = ", ".join(f"{ref / abs(a):.4f}" for _, a in usable)
    return (
        f"MOVES DISAGREE: the per-move scale corrections ({corrs}) differ by far more than "
        f"their uncertainties and a {tolerance:.2%} allowance per move (chi-square "
        f"{chi2:.3g} on {dof} degree(s) of freedom); the mean's uncertainty is widened by "
        f"the Birge ratio {birge:.3g}. Check that "
        "every move went from stop to stop, and look for a bounce, a slipped stop, or a "
        "scale that differs between directions"
    )


def _clip_mask(
    y: NDArray[np.float64], status: ArrayLike | None, full_scale_dps: float | None
) -> NDArray[np.bool_]:
    clip = np.zeros(y.size, dtype=bool)
    if status is not None:
        st = np.asarray(status)
        if st.shape != y.shape:
            raise AnalysisError(f"status has {st.size} entries but rate_dps has {y.size}")
        clip |= (st.astype(np.int64) & CLIP_BITS) != 0
    if full_scale_dps is not None:
        clip |= np.abs(y) > positive(full_scale_dps, "full_scale_dps")
    return clip


def _mean_correction(
    usable: list[tuple[int, float]], ref: float, u_ref: float, cov: NDArray[np.float64]
) -> tuple[float | None, float | None]:
    """Mean of ref*sign/angle over the usable moves (index into `cov`, angle), with its
    standard uncertainty from the reference and the angle errors' covariance `cov`."""
    if not usable:
        return None, None
    idx = [j for j, _ in usable]
    angles = np.array([a for _, a in usable])
    corrs = np.copysign(ref, angles) / angles
    # d mean / d ref = mean(c_k) / ref; d mean / d angle_k = -c_k / (n angle_k)
    g_ref = float(np.mean(corrs / ref))
    g = -corrs / angles / len(usable)
    var = (g_ref * u_ref) ** 2 + float(g @ cov[np.ix_(idx, idx)] @ g)
    return float(corrs.mean()), math.sqrt(var)


CONSISTENCY_P = 1e-3  # moves are flagged inconsistent when chi-square's p-value is below this


def _move_consistency(
    usable: list[tuple[int, float]], ref: float, cov: NDArray[np.float64], tolerance: float
) -> tuple[float | None, int, float | None, bool | None]:
    """Consistency of the usable moves' corrections. The covariance of the corrections comes
    from the angle errors (the reference angle is common to all moves and cancels in their
    differences). The test: chi-square about the generalised-least-squares mean with each
    move given an extra independent relative allowance `tolerance` (direction/rate
    dependence of a real part's scale), p-value below CONSISTENCY_P = inconsistent. The
    Birge ratio sqrt(chi2 / dof) is from the noise-only covariance: it is what the mean's
    uncertainty must be multiplied by to cover the observed scatter. Returns (chi2 with the
    allowance, dof, Birge ratio, consistent); (None, 0, None, None) below two moves."""
    if len(usable) < 2:
        return None, 0, None, None
    idx = [j for j, _ in usable]
    angles = np.array([a for _, a in usable])
    corrs = np.copysign(ref, angles) / angles
    jac = np.diag(-corrs / angles)
    c_cov = jac @ cov[np.ix_(idx, idx)] @ jac.T
    dof = corrs.size - 1

    def chi2_of(c: NDArray[np.float64]) -> float:
        inv = np.linalg.pinv(c, rcond=1e-12, hermitian=True)
        ones = np.ones(corrs.size)
        denom = float(ones @ inv @ ones)
        mu = float(ones @ inv @ corrs) / denom if denom > 0 else float(corrs.mean())
        r = corrs - mu
        return max(float(r @ inv @ r), 0.0)

    chi2_noise = chi2_of(c_cov)
    chi2 = chi2_of(c_cov + np.diag((tolerance * corrs) ** 2))
    consistent = bool(chi2_dist.sf(chi2, dof) >= CONSISTENCY_P)
    return chi2, dof, math.sqrt(chi2_noise / dof), consistent


def angle_error_covariance(
    noise: NoiseModel,
    bias_window_s: tuple[float, float],
    moves_s: list[tuple[float, float]],
    points_per_decade: int = 2000,
) -> NDArray[np.float64]:
    """Covariance (deg^2) of the errors of angles integrated over `moves_s` from an output
    corrected by the mean over `bias_window_s` (error_k = noise integrated over move k - T_k x
    the window's mean noise).

    White noise (angle random walk) is exact in closed form. Bias instability (flicker,
    S(f) = h_-1 / f) and rate random walk (S(f) = h_-2 / f^2) are integrated over their
    one-sided spectra, Var = integral S(f) |H(f)|^2 df, with H the Fourier transform of the
    move-minus-window weighting; this carries the bias's drift between the window and each
    move. For a move adjacent to a window of its own length the variance is T^2 x 2 AVAR(T).
    """
    w0, w1 = bias_window_s
    t_w = w1 - w0
    if not t_w > 0:
        raise AnalysisError("the bias window must have a positive length")
    n = len(moves_s)
    dur = np.array([b - a for a, b in moves_s], dtype=np.float64)
    if n == 0:
        return np.zeros((0, 0))
    # white: h_k = 1_move_k - (T_k / T_w) 1_window; moves and window do not overlap
    n2 = noise.arw_deg_per_sqrt_s**2
    cov = n2 * (np.diag(dur) + np.outer(dur, dur) / t_w)
    h_m1 = FLICKER_AVAR_FACTOR * noise.bias_instability_dps**2 / (2.0 * math.log(2.0))
    h_m2 = noise.rrw_dps_per_sqrt_s**2 / (2.0 * math.pi**2)
    if h_m1 == 0.0 and h_m2 == 0.0:
        return cov
    span = max(max(b for _, b in moves_s), w1) - min(min(a for a, _ in moves_s), w0)
    shortest = float(min(dur.min(), t_w))
    f_lo, f_hi = 1e-5 / span, 1e3 / max(shortest, 1e-3)
    f = np.logspace(
        math.log10(f_lo), math.log10(f_hi), int(points_per_decade * math.log10(f_hi / f_lo))
    )
    om = 2.0 * math.pi * f

    def box(a: float, b: float) -> NDArray[np.complex128]:  # transform of 1_[a, b]
        a, b = a - w0, b - w0  # times from the window start keep the phases small
        return (np.exp(-1j * om * a) - np.exp(-1j * om * b)) / (1j * om)

    win = box(w0, w1) / t_w
    h = np.array([box(a, b) - d * win for (a, b), d in zip(moves_s, dur, strict=True)])
    s = h_m1 / f + h_m2 / f**2
    weight = s * f  # integrate over ln f
    cross = np.real(h[:, None, :] * np.conj(h[None, :, :])) * weight
    cov += np.trapezoid(cross, np.log(f), axis=-1)
    return cov


def _static_segments(
    t: NDArray[np.float64], moves: list[tuple[float, float]]
) -> tuple[tuple[float, float], ...]:
    out: list[tuple[float, float]] = []
    cursor = float(t[0])
    for a, b in sorted(moves):
        if a > cursor:
            out.append((cursor, a))
        cursor = max(cursor, b)
    if cursor < float(t[-1]):
        out.append((cursor, float(t[-1])))
    return tuple(out)
