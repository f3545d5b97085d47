"""Overlapping Allan deviation of a rate record and the IEEE 952 noise terms read from it.

The Allan variance is computed from the integrated angle (IEEE 952 Annex C, NIST SP 1065
eq. 11), exactly as allantools' `oadev(data_type="freq")` does; tests check it against
allantools and against NIST's NBS14 values.

The noise terms are found by one weighted least-squares fit of the variance model

    AVAR(tau) = N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3

(angle random walk N, bias instability B, rate random walk K), with non-negative terms and
weights from the equivalent degrees of freedom of each tau. Each term is thereby fixed by
the taus where its slope (-1/2, 0, +1/2 in deviation) dominates, not by reading one point;
the region where each term holds is reported with the result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import nnls

from procedures.analysis._checks import finite_1d, positive
from procedures.analysis.errors import AnalysisError

FLICKER_AVAR_FACTOR = 2.0 * math.log(2.0) / math.pi  # AVAR = factor * B^2 in the flat part
FLICKER_ADEV_FACTOR = math.sqrt(FLICKER_AVAR_FACTOR)  # 0.664
MIN_SAMPLES = 8
SIGNIFICANCE = 3.0
# Overlapping Allan variances at neighbouring octave taus are positively correlated, so the
# fit's independent-tau covariance understates the scatter of N and B: by 1.55-1.63 in
# Monte Carlo of white and white + flicker records of 20k-360k samples (octave taus).
# tests/analysis/test_allan.py checks the corrected uncertainties against that scatter.
OCTAVE_CORRELATION_FACTOR = 1.6  # a flat or +1/2 term is kept only when this many sigma above zero

TauSpec = Literal["octave", "log"] | ArrayLike


@dataclass(frozen=True)
class AllanDeviation:
    """Overlapping Allan deviation at each tau, with the statistics behind each point."""

    tau_s: NDArray[np.float64]
    adev_dps: NDArray[np.float64]
    m: NDArray[np.int64]  # tau in samples
    n_terms: NDArray[np.int64]  # second differences summed at each tau
    n_samples: int
    sample_rate_hz: float

    @property
    def avar_dps2(self) -> NDArray[np.float64]:
        return self.adev_dps**2

    def edf(self, alpha: int = 0) -> NDArray[np.float64]:
        """Equivalent degrees of freedom at each tau for power-law noise alpha (SP 1065 t. 5)."""
        return _edf(self.n_samples + 1, self.m.astype(np.float64), alpha)


@dataclass(frozen=True)
class NoiseModel:
    """IEEE 952 noise terms of a rate signal, in SI-like units (deg, s)."""

    arw_deg_per_sqrt_s: float = 0.0  # N: AVAR = N^2 / tau
    bias_instability_dps: float = 0.0  # B: AVAR = 0.4413 B^2 (ADEV = 0.664 B)
    rrw_dps_per_sqrt_s: float = 0.0  # K: AVAR = K^2 tau / 3

    @property
    def arw_deg_per_sqrt_h(self) -> float:
        return self.arw_deg_per_sqrt_s * 60.0

    @property
    def bias_instability_deg_per_h(self) -> float:
        return self.bias_instability_dps * 3600.0

    @property
    def rrw_deg_per_h_per_sqrt_h(self) -> float:
        return self.rrw_dps_per_sqrt_s * 3600.0 * 60.0

    def avar_dps2(self, tau_s: ArrayLike) -> NDArray[np.float64]:
        tau = np.asarray(tau_s, dtype=np.float64)
        return (
            self.arw_deg_per_sqrt_s**2 / tau
            + FLICKER_AVAR_FACTOR * self.bias_instability_dps**2
            + self.rrw_dps_per_sqrt_s**2 * tau / 3.0
        )

    def adev_dps(self, tau_s: ArrayLike) -> NDArray[np.float64]:
        return np.sqrt(self.avar_dps2(tau_s))

    def with_floor(
        self, bias_instability_dps: float, rrw_dps_per_sqrt_s: float = 0.0
    ) -> NoiseModel:
        """This model with its slow terms at least the given values (a record too short to
        resolve them fits them near zero; a product's typical values are their floor)."""
        return replace(
            self,
            bias_instability_dps=max(self.bias_instability_dps, bias_instability_dps),
            rrw_dps_per_sqrt_s=max(self.rrw_dps_per_sqrt_s, rrw_dps_per_sqrt_s),
        )

    @classmethod
    def from_datasheet(
        cls,
        arw_deg_per_sqrt_h: float = 0.0,
        bias_instability_deg_per_h: float = 0.0,
        rrw_deg_per_h_per_sqrt_h: float = 0.0,
    ) -> NoiseModel:
        return cls(
            arw_deg_per_sqrt_s=arw_deg_per_sqrt_h / 60.0,
            bias_instability_dps=bias_instability_deg_per_h / 3600.0,
            rrw_dps_per_sqrt_s=rrw_deg_per_h_per_sqrt_h / 216000.0,
        )


@dataclass(frozen=True)
class NoiseFit:
    """Noise terms fitted to an Allan deviation, with standard (k=1) uncertainties.

    The fit's own covariance treats the taus as independent, which overlapping estimates
    are not; the uncertainties are that covariance times OCTAVE_CORRELATION_FACTOR. Where a
    term is only marginally resolved its distribution is far from normal: treat its
    uncertainty as indicative. A region is (tau_min_s, tau_max_s) where the term carries
    at least half of the fitted variance, or None where it never does.
    """

    model: NoiseModel
    u_arw_deg_per_sqrt_s: float
    u_bias_instability_dps: float
    u_rrw_dps_per_sqrt_s: float
    arw_region_s: tuple[float, float] | None
    flat_region_s: tuple[float, float] | None
    rrw_region_s: tuple[float, float] | None
    chi2_per_dof: float

    @property
    def arw_deg_per_sqrt_h(self) -> float:
        return self.model.arw_deg_per_sqrt_h

    @property
    def bias_instability_deg_per_h(self) -> float:
        return self.model.bias_instability_deg_per_h

    @property
    def u_arw_deg_per_sqrt_h(self) -> float:
        return self.u_arw_deg_per_sqrt_s * 60.0

    @property
    def u_bias_instability_deg_per_h(self) -> float:
        return self.u_bias_instability_dps * 3600.0


@dataclass(frozen=True)
class AllanAnalysis:
    """What `station analyze allan` reports: the deviation and the noise terms read from it."""

    adev: AllanDeviation
    noise: NoiseFit

    @property
    def bias_instability_upper_bound_deg_per_h(self) -> float:
        """Lowest ADEV / 0.664: what B can be at most; useful when the flat part is unseen."""
        return float(np.min(self.adev.adev_dps)) / FLICKER_ADEV_FACTOR * 3600.0

    @property
    def rrw_upper_bound_deg_per_h_per_sqrt_h(self) -> float:
        """min over tau of ADEV * sqrt(3 / tau) (AVAR >= K^2 tau / 3): what K can be at most;
        useful when the +1/2 part is unseen."""
        k = self.adev.adev_dps * np.sqrt(3.0 / self.adev.tau_s)
        return float(np.min(k)) * 3600.0 * 60.0


NON_STATIC_SIGMA = 10.0  # |rate - local level| beyond this many white-noise sigma is motion
BASELINE_S = 60.0  # the local level: medians of blocks this long, interpolated between them


def _local_level(y: NDArray[np.float64], block: int) -> NDArray[np.float64]:
    """The record's slowly varying level: medians of consecutive blocks of `block` samples
    (a move of a few seconds barely shifts them), interpolated linearly between the block
    centres; a record shorter than two blocks gets its overall median. Following the level
    keeps the slow wander of a part at rest (bias instability, rate random walk, temperature)
    from being taken for motion in a long record."""
    n_blocks = y.size // block
    if n_blocks < 2:
        return np.full(y.size, float(np.median(y)))
    edges = np.linspace(0, y.size, n_blocks + 1).astype(np.int64)
    centres = 0.5 * (edges[:-1] + edges[1:] - 1)
    levels = np.array([np.median(y[a:b]) for a, b in zip(edges[:-1], edges[1:], strict=True)])
    return np.interp(np.arange(y.size), centres, levels)


@dataclass(frozen=True)
class StaticCheck:
    """Whether a record looks static: excursions from its level far beyond the
    sample-to-sample noise (a move, a step, a shock) make Allan's noise terms meaningless."""

    static: bool
    sigma_dps: float  # white noise per sample, robust, from first differences
    n_excursion: int  # samples more than NON_STATIC_SIGMA sigma from the median
    first_excursion_s: float | None  # time from the record start of the first one
    max_excursion_dps: float

    def message(self) -> str:
        return (
            f"the record is not static: {self.n_excursion} sample(s) lie more than "
            f"{NON_STATIC_SIGMA:g} sigma ({NON_STATIC_SIGMA * self.sigma_dps:.3g} deg/s) from the "
            f"record's level, the first {self.first_excursion_s:.6g} s into the record, up to "
            f"{self.max_excursion_dps:.4g} deg/s away (a move or a step?); the Allan deviation "
            "needs a static record, so the noise terms (rate random walk above all) are not the "
            "part's: record the part at rest and analyse that"
        )


def check_static(rate_dps: ArrayLike, sample_rate_hz: float) -> StaticCheck:
    """Excursions of a rate record from its level (block medians over BASELINE_S, see
    `_local_level`) beyond NON_STATIC_SIGMA x the white noise (robust sigma of first
    differences / sqrt 2). A move between stops or a rate step is tens of deg/s; the wander
    of a part at rest within a minute stays well inside the threshold."""
    y = np.asarray(rate_dps, dtype=np.float64)
    d = np.diff(y)
    sigma = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(2.0)
    dev = np.abs(y - _local_level(y, max(int(round(BASELINE_S * sample_rate_hz)), 16)))
    if sigma <= 0.0:  # coarsely quantised: most steps are zero
        sigma = float(np.std(d)) / math.sqrt(2.0)
    hit = dev > NON_STATIC_SIGMA * sigma if sigma > 0.0 else np.zeros(y.size, dtype=bool)
    n = int(hit.sum())
    return StaticCheck(
        static=n == 0,
        sigma_dps=sigma,
        n_excursion=n,
        first_excursion_s=float(np.argmax(hit)) / sample_rate_hz if n else None,
        max_excursion_dps=float(dev.max()) if dev.size else 0.0,
    )


def tau_samples(n_samples: int, taus: TauSpec, sample_rate_hz: float) -> NDArray[np.int64]:
    """Averaging factors m (tau = m / rate) usable on a record of n_samples."""
    m_max = n_samples // 2  # at least one second difference of the phase at every tau
    if m_max < 1:
        raise AnalysisError(f"{n_samples} samples are too few for an Allan deviation")
    if isinstance(taus, str):
        if taus == "octave":
            m = 2 ** np.arange(int(math.log2(m_max)) + 1)
        elif taus == "log":  # about ten per decade
            n_points = int(10 * math.log10(m_max)) + 1 if m_max > 1 else 1
            m = np.unique(np.round(np.logspace(0, math.log10(m_max), n_points)).astype(np.int64))
        else:
            raise AnalysisError(
                f"taus must be 'octave', 'log' or an array of seconds, not {taus!r}"
            )
    else:
        tau_req = finite_1d(taus, "taus")
        m = np.unique(np.round(tau_req * sample_rate_hz).astype(np.int64))
        m = m[(m >= 1) & (m <= m_max)]
        if m.size == 0:
            raise AnalysisError(
                f"no requested tau fits a record of {n_samples} samples at {sample_rate_hz} Hz "
                f"(usable 1/rate to {m_max / sample_rate_hz:g} s)"
            )
    return np.asarray(m, dtype=np.int64)


def overlapping_adev(
    rate_dps: ArrayLike, sample_rate_hz: float, taus: TauSpec = "octave"
) -> AllanDeviation:
    """Overlapping Allan deviation of a rate record sampled at `sample_rate_hz`."""
    rate = finite_1d(rate_dps, "rate_dps", MIN_SAMPLES)
    fs = positive(sample_rate_hz, "sample_rate_hz")
    m = tau_samples(rate.size, taus, fs)
    dt = 1.0 / fs
    # Angle from a zero start, mean removed first: the second differences are unchanged and
    # the cumulative sum keeps its precision on a record with a large bias.
    phase = np.empty(rate.size + 1)
    phase[0] = 0.0
    np.cumsum(rate - rate.mean(), out=phase[1:])
    phase *= dt
    adev = np.empty(m.size)
    n_terms = np.empty(m.size, dtype=np.int64)
    buf = np.empty(phase.size)
    for i, mi in enumerate(m):
        mi = int(mi)
        k = phase.size - 2 * mi
        d = buf[:k]  # x[n+2m] - 2 x[n+m] + x[n], in place: no temporaries on long records
        np.subtract(phase[2 * mi :], phase[mi:-mi], out=d)
        np.subtract(d, phase[mi:-mi], out=d)
        np.add(d, phase[:k], out=d)
        tau = mi * dt
        n_terms[i] = k
        adev[i] = math.sqrt(float(np.dot(d, d)) / (2.0 * tau * tau * k))
    return AllanDeviation(
        tau_s=np.asarray(m * dt, dtype=np.float64),
        adev_dps=adev,
        m=m,
        n_terms=n_terms,
        n_samples=rate.size,
        sample_rate_hz=fs,
    )


def _edf(n_phase: int, m: NDArray[np.float64], alpha: int) -> NDArray[np.float64]:
    n = float(n_phase)
    if alpha == 0:
        edf = (3.0 * (n - 1.0) / (2.0 * m) - 2.0 * (n - 2.0) / n) * (
            4.0 * m**2 / (4.0 * m**2 + 5.0)
        )
    elif alpha == -1:
        edf = np.where(
            m == 1, 2.0 * (n - 2.0) / (2.3 * n - 4.9), 5.0 * n**2 / (4.0 * m * (n + 3.0 * m))
        )
    elif alpha == -2:
        edf = (n - 2.0) / m * ((n - 1.0) ** 2 - 3.0 * m * (n - 1.0) + 4.0 * m**2) / (n - 3.0) ** 2
    else:
        raise ValueError(f"unsupported alpha {alpha}")
    return np.maximum(edf, 1.0)


def _basis(tau: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.column_stack([1.0 / tau, np.full_like(tau, FLICKER_AVAR_FACTOR), tau / 3.0])


def fit_noise_model(
    adev: AllanDeviation,
    terms: tuple[bool, bool, bool] = (True, True, True),
    iterations: int = 4,
    min_significance: float = SIGNIFICANCE,
) -> NoiseFit:
    """Fit (N, B, K) to an Allan deviation; `terms` switches white, flat and +1/2 parts on.

    A term whose fitted variance is less than `min_significance` times its own standard
    uncertainty is dropped and the fit repeated: on a short record the last few taus carry
    so few degrees of freedom that a spurious flat or +1/2 term would otherwise inflate
    every uncertainty read from the model.
    """
    active = np.asarray(terms, dtype=bool)
    if not np.any(adev.adev_dps > 0.0):  # a constant record: no noise to fit
        return NoiseFit(NoiseModel(), 0.0, 0.0, 0.0, None, None, None, 0.0)
    while True:
        fit, p, u_p = _fit_terms(adev, active, iterations)
        weak = active & (p < min_significance * u_p)
        weak[0] = False  # the white term is always kept: every sampled signal has one
        if not weak.any():
            return fit
        # drop the least significant term only, then refit
        ratio = np.where(weak, p / np.maximum(u_p, 1e-300), np.inf)
        active = active.copy()
        active[int(np.argmin(ratio))] = False


def _fit_terms(
    adev: AllanDeviation, active: NDArray[np.bool_], iterations: int
) -> tuple[NoiseFit, NDArray[np.float64], NDArray[np.float64]]:
    tau = adev.tau_s
    avar = adev.avar_dps2
    if tau.size < 2:
        raise AnalysisError("an Allan deviation needs at least two taus to fit noise terms")
    basis_all = _basis(tau)
    if not active.any():
        raise AnalysisError("fit at least one noise term")
    basis = basis_all[:, active]
    edf_by_alpha = {a: adev.edf(a) for a in (0, -1, -2)}
    model_var = np.maximum(avar, np.finfo(float).tiny)
    p = np.zeros(int(active.sum()))
    edf = edf_by_alpha[0]
    for _ in range(iterations):
        # Each point's weight is its model variance times its relative standard error; using
        # the model (not the data) keeps low-lying points from pulling the fit down.
        sd = model_var * np.sqrt(2.0 / edf)
        p, _ = nnls(basis / sd[:, None], avar / sd)
        parts = basis * p
        fitted = parts.sum(axis=1)
        if not np.any(fitted > 0):
            break
        model_var = np.maximum(fitted, 1e-300)
        dominant = np.argmax(basis_all * _expand(p, active), axis=1)
        edf = np.choose(dominant, [edf_by_alpha[0], edf_by_alpha[-1], edf_by_alpha[-2]])
    sd = model_var * np.sqrt(2.0 / edf)
    w_basis = basis / sd[:, None]
    resid = (avar - basis @ p) / sd
    dof = max(tau.size - int(np.count_nonzero(p)), 1)
    chi2 = float(resid @ resid) / dof
    cov = _covariance(w_basis, p)
    full_p = _expand(p, active)
    full_cov = np.zeros((3, 3))
    idx = np.flatnonzero(active)
    full_cov[np.ix_(idx, idx)] = cov
    values = np.sqrt(np.maximum(full_p, 0.0))
    u_vals = _sqrt_uncertainty(full_p, np.diag(full_cov)) * OCTAVE_CORRELATION_FACTOR
    model = NoiseModel(
        arw_deg_per_sqrt_s=float(values[0]),
        bias_instability_dps=float(values[1]),
        rrw_dps_per_sqrt_s=float(values[2]),
    )
    shares = basis_all * full_p
    total = np.maximum(shares.sum(axis=1), 1e-300)
    regions = [_region(tau, shares[:, j] / total) for j in range(3)]
    fit = NoiseFit(
        model=model,
        u_arw_deg_per_sqrt_s=float(u_vals[0]),
        u_bias_instability_dps=float(u_vals[1]),
        u_rrw_dps_per_sqrt_s=float(u_vals[2]),
        arw_region_s=regions[0],
        flat_region_s=regions[1],
        rrw_region_s=regions[2],
        chi2_per_dof=chi2,
    )
    return fit, full_p, np.sqrt(np.maximum(np.diag(full_cov), 0.0))


def analyze_allan(
    rate_dps: ArrayLike, sample_rate_hz: float, taus: TauSpec = "octave"
) -> AllanAnalysis:
    """Allan deviation of a static record and the noise terms fitted to it."""
    adev = overlapping_adev(rate_dps, sample_rate_hz, taus)
    return AllanAnalysis(adev=adev, noise=fit_noise_model(adev))


def _expand(p: NDArray[np.float64], active: NDArray[np.bool_]) -> NDArray[np.float64]:
    full = np.zeros(3)
    full[active] = p
    return full


def _covariance(w_basis: NDArray[np.float64], p: NDArray[np.float64]) -> NDArray[np.float64]:
    """Covariance of the fitted variance terms, over the terms the fit kept positive."""
    k = p.size
    cov = np.zeros((k, k))
    free = p > 0
    if free.any():
        a = w_basis[:, free]
        normal = a.T @ a
        try:
            cov[np.ix_(free, free)] = np.linalg.inv(normal)
        except np.linalg.LinAlgError:
            cov[np.ix_(free, free)] = np.linalg.pinv(normal)
    return cov


def _sqrt_uncertainty(p: NDArray[np.float64], var_p: NDArray[np.float64]) -> NDArray[np.float64]:
    """u(sqrt(p)) from u(p): u/(2 sqrt p), bounded by sqrt(u) near zero."""
    u_p = np.sqrt(np.maximum(var_p, 0.0))
    root = np.sqrt(np.maximum(p, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        lin = np.where(root > 0, u_p / (2.0 * root), np.inf)
    return np.minimum(lin, np.sqrt(u_p))


def _region(tau: NDArray[np.float64], share: NDArray[np.float64]) -> tuple[float, float] | None:
    hit = share >= 0.5
    if not hit.any():
        return None
    return (float(tau[hit].min()), float(tau[hit].max()))
