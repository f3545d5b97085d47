"""The noise floor, measured from the data itself with the Allan deviation.

The overlapping Allan variance of the model residual is pooled over the windows where the
input is constant (static, plateau, stop_static, verify): the Allan variance ignores
constant offsets, so what remains is the part's noise, whatever the model gets wrong about
bias or scale. A white + flat model, sigma^2(T) = N^2/T + F^2, is fitted to it; sigma(T) is
then the expected scatter of the mean of a T-second block. For the significance tests the
bias instability (flicker, flat Allan deviation) is represented by a sum of first-order
Gauss-Markov processes one decade apart in correlation time (10, 100, 1000 s), scaled so
their combined Allan deviation peaks at F; slow wander of the bias is then not mistaken for
an effect.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from procedures.model.blocks import Blocks
from procedures.model.trajectory import FloatArray

CONSTANT_INPUT_KINDS = ("static", "plateau", "stop_static", "verify")
GM_CORRELATION_TIMES_S = (10.0, 100.0, 1000.0)


def _gm_avar(t: FloatArray, tau_c: float) -> FloatArray:
    """Allan variance of a unit-variance first-order Gauss-Markov process."""
    x = t / tau_c
    return (2 * x - 3 + 4 * np.exp(-x) - np.exp(-2 * x)) / x**2


def _flicker_gm_sigma() -> float:
    """Per-process sigma (in units of F) so the summed Allan deviation peaks at F."""
    t = np.logspace(-1, 5, 400)
    total = sum(_gm_avar(t, tc) for tc in GM_CORRELATION_TIMES_S)
    return float(1.0 / np.sqrt(np.max(total)))


GM_SIGMA_PER_F = _flicker_gm_sigma()
# Extra factor on the wander level of the covariance (1: as measured).
WANDER_MARGIN = 1.0


@dataclass(frozen=True)
class NoiseModel:
    white_dps_rt_s: float  # N: sigma(T) = N / sqrt(T) on the -1/2 slope, deg/s * sqrt(s)
    floor_dps: float  # F: the flat part of the Allan deviation, deg/s
    tau_s: FloatArray  # measured Allan curve, for the report
    adev_dps: FloatArray
    rrw_dps_per_rt_s: float = 0.0  # K: rate random walk, sigma(T)^2 += K^2 T / 3
    slow_from: str = "allan"  # "allan" (windows only) or "reml" (between-block residuals)

    @property
    def rrw_deg_per_h_per_sqrt_h(self) -> float:
        return self.rrw_dps_per_rt_s * 216000.0

    @property
    def arw_deg_per_sqrt_h(self) -> float:
        return self.white_dps_rt_s * 60.0

    @property
    def bias_instability_deg_per_h(self) -> float:
        return self.floor_dps / 0.664 * 3600.0

    @property
    def wander_dps(self) -> float:
        """Flat level used for the bias wander in the covariance (the fitted F). Raising it
        to the Allan deviation at the longest measured tau was tried: it suppresses false
        alarms of slow effects but makes fast contrasts overconfident, so it is not done."""
        return self.floor_dps

    def sigma_dps(self, duration_s: FloatArray) -> FloatArray:
        """Expected scatter of the mean of a block of the given duration."""
        t = np.asarray(duration_s, dtype=float)
        return np.sqrt(
            self.white_dps_rt_s**2 / t + self.floor_dps**2 + self.rrw_dps_per_rt_s**2 * t / 3
        )

    def block_covariance(self, blocks: Blocks) -> FloatArray:
        """Covariance of block-mean noise: white per block plus a Gauss-Markov bias wander."""
        cov = np.diag(self.white_dps_rt_s**2 / blocks.duration_s)
        wander = self.wander_dps
        if wander > 0:
            s2 = (wander * GM_SIGMA_PER_F * WANDER_MARGIN) ** 2
            dt = np.abs(blocks.center_s[:, None] - blocks.center_s[None, :])
            for tau_c in GM_CORRELATION_TIMES_S:
                cov = cov + s2 * np.exp(-dt / tau_c)
        if self.rrw_dps_per_rt_s > 0:
            t = blocks.center_s - blocks.center_s.min()
            cov = cov + self.rrw_dps_per_rt_s**2 * np.minimum(t[:, None], t[None, :])
        return cov

    def floor_per_block_dps(self, blocks: Blocks) -> FloatArray:
        """Scatter of each block's noise mean about the record's duration-weighted mean:
        what noise alone leaves in a block-mean residual once a bias is fitted."""
        cov = self.block_covariance(blocks)
        w = blocks.duration_s / blocks.duration_s.sum()
        cw = cov @ w
        var = np.diag(cov) - 2 * cw + w @ cw
        return np.sqrt(np.maximum(var, 0.0))


def overlapping_avar(rate: FloatArray, dt_s: float, m: int) -> tuple[float, int]:
    """Overlapping Allan variance of rate data at averaging factor m, and its term count."""
    n = rate.size
    if n < 2 * m + 1:
        return math.nan, 0
    phase = np.concatenate([[0.0], np.cumsum(rate)]) * dt_s
    d = phase[2 * m :] - 2 * phase[m:-m] + phase[: -2 * m]
    tau = m * dt_s
    return float(np.sum(d * d) / (2 * tau * tau * d.size)), int(d.size)


def measure_noise(
    residual_dps: FloatArray, time_s: FloatArray, blocks: Blocks, max_piece_s: float = 200.0
) -> NoiseModel:
    """Pooled Allan deviation of the residual over constant-input windows, and its fit."""
    dt = float(np.median(np.diff(time_s)))
    pieces: list[FloatArray] = []
    # contiguous constant-input blocks are joined back into their windows
    i = 0
    kinds = blocks.kind
    while i < blocks.count:
        if kinds[i] not in CONSTANT_INPUT_KINDS:
            i += 1
            continue
        j = i
        while (
            j + 1 < blocks.count
            and kinds[j + 1] == kinds[i]
            and blocks.start[j + 1] == blocks.stop[j]
        ):
            j += 1
        a, b = int(blocks.start[i]), int(blocks.stop[j])
        max_n = max(int(max_piece_s / dt), 8)
        for k in range(a, b, max_n):
            piece = residual_dps[k : min(k + max_n, b)]
            if piece.size >= 16:
                pieces.append(piece)
        i = j + 1
    if not pieces:
        raise ValueError(
            "no static or constant-rate window in the data to measure the noise floor from; "
            "the record needs static windows or rate plateaus"
        )
    longest = max(p.size for p in pieces)
    ms = [1]
    while 2 * ms[-1] <= longest // 4:
        ms.append(2 * ms[-1])
    taus, avars, dofs = [], [], []
    for m in ms:
        num, den = 0.0, 0
        for p in pieces:
            v, c = overlapping_avar(p, dt, m)
            if c > 0:
                num += v * c
                den += c
        if den > 0:
            taus.append(m * dt)
            avars.append(num / den)
            dofs.append(max(den / m, 1.0))  # about one independent term per m samples
    tau = np.asarray(taus)
    avar = np.asarray(avars)
    # fit of avar = N^2 / tau + F^2, each point weighted by its relative precision
    # (~ sqrt(dof)), non-negative terms
    weight = np.sqrt(np.asarray(dofs)) / avar
    design = np.stack([1.0 / tau, np.ones_like(tau)], axis=1) * weight[:, None]
    coef, _ = nnls(design, weight * avar)
    return NoiseModel(
        white_dps_rt_s=float(math.sqrt(coef[0])),
        floor_dps=float(math.sqrt(coef[1])),
        tau_s=tau,
        adev_dps=np.sqrt(avar),
    )
