"""Slow noise (bias wander, rate random walk) estimated from the residuals between blocks.

Windows of tens of seconds cannot show the Allan deviation beyond a few tens of seconds, yet
over a run of an hour the bias wanders (flicker, rate random walk) by more than the white
noise of a block mean. With the white level N fixed from the Allan deviation, the flat level F
and the rate random walk K are estimated by restricted maximum likelihood (REML) from the
block-mean residuals of the full model (every catalog effect, see discrepancy.py):

    -2 l = log|C| + log|X' C^-1 X| + r' C^-1 r,   C = C_white + F^2 C_flicker + K^2 C_walk

REML accounts for the degrees of freedom used by the model's coefficients. Using the full
model keeps an effect the current model lacks from being taken for wander.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.optimize import minimize

from procedures.model.blocks import Blocks
from procedures.model.noise import NoiseModel
from procedures.model.trajectory import FloatArray

LOG_BOUNDS = (-16.0, -2.0)  # natural log of F (deg/s) and K (deg/s/sqrt(s))


def _neg2_loglik(cov: FloatArray, x: FloatArray, y: FloatArray) -> float:
    try:
        chol = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return math.inf
    from scipy.linalg import solve_triangular

    xw = solve_triangular(chol, x, lower=True, check_finite=False)
    yw = solve_triangular(chol, y, lower=True, check_finite=False)
    u, sv, _ = np.linalg.svd(xw, full_matrices=False)
    keep = sv > 1e-9 * sv[0]  # the full model may hold collinear columns
    u = u[:, keep]
    r = yw - u @ (u.T @ yw)
    logdet_xx = 2 * float(np.sum(np.log(sv[keep])))
    return float(2 * np.sum(np.log(np.diag(chol))) + logdet_xx + r @ r)


def estimate_slow_noise(
    noise: NoiseModel, blocks: Blocks, design_block: FloatArray, y_block: FloatArray
) -> NoiseModel:
    """F and K by REML given the model's block design; N is kept from the Allan fit."""
    white = replace(noise, floor_dps=0.0, rrw_dps_per_rt_s=0.0)
    c_white = white.block_covariance(blocks)
    c_flick = replace(white, floor_dps=1.0).block_covariance(blocks) - c_white
    c_walk = replace(white, rrw_dps_per_rt_s=1.0).block_covariance(blocks) - c_white

    def objective(p: FloatArray) -> float:
        lf, lk = np.clip(p, *LOG_BOUNDS)
        cov = c_white + math.exp(2 * lf) * c_flick + math.exp(2 * lk) * c_walk
        return _neg2_loglik(cov, design_block, y_block)

    f0 = max(noise.floor_dps, 1e-5)
    starts = [np.array([math.log(f0), math.log(1e-5)]),
              np.array([math.log(f0 * 3), math.log(1e-4)])]
    best = None
    for x0 in starts:
        res = minimize(objective, x0, method="Nelder-Mead",
                       options={"xatol": 0.05, "fatol": 0.05, "maxiter": 200})
        if best is None or res.fun < best.fun:
            best = res
    assert best is not None
    lf, lk = np.clip(best.x, *LOG_BOUNDS)
    f = math.exp(lf) if lf > LOG_BOUNDS[0] + 0.5 else 0.0
    k = math.exp(lk) if lk > LOG_BOUNDS[0] + 0.5 else 0.0
    return replace(noise, floor_dps=f, rrw_dps_per_rt_s=k, slow_from="reml")
