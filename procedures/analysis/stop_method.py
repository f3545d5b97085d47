"""The article's stop method: integrate the bias-corrected rate over moves between two stops.

Steps (reference/METHOD.md): find the static and moving parts of the record by hysteresis on
the bias-corrected rate; take the bias from the first static window; integrate each move from
before the motion starts to after it stops (margins), so that a bounce at the stop is inside
the integral; scale correction = reference angle / measured angle for each move, and their
mean. A move holding an over-range or saturated sample gets no scale.

Uncertainty of each correction and of the mean combines, with their correlations: the noise
integrated over each move (Allan variance at the integration time x time^2), the bias
uncertainty x integration time (common to all moves: it cancels to first order between an out
and a back move), and the reference angle's own uncertainty (common to all moves).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.fixture_protocol import SampleStatus
from procedures.analysis._checks import finite_1d, monotonic_time, non_negative, positive
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


@dataclass(frozen=True)
class StopMove:
    """One move between the stops; u_* are standard (k=1) uncertainties."""

    start_s: float
    end_s: float
    measured_angle_deg: float
    u_measured_angle_deg: float  # noise and bias only
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
) -> StopMethodResult:
    """Bias and scale correction from a stop-method record (time, rate and optional status)."""
    cfg = settings or StopMethodSettings()
    t = finite_1d(time_s, "time_s", 16)
    y = finite_1d(rate_dps, "rate_dps", 16)
    if t.size != y.size:
        raise AnalysisError(f"time_s has {t.size} samples but rate_dps has {y.size}")
    monotonic_time(t)
    ref = positive(reference_angle_deg, "reference_angle_deg")
    u_ref = non_negative(u_reference_angle_deg, "u_reference_angle_deg")
    clip = _clip_mask(y, status, cfg.full_scale_dps)

    ranges, _, sigma = detect_moves(t, y, cfg)
    if not ranges:
        raise AnalysisError(
            "no move found in the record: the rate never left the static noise band; "
            "check that the part was rotated between the stops while sampling"
        )
    fs = (t.size - 1) / (t[-1] - t[0])
    first = ranges[0][0]
    if first == 0 or t[first] - t[0] < cfg.min_bias_window_s:
        raise AnalysisError(
            f"the record must start with at least {cfg.min_bias_window_s:g} s at rest at the "
            f"first stop (found {t[first] - t[0]:.3g} s before the first move): "
            "start sampling, wait 5 s, then rotate"
        )
    bias = estimate_bias(y[:first], fs)

    warnings: list[str] = []
    raw_moves: list[tuple[int, int, float, float]] = []
    for i0, i1 in ranges:
        e = y[i0 : i1 + 1] - bias.bias_dps
        angle = float(np.trapezoid(e, t[i0 : i1 + 1]))
        duration = float(t[i1] - t[i0])
        raw_moves.append((i0, i1, angle, duration))

    moves: list[StopMove] = []
    usable: list[tuple[float, float, float]] = []  # (angle, duration, u_noise)
    for i0, i1, angle, duration in raw_moves:
        if abs(angle) < cfg.min_move_fraction * ref:
            warnings.append(
                f"ignored a disturbance of {angle:.3g} deg at {t[i0]:.3g}-{t[i1]:.3g} s "
                "(too small to be a move between the stops)"
            )
            continue
        u_noise = duration * float(np.sqrt(bias.noise.avar_dps2(max(duration, 1.0 / fs))))
        u_angle = math.hypot(u_noise, bias.u_bias_dps * duration)
        n_clip = int(clip[i0 : i1 + 1].sum())
        complete = i0 > 0 and i1 < t.size - 1
        corr: float | None = None
        u_corr: float | None = None
        if n_clip:
            warnings.append(
                f"move at {t[i0]:.3g}-{t[i1]:.3g} s has {n_clip} over-range sample(s): its scale "
                "is refused; rotate more slowly so the rate stays inside the range"
            )
        elif not complete:
            warnings.append(
                f"the record {'starts' if i0 == 0 else 'ends'} inside the move at "
                f"{t[i0]:.3g}-{t[i1]:.3g} s: keep sampling at rest before and after each move"
            )
        else:
            corr = math.copysign(ref, angle) / angle
            rel = math.hypot(u_ref / ref, u_angle / angle)
            u_corr = abs(corr) * rel
            usable.append((angle, duration, u_noise))
        moves.append(
            StopMove(
                start_s=float(t[i0]),
                end_s=float(t[i1]),
                measured_angle_deg=angle,
                u_measured_angle_deg=u_angle,
                direction=1 if angle > 0 else -1,
                peak_rate_dps=float(np.max(np.abs(y[i0 : i1 + 1] - bias.bias_dps))),
                n_over_range=n_clip,
                complete=complete,
                scale_correction=corr,
                u_scale_correction=u_corr,
            )
        )

    mean_corr, u_mean = _mean_correction(usable, ref, u_ref, bias.u_bias_dps)
    if mean_corr is None:
        warnings.append("no usable move: no scale correction")
    statics = _static_segments(t, [(m.start_s, m.end_s) for m in moves])
    return StopMethodResult(
        bias=bias,
        moves=tuple(moves),
        static_segments_s=statics,
        scale_correction=mean_corr,
        u_scale_correction=u_mean,
        reference_angle_deg=ref,
        u_reference_angle_deg=u_ref,
        noise_sigma_dps=sigma,
        n_over_range=int(clip.sum()),
        warnings=tuple(warnings),
        over_range_intervals_s=tuple((float(t[a]), float(t[b])) for a, b in _runs(clip)),
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
    usable: list[tuple[float, float, float]], ref: float, u_ref: float, u_bias: float
) -> tuple[float | None, float | None]:
    """Mean of ref*sign/angle over moves; u from sources [reference, bias, noise_1..n]."""
    if not usable:
        return None, None
    n = len(usable)
    corrs = np.array([math.copysign(ref, a) / a for a, _, _ in usable])
    # d c_k / d ref = c_k / ref; d c_k / d bias = c_k T_k / angle_k;
    # d c_k / d noise_k = -c_k / angle_k
    g_ref = float(np.mean(corrs / ref))
    g_bias = float(np.mean([c * d / a for c, (a, d, _) in zip(corrs, usable, strict=True)]))
    g_noise = np.array([-c / a * un for c, (a, _, un) in zip(corrs, usable, strict=True)]) / n
    var = (g_ref * u_ref) ** 2 + (g_bias * u_bias) ** 2 + float(g_noise @ g_noise)
    return float(corrs.mean()), math.sqrt(var)


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
