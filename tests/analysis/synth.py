"""Synthetic gyro records with known truth, generated inside the tests (no data files)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def nbs14_1000() -> NDArray[np.float64]:
    """NIST SP 1065's 1000-point NBS14 test set, from its generator (not a copied file)."""
    n = 1234567890
    out = np.empty(1000)
    for i in range(1000):
        out[i] = n / 2147483647.0
        n = (16807 * n) % 2147483647
    return out


def flicker(
    rng: np.random.Generator, n: int, bias_instability_dps: float
) -> NDArray[np.float64]:
    """Flicker (1/f) rate noise with the IEEE 952 bias instability B (ADEV plateau 0.664 B).

    Kasdin-Walter: white noise of variance B^2 through (1 - z^-1)^(-1/2), whose one-sided PSD
    at low frequency is B^2 / (pi f), the IEEE 952 two-sided B^2 / (2 pi f).
    """
    k = np.arange(1, n)
    h = np.concatenate([[1.0], np.cumprod((k - 0.5) / k)])
    w = rng.standard_normal(n) * bias_instability_dps
    size = 1 << int(np.ceil(np.log2(2 * n)))
    return np.fft.irfft(np.fft.rfft(w, size) * np.fft.rfft(h, size), size)[:n]


def gyro_noise(
    rng: np.random.Generator,
    n: int,
    sample_rate_hz: float,
    arw_deg_per_sqrt_h: float = 0.0,
    bias_instability_deg_per_h: float = 0.0,
) -> NDArray[np.float64]:
    """White (ARW) plus flicker (bias instability) rate noise in deg/s."""
    sigma_white = arw_deg_per_sqrt_h / 60.0 * np.sqrt(sample_rate_hz)
    out = sigma_white * rng.standard_normal(n)
    if bias_instability_deg_per_h:
        out += flicker(rng, n, bias_instability_deg_per_h / 3600.0)
    return out


def raised_cosine(
    t: NDArray[np.float64], start_s: float, duration_s: float, angle_deg: float
) -> NDArray[np.float64]:
    """A smooth move: rate profile 1 - cos over [start, start + duration] integrating to angle."""
    x = (t - start_s) / duration_s
    shape = np.where((x >= 0.0) & (x <= 1.0), 1.0 - np.cos(2.0 * np.pi * x), 0.0)
    return shape * angle_deg / duration_s


def article_record(
    rng: np.random.Generator,
    sample_rate_hz: float = 100.0,
    noise_dps: float = 0.02,
    bias_dps: float = 8.6,
    out_deg: float = 95.1,
    back_deg: float = -95.3,
    bounce_deg: float = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A record shaped like the article's Figure 4: static to 4.5 s, a 3.5 s move out,
    static, a 3.5 s move back from 12.5 s, static to 21 s. Angles are bias-corrected
    integrals. A bounce can follow each arrival: the part rebounds off the stop by up to
    `bounce_deg` and settles back on it, so its net angle is zero."""
    t = np.arange(0.0, 21.0, 1.0 / sample_rate_hz)
    y = bias_dps + raised_cosine(t, 4.5, 3.5, out_deg) + raised_cosine(t, 12.5, 3.5, back_deg)
    if bounce_deg:
        omega, tau = 2.0 * np.pi / 0.15, 0.1
        for arrive, rebound in ((8.0, -np.sign(out_deg)), (16.0, -np.sign(back_deg))):
            s = np.maximum(t - arrive, 0.0)
            # angle = a sin^2(omega s / 2) exp(-s / tau): smooth, away from the stop and back
            rate = bounce_deg * np.exp(-s / tau) * (
                0.5 * omega * np.sin(omega * s) - np.sin(0.5 * omega * s) ** 2 / tau)
            y += rebound * rate
    return t, y + noise_dps * rng.standard_normal(t.size)
