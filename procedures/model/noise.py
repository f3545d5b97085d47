"""The noise floor, measured from the data itself with the Allan deviation.

The overlapping Allan variance of the model residual is pooled over the windows where the
input is constant (static, plateau, stop_static, verify): the Allan variance ignores
constant offsets, so what remains is the part's noise, whatever the model gets wrong about
bias or scale. A white + flat model, sigma^2(T) = N^2/T + F^2, is fitted to it; sigma(T) is
then the expected scatter of the mean of a T-second block. For the significance tests the
bias instability is represented by a first-order Gauss-Markov process whose Allan deviation
peaks at F (the peak of a Gauss-Markov Allan deviation is 0.617 sigma_GM at T = 1.89 tau_c),
so slow wander of the bias is not mistaken for an effect.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from procedures.model.blocks import Blocks
from procedures.model.trajectory import FloatArray

CONSTANT_INPUT_KINDS = ("static", "plateau", "stop_static", "verify")
GM_PEAK_RATIO = 0.6174  # max Allan deviation of a Gauss-Markov process / its sigma
GM_CORRELATION_TIME_S = 100.0


@dataclass(frozen=True)
class NoiseModel:
    white_dps_rt_s: float  # N: sigma(T) = N / sqrt(T) on the -1/2 slope, deg/s * sqrt(s)
    floor_dps: float  # F: the flat part of the Allan deviation, deg/s
    tau_s: FloatArray  # measured Allan curve, for the report
    adev_dps: FloatArray
    correlation_time_s: float = GM_CORRELATION_TIME_S

    @property
    def arw_deg_per_sqrt_h(self) -> float:
        return self.white_dps_rt_s * 60.0

    @property
    def bias_instability_deg_per_h(self) -> float:
        return self.floor_dps / 0.664 * 3600.0

    def sigma_dps(self, duration_s: FloatArray) -> FloatArray:
        """Expected scatter of the mean of a block of the given duration."""
        t = np.asarray(duration_s, dtype=float)
        return np.sqrt(self.white_dps_rt_s**2 / t + self.floor_dps**2)

    def block_covariance(self, blocks: Blocks) -> FloatArray:
        """Covariance of block-mean noise: white per block plus a Gauss-Markov bias wander."""
        cov = np.diag(self.white_dps_rt_s**2 / blocks.duration_s)
        if self.floor_dps > 0:
            s2 = (self.floor_dps / GM_PEAK_RATIO) ** 2
            dt = np.abs(blocks.center_s[:, None] - blocks.center_s[None, :])
            cov = cov + s2 * np.exp(-dt / self.correlation_time_s)
        return cov


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
    taus, avars = [], []
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
    tau = np.asarray(taus)
    avar = np.asarray(avars)
    # weighted fit of avar = N^2 / tau + F^2 with relative errors, non-negative terms
    design = np.stack([1.0 / tau, np.ones_like(tau)], axis=1) / avar[:, None]
    coef, _ = nnls(design, np.ones_like(tau))
    return NoiseModel(
        white_dps_rt_s=float(math.sqrt(coef[0])),
        floor_dps=float(math.sqrt(coef[1])),
        tau_s=tau,
        adev_dps=np.sqrt(avar),
    )
