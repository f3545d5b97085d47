"""Generalised least-squares fit of a gyro model to the block means of a record.

The model is linear in its coefficients once the time constants are fixed; those (sensor
lag, warm-up tau) are profiled: a log-spaced grid, then a bounded scalar search. Block
means are whitened with the Cholesky factor of the noise covariance (noise.py), so chi^2
is in units of the measured noise and the F tests of the workflow are meaningful.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import minimize_scalar

from procedures.model import effects as fx
from procedures.model.blocks import Blocks
from procedures.model.gyro_model import GyroModel, zero_params
from procedures.model.lag import lag_filter
from procedures.model.noise import NoiseModel
from procedures.model.trajectory import FloatArray, Trajectory

PROFILE_GRID_POINTS = 12
LAG_CACHE_ENTRIES = 600  # lagged block columns kept (term, time constants, lag tau)
SAMPLE_CACHE_VALUES = 8_000_000  # per-sample column values kept for the lag (64 MB)


@dataclass(frozen=True)
class FitResult:
    model: GyroModel
    chi2: float  # whitened residual sum of squares
    n_blocks: int
    n_params: int  # linear coefficients + profiled time constants
    residual_dps: FloatArray  # block-mean residual (measured - model), deg/s
    fitted_white: FloatArray  # whitened block-mean prediction, for comparing signatures

    @property
    def dof(self) -> int:
        return self.n_blocks - self.n_params

    @property
    def chi2_reduced(self) -> float:
        return self.chi2 / max(self.dof, 1)


@dataclass(frozen=True)
class _Solution:
    theta: FloatArray
    cov: FloatArray  # unscaled (X'X)^-1 in whitened units
    chi2: float
    fitted_white: FloatArray
    residual_dps: FloatArray
    layout: tuple[tuple[str, int, int], ...]  # (effect, first column, number of columns)
    x_block: FloatArray  # unwhitened block design


class Fitter:
    """Holds one record's block means and noise whitening; fits any model structure."""

    def __init__(self, traj: Trajectory, blocks: Blocks, noise: NoiseModel) -> None:
        self.traj = traj
        self.blocks = blocks
        self.noise = noise
        self._white_diag: FloatArray | None = None
        if noise.wander_dps <= 0 and noise.rrw_dps_per_rt_s <= 0:
            # white noise only: the covariance is diagonal, whitening a scaling (O(n))
            var = noise.white_dps_rt_s**2 / blocks.duration_s
            if not np.all(var > 0):
                raise ValueError(
                    "the noise covariance of the blocks is not positive definite; "
                    "the record may hold duplicated samples"
                )
            self._white_diag = 1.0 / np.sqrt(var)
        else:
            cov = noise.block_covariance(blocks)
            try:
                chol = np.linalg.cholesky(cov)
            except np.linalg.LinAlgError as exc:
                raise ValueError(
                    "the noise covariance of the blocks is not positive definite; "
                    "the record may hold duplicated samples"
                ) from exc
            # explicit inverse factor: one matrix product per solve is far cheaper than a
            # triangular solve call for the small systems here
            self._white = solve_triangular(chol, np.eye(chol.shape[0]), lower=True)
        self.y_block = blocks.mean(traj.gyro_dps)
        self.y_white = self._whiten(self.y_block)
        self._cache: dict[tuple[str, tuple[float, ...]], FloatArray] = {}
        self._lag_cache: dict[tuple[object, ...], FloatArray] = {}
        # whitening is linear and acts column by column: each term's whitened block columns
        # are kept beside its block columns, so a solve whitens only what it has not seen
        # (a candidate's own columns) instead of the whole design (n^2 per column, once)
        self._white_cache: dict[tuple[object, ...], FloatArray] = {}
        self._sample_cache: dict[tuple[str, tuple[float, ...]], FloatArray] = {}
        self._basis: tuple[tuple[object, ...], FloatArray] | None = None  # last base's Q

    def _whiten(self, x: FloatArray) -> FloatArray:
        if self._white_diag is not None:
            d = self._white_diag
            return d * x if x.ndim == 1 else d[:, None] * x
        return self._white @ x

    def whiten(self, x: FloatArray) -> FloatArray:
        """Block-mean values in units of the noise (the Cholesky factor's inverse applied)."""
        return self._whiten(x)

    def _sample_columns(self, effect_id: str, nl: Mapping[str, float]) -> FloatArray:
        if effect_id == "bias":
            return np.ones((self.traj.n, 1))
        if effect_id == "scale":
            return self.traj.ref_rate_dps[:, None]
        return fx.columns(effect_id, self.traj, nl)

    def _block_columns(self, effect_id: str, nl: Mapping[str, float]) -> FloatArray:
        key = (effect_id, tuple(sorted(nl.values())))
        if key not in self._cache:
            self._cache[key] = self.blocks.mean(self._sample_columns(effect_id, nl))
        return self._cache[key]

    def _white_block_columns(self, effect_id: str, nl: Mapping[str, float]) -> FloatArray:
        key = (effect_id, tuple(sorted(nl.values())))
        return self._white_columns(key, self._block_columns(effect_id, nl))

    def _white_columns(self, key: tuple[object, ...], block_cols: FloatArray) -> FloatArray:
        """The whitened block columns of one term (cached under the term's cache key)."""
        white = self._white_cache.get(key)
        if white is None:
            if len(self._white_cache) > LAG_CACHE_ENTRIES + len(self._cache):
                self._white_cache.clear()
            white = self._whiten(block_cols)
            self._white_cache[key] = white
        return white

    def _kept_sample_columns(self, effect_id: str, nl: Mapping[str, float]) -> FloatArray:
        """Per-sample columns of a term, kept while the lag is profiled (every trial time
        constant filters the same columns again); bounded to SAMPLE_CACHE_VALUES values."""
        key = (effect_id, tuple(sorted(nl.values())))
        cols = self._sample_cache.get(key)
        if cols is None:
            cols = self._sample_columns(effect_id, nl)
            if sum(c.size for c in self._sample_cache.values()) + cols.size > (
                SAMPLE_CACHE_VALUES
            ):
                self._sample_cache.clear()
            self._sample_cache[key] = cols
        return cols

    def _lagged_block_columns(
        self, terms: list[str], structure: Mapping[str, Mapping[str, float]], tau_s: float
    ) -> list[FloatArray]:
        """Block means of each term's columns passed through the lag. The lag is linear and
        acts column by column, so each term's filtered columns are kept (per time constant)
        and a candidate added to a lagged model filters only its own; the terms not yet
        kept are filtered together in one pass."""
        keys = [(e, tuple(sorted(structure.get(e, {}).values())), tau_s) for e in terms]
        # this solve's columns are taken out first: clearing a full cache below must not
        # lose the ones already kept (a KeyError once the cache had filled up)
        found = {k: self._lag_cache[k] for k in keys if k in self._lag_cache}
        todo = [(e, k) for e, k in zip(terms, keys, strict=True) if k not in found]
        if todo:
            if len(self._lag_cache) > LAG_CACHE_ENTRIES:
                self._lag_cache.clear()
            cols = [self._kept_sample_columns(e, structure.get(e, {})) for e, _ in todo]
            filtered = self.blocks.mean(
                lag_filter(np.concatenate(cols, axis=1), self.traj.time_s, tau_s)
            )
            first = 0
            for (_, key), c in zip(todo, cols, strict=True):
                found[key] = self._lag_cache[key] = filtered[:, first : first + c.shape[1]]
                first += c.shape[1]
        return [found[k] for k in keys]

    def solve(self, structure: Mapping[str, Mapping[str, float]]) -> _Solution:
        """Fit with fixed time constants; `structure` maps effect id -> nonlinear params."""
        terms = ["bias", "scale", *[e for e in structure if e != "sensor_lag"]]
        lag = structure.get("sensor_lag")
        layout = []
        first = 0
        keys: list[tuple[object, ...]]
        if lag is None:
            keys = [(e, tuple(sorted(structure.get(e, {}).values()))) for e in terms]
            blocks_cols = [self._block_columns(e, structure.get(e, {})) for e in terms]
        else:
            tau_s = float(lag["tau_s"])
            keys = [(e, tuple(sorted(structure.get(e, {}).values())), tau_s) for e in terms]
            blocks_cols = self._lagged_block_columns(terms, structure, tau_s)
        for e, c in zip(terms, blocks_cols, strict=True):
            layout.append((e, first, c.shape[1]))
            first += c.shape[1]
        x_block = np.concatenate(blocks_cols, axis=1)
        x_white = np.concatenate(
            [self._white_columns(k, c) for k, c in zip(keys, blocks_cols, strict=True)], axis=1
        )
        theta = np.asarray(np.linalg.lstsq(x_white, self.y_white, rcond=None)[0], dtype=float)
        fitted = x_white @ theta
        chi2 = float(np.sum((self.y_white - fitted) ** 2))
        cov = np.asarray(np.linalg.pinv(x_white.T @ x_white), dtype=float)
        return _Solution(
            theta=theta,
            cov=cov,
            chi2=chi2,
            fitted_white=fitted,
            residual_dps=self.y_block - x_block @ theta,
            layout=tuple(layout),
            x_block=x_block,
        )

    def design(self, model: GyroModel) -> FloatArray:
        """Block design of a model at its current time constants (for noise estimation)."""
        structure = {e: fx.nonlinear_of(e, p) for e, p in model.effects.items()}
        return self.solve(structure).x_block

    def column_rank_gain(self, base: Mapping[str, Mapping[str, float]], effect_id: str) -> float:
        """Fraction of an effect's whitened regressor not explained by the base model's."""
        if effect_id == "sensor_lag":
            # a lag shows only where the rate changes; without such windows it is invisible
            return 1.0 if self.blocks.has_motion_changes else 0.0
        nl = fx.nonlinear_of(effect_id, zero_params(effect_id))
        terms = [e for e in ["bias", "scale", *base] if e != "sensor_lag"]
        key = tuple((e, tuple(sorted(base.get(e, {}).items()))) for e in terms)
        if self._basis is None or self._basis[0] != key:
            xb = np.concatenate([self._white_block_columns(e, base.get(e, {})) for e in terms],
                                axis=1)
            self._basis = (key, np.linalg.qr(xb)[0])
        q = self._basis[1]
        xc = self._white_block_columns(effect_id, nl)
        resid = xc - q @ (q.T @ xc)
        norms = np.maximum(np.linalg.norm(xc, axis=0), 1e-300)
        return float(np.min(np.linalg.norm(resid, axis=0) / norms))

    def fit(
        self, model: GyroModel, profile: Collection[str] | None = None, local: bool = False
    ) -> FitResult:
        """Fit every linear parameter of the model's structure and profile its time
        constants: all of them (profile=None) or only those named, the others held at the
        model's values; `local` searches near the model's values instead of the whole range.
        """
        structure: dict[str, dict[str, float]] = {
            e: fx.nonlinear_of(e, p) for e, p in model.effects.items()
        }
        profiled = [e for e in structure if fx.check_effect_id(e).nonlinear]
        to_profile = profiled if profile is None else [e for e in profiled if e in profile]
        tau_sigma: dict[str, float] = {}
        for _round in range(2 if len(to_profile) > 1 else 1):
            for e in to_profile:
                structure[e]["tau_s"] = self._profile(structure, e, local)
        for e in profiled if profile is None else to_profile:  # candidates: their own only
            tau_sigma[e] = self._tau_sigma(structure, e)
        sol = self.solve(structure)
        n_params = sol.theta.size + len(profiled)
        dof = max(self.blocks.count - n_params, 1)
        inflate = max(1.0, sol.chi2 / dof)
        cov = sol.cov * inflate
        fitted_model = self._to_model(model, sol, cov, structure, tau_sigma, inflate)
        return FitResult(
            model=fitted_model,
            chi2=sol.chi2,
            n_blocks=self.blocks.count,
            n_params=n_params,
            residual_dps=sol.residual_dps,
            fitted_white=sol.fitted_white,
        )

    def _profile(
        self, structure: dict[str, dict[str, float]], effect_id: str, local: bool
    ) -> float:
        lo, hi = fx.TAU_RANGE_S[effect_id]

        def chi2_at(log_tau: float) -> float:
            trial = {k: dict(v) for k, v in structure.items()}
            trial[effect_id]["tau_s"] = math.exp(log_tau)
            return self.solve(trial).chi2

        if local:
            here = math.log(structure[effect_id]["tau_s"])
            grid = np.clip(here + np.linspace(-0.7, 0.7, 5), math.log(lo), math.log(hi))
        else:
            grid = np.linspace(math.log(lo), math.log(hi), PROFILE_GRID_POINTS)
        values = [chi2_at(g) for g in grid]
        i = int(np.argmin(values))
        a = grid[max(i - 1, 0)]
        b = grid[min(i + 1, grid.size - 1)]
        res = minimize_scalar(chi2_at, bounds=(a, b), method="bounded", options={"xatol": 5e-3})
        best = float(res.x) if res.fun <= values[i] else float(grid[i])
        return math.exp(best)

    def _tau_sigma(self, structure: dict[str, dict[str, float]], effect_id: str) -> float:
        tau = structure[effect_id]["tau_s"]
        h = 0.05
        vals = []
        for d in (-h, 0.0, h):
            trial = {k: dict(v) for k, v in structure.items()}
            trial[effect_id]["tau_s"] = tau * math.exp(d)
            vals.append(self.solve(trial).chi2)
        curv = (vals[0] - 2 * vals[1] + vals[2]) / h**2
        return tau * math.sqrt(2.0 / curv) if curv > 0 else math.inf

    def _to_model(
        self,
        model: GyroModel,
        sol: _Solution,
        cov: FloatArray,
        structure: Mapping[str, Mapping[str, float]],
        tau_sigma: Mapping[str, float],
        inflate: float,
    ) -> GyroModel:
        layout = {e: (a, k) for e, a, k in sol.layout}
        bias = float(sol.theta[layout["bias"][0]])
        scale = float(sol.theta[layout["scale"][0]])
        # a design near rank-deficient (e.g. one rate magnitude, two temperatures) can leave
        # a rounding-negative variance in the pseudo-inverse: zero, as the effects' own are
        unc = {
            "bias_dps": math.sqrt(max(float(cov[layout["bias"][0], layout["bias"][0]]), 0.0)),
            "scale": math.sqrt(max(float(cov[layout["scale"][0], layout["scale"][0]]), 0.0)),
        }
        effects: dict[str, dict[str, float]] = {}
        for e, old in model.effects.items():
            a, k = layout.get(e, (0, 0))
            params, sig = fx.to_params(
                e,
                sol.theta[a : a + k],
                cov[a : a + k, a : a + k],
                structure.get(e, {}),
                scale,
                tilt_deg=float(old.get("tilt_deg", fx.DEFAULT_TILT_DEG)),
            )
            effects[e] = params
            for p, s in sig.items():
                unc[f"{e}.{p}"] = s
            if e in tau_sigma:
                unc[f"{e}.tau_s"] = tau_sigma[e] * math.sqrt(inflate)
        return GyroModel(
            name=model.name, bias_dps=bias, scale=scale, effects=effects, uncertainties=unc
        )
