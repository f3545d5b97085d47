"""The block-noise covariance as a Markov (state-space) model, for O(n) algebra.

The covariance of block-mean noise (noise.py) is white noise on the diagonal plus three
Gauss-Markov processes and a rate random walk sampled at the block centres:

    C = D + sum_k s2 exp(-|t_i - t_j| / tau_k) + K^2 min(t_i - t0, t_j - t0)

Each slow process is a first-order Markov chain over the blocks in time order, so with the
latent states z (three Gauss-Markov values per block, and the walk from the second block on;
the walk is zero at the first block) C = D + H P H' with P^-1 block-tridiagonal. Woodbury and
the matrix determinant lemma then give, with the banded M = P^-1 + H' D^-1 H (bandwidth 4),

    Z' C^-1 Z = Z' D^-1 Z - (H' D^-1 Z)' M^-1 (H' D^-1 Z)
    log|C|    = log|D| + log|P| + log|M|

in O(n) per evaluation instead of the O(n^3) of a dense Cholesky factorisation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_solve_banded, cholesky_banded

from procedures.model.trajectory import FloatArray

BANDWIDTH = 4  # latent states per block; neighbours in time are 4 apart


@dataclass(frozen=True)
class MarkovGram:
    """Z' C^-1 Z and log|C| for one covariance."""

    gram: FloatArray
    logdet_cov: float


class MarkovCovariance:
    """Blocks' white variances and centres; evaluates C^-1 forms for any slow levels."""

    def __init__(
        self, white_var: FloatArray, center_s: FloatArray, correlation_times_s: Sequence[float]
    ) -> None:
        order = np.argsort(center_s, kind="stable")
        t = np.asarray(center_s, dtype=float)[order]
        dt = np.diff(t)
        if t.size < 2 or np.any(dt <= 0) or not np.all(np.isfinite(t)):
            raise ValueError("block centres must be distinct and finite for the Markov form")
        if len(correlation_times_s) != 3:
            raise ValueError("the Markov form holds exactly three Gauss-Markov processes")
        self.order = order
        self.n = int(t.size)
        self.white_var = np.asarray(white_var, dtype=float)[order]
        self.dt_s = dt
        self.taus_s = tuple(float(x) for x in correlation_times_s)
        n = self.n
        self.m = 4 * n - 1  # latent states: g1..g3 of block 0, then (w, g1, g2, g3) per block
        gm_index = np.empty((3, n), dtype=np.int64)
        gm_index[:, 0] = np.arange(3)
        gm_index[:, 1:] = 4 * np.arange(1, n)[None, :] + np.arange(3)[:, None]
        self.gm_index = gm_index
        self.walk_index = 4 * np.arange(1, n) - 1  # walk state of blocks 1..n-1
        block_of = np.empty(self.m, dtype=np.int64)
        for k in range(3):
            block_of[gm_index[k]] = np.arange(n)
        block_of[self.walk_index] = np.arange(1, n)
        self.block_of = block_of
        # the observation part H' D^-1 H: every pair of states of one block gets 1/d_b
        rows, cols = [], []
        for a in range(self.m):
            for off in range(BANDWIDTH + 1):
                b = a + off
                if b < self.m and block_of[b] == block_of[a]:
                    rows.append(b)
                    cols.append(a)
        r = np.asarray(rows, dtype=np.int64)
        c = np.asarray(cols, dtype=np.int64)
        self._obs_banded = np.zeros((BANDWIDTH + 1, self.m))
        np.add.at(self._obs_banded, (r - c, c), 1.0 / self.white_var[block_of[r]])

    def _chains(self, gm_var: float, walk_var_rate: float) -> list[tuple[
            NDArray[np.int64], FloatArray, FloatArray, float]]:
        """Each slow process as (state indices in time order, transition factors a_i and
        innovation variances q_i for i >= 1, variance of its first state; 0 for the walk,
        which starts from zero and whose first listed state is one increment away)."""
        chains = []
        for k, tau in enumerate(self.taus_s):
            a = np.exp(-self.dt_s / tau)
            q = -gm_var * np.expm1(-2.0 * self.dt_s / tau)
            chains.append((self.gm_index[k], a, q, gm_var))
        q = walk_var_rate * self.dt_s
        chains.append((self.walk_index, np.ones(q.size - 1), q, 0.0))
        return chains

    def _banded(self, chains: list[tuple[NDArray[np.int64], FloatArray, FloatArray, float]]
                ) -> tuple[FloatArray, float]:
        """M in lower banded storage and log|P|."""
        ab = self._obs_banded.copy()
        logdet_p = 0.0
        for idx, a, q, var0 in chains:
            if var0 > 0:  # Gauss-Markov: x_0 ~ N(0, var0), x_i = a_i x_(i-1) + e_i
                ab[0, idx[0]] += 1.0 / var0
                ab[0, idx[1:]] += 1.0 / q
                ab[0, idx[:-1]] += a * a / q
                ab[BANDWIDTH, idx[:-1]] += -a / q
                logdet_p += math.log(var0) + float(np.sum(np.log(q)))
            else:  # walk: w_1 ~ N(0, q_0), w_i = w_(i-1) + e_i
                ab[0, idx] += 1.0 / q
                ab[0, idx[:-1]] += 1.0 / q[1:]
                ab[BANDWIDTH, idx[:-1]] += -1.0 / q[1:]
                logdet_p += float(np.sum(np.log(q)))
        return ab, logdet_p

    def gram(self, z: FloatArray, gm_var: float, walk_var_rate: float) -> MarkovGram:
        """Z' C^-1 Z and log|C| with per-process Gauss-Markov variance `gm_var` (> 0) and
        walk variance per second `walk_var_rate` (> 0). Raises LinAlgError if M is not
        positive definite.

        Z' C^-1 Z is not formed as the Woodbury difference (which loses most digits when
        the wander dwarfs the white noise) but as the minimum of the smoothing problem,
        min_s (z - H s)' D^-1 (z - H s) + s' P^-1 s, a sum of squares at the smoothed
        states s = M^-1 H' D^-1 z; being a minimum, it is insensitive to first order to
        the rounding of s."""
        zs = np.asarray(z, dtype=float)[self.order]
        sd = np.sqrt(self.white_var)
        chains = self._chains(gm_var, walk_var_rate)
        ab, logdet_p = self._banded(chains)
        chol = cholesky_banded(ab, lower=True, check_finite=False)
        smooth = cho_solve_banded((chol, True), (zs / self.white_var[:, None])[self.block_of],
                                  check_finite=False)
        fitted = smooth[self.gm_index[0]] + smooth[self.gm_index[1]] + smooth[self.gm_index[2]]
        fitted[1:] += smooth[self.walk_index]
        parts = [(zs - fitted) / sd[:, None]]
        for idx, a, q, var0 in chains:
            s = smooth[idx]
            if var0 > 0:
                parts.append(s[:1] / math.sqrt(var0))
                parts.append((s[1:] - a[:, None] * s[:-1]) / np.sqrt(q)[:, None])
            else:
                parts.append(s[:1] / math.sqrt(q[0]))
                parts.append((s[1:] - s[:-1]) / np.sqrt(q[1:])[:, None])
        e = np.concatenate(parts, axis=0)
        logdet = float(np.sum(np.log(self.white_var))) + logdet_p + \
            2.0 * float(np.sum(np.log(chol[0])))
        return MarkovGram(gram=e.T @ e, logdet_cov=logdet)
