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
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import minimize

from procedures.model.blocks import Blocks
from procedures.model.markov_cov import MarkovCovariance
from procedures.model.noise import (
    GM_CORRELATION_TIMES_S,
    GM_SIGMA_PER_F,
    WANDER_MARGIN,
    NoiseModel,
)
from procedures.model.trajectory import FloatArray

LOG_BOUNDS = (-16.0, -2.0)  # natural log of F (deg/s) and K (deg/s/sqrt(s))
# design directions below this fraction of the largest (white-whitened) singular value are
# exact collinearities of the full model, dropped before the Markov-form likelihood
COLLINEAR_RATIO = 1e-12


def _neg2_loglik(cov: FloatArray, x: FloatArray, y: FloatArray) -> float:
    try:
        chol = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return math.inf
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
    """F and K by REML given the model's block design; N is kept from the Allan fit.

    The restricted likelihood is evaluated through the covariance's Markov structure
    (markov_cov.py) in O(n) per evaluation; records whose block centres are not distinct
    fall back to the dense Cholesky form (O(n^3))."""
    try:
        objective = _markov_objective(noise, blocks, design_block, y_block)
    except ValueError:
        objective = _dense_objective(noise, blocks, design_block, y_block)
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


def _dense_objective(
    noise: NoiseModel, blocks: Blocks, design_block: FloatArray, y_block: FloatArray
) -> Callable[[FloatArray], float]:
    """-2 l(log F, log K) with the dense covariance (Cholesky, O(n^3) per evaluation)."""
    white = replace(noise, floor_dps=0.0, rrw_dps_per_rt_s=0.0)
    c_white = white.block_covariance(blocks)
    c_flick = replace(white, floor_dps=1.0).block_covariance(blocks) - c_white
    c_walk = replace(white, rrw_dps_per_rt_s=1.0).block_covariance(blocks) - c_white

    def objective(p: FloatArray) -> float:
        lf, lk = np.clip(p, *LOG_BOUNDS)
        cov = c_white + math.exp(2 * lf) * c_flick + math.exp(2 * lk) * c_walk
        return _neg2_loglik(cov, design_block, y_block)

    return objective


def _markov_objective(
    noise: NoiseModel, blocks: Blocks, design_block: FloatArray, y_block: FloatArray
) -> Callable[[FloatArray], float]:
    """-2 l(log F, log K) through the Markov form, equal to the dense one to rounding.

    The design is first reduced to its numerical range (exactly collinear columns of the
    full model dropped, from the design whitened by the white noise alone) and scaled to
    unit whitened norm, so its Gram matrix under C is well conditioned; the response is
    replaced by its white-noise residual (the REML residual is unchanged by adding
    combinations of the columns), so r' C^-1 r is not a small difference of large numbers.
    The singular values of the C-whitened design, which the dense form thresholds, are
    recovered from the reduced Gram matrix's Cholesky factor and the reduction."""
    white_var = noise.white_dps_rt_s**2 / blocks.duration_s
    gm_unit = (GM_SIGMA_PER_F * WANDER_MARGIN) ** 2  # per-process variance per F^2
    markov = MarkovCovariance(white_var, blocks.center_s, GM_CORRELATION_TIMES_S)
    x = np.asarray(design_block, dtype=float)
    y = np.asarray(y_block, dtype=float)
    sd = np.sqrt(white_var)
    _, sv, vt = np.linalg.svd(x / sd[:, None], full_matrices=False)
    keep = sv > COLLINEAR_RATIO * sv[0]
    x_red = x @ (vt[keep].T / sv[keep])
    back = sv[keep, None] * vt[keep]  # x = x_red @ back (on the kept directions)
    theta = np.linalg.lstsq(x_red / sd[:, None], y / sd, rcond=None)[0]
    z = np.column_stack([x_red, y - x_red @ theta])
    k = x_red.shape[1]

    def objective(p: FloatArray) -> float:
        lf, lk = np.clip(p, *LOG_BOUNDS)
        try:
            g = markov.gram(z, gm_unit * math.exp(2 * lf), math.exp(2 * lk))
            chol = np.linalg.cholesky(g.gram[:k, :k])
        except np.linalg.LinAlgError:
            return math.inf
        u = solve_triangular(chol, g.gram[:k, k], lower=True, check_finite=False)
        # C-whitened design = Q (chol' back), Q orthonormal; Q' of the whitened residual
        # z_y is u, of the whitened response u + chol' theta
        left, sv_c, _ = np.linalg.svd(chol.T @ back, full_matrices=False)
        kept = sv_c > 1e-9 * sv_c[0]  # the dense form's threshold
        dropped = left[:, ~kept].T @ (u + chol.T @ theta)
        rr = float(g.gram[k, k] - u @ u + dropped @ dropped)
        logdet_xx = 2.0 * float(np.sum(np.log(sv_c[kept])))
        return g.logdet_cov + logdet_xx + rr

    return objective
