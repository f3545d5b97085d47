"""Three-axis calibration fit: bias vector, correction matrix, g-sensitivity and per-axis
first-order temperature and supply coefficients, from windows measured in cube orientations.

The product's convention (docs/three-axis.md), part frame, deg/s and m/s^2:

    raw = S(T, V) w + b(T, V) + G a,      S = P D(T, V),  P = M^-1
    D   = diag(1 + sT_j dT + sV_j dV),    b(T, V) = b + bT dT + bV dV   (per axis)

Each window is the mean raw output over a stretch at rest (w = 0) or on a table-rate
plateau (w = r e_up, the table axis along the face that points up), with the mean
accelerometer reading a and the die temperature and supply during it. All windows, at all
conditions, enter one weighted least-squares fit of the 33 parameters (b, bT, bV, G, P, sT,
sV) by Gauss-Newton (the model is bilinear in P and sT/sV); the weights are the windows' own
k=1 uncertainties, not rescaled by the scatter, so the covariance is the propagated
measurement uncertainty, as in the single-axis fit (procedures/analysis/temp_supply_fit.py).
M = P^-1 and its covariance follow through the Jacobian dM = -M dP M.

When every window is at the reference condition (one temperature, one supply), the
temperature and supply terms are left out and reported as zero with no uncertainty.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import solve_triangular

from procedures.analysis.bias_wander import window_mean_covariance
from procedures.analysis.errors import AnalysisError

FloatArray = NDArray[np.float64]

REFERENCE_TEMPERATURE_C = 25.0
REFERENCE_SUPPLY_V = 5.0
_MIN_SPREAD_C = 1.0  # less temperature spread than this: no temperature terms
_MIN_SPREAD_V = 0.02
_MAX_ITERATIONS = 8

# Parameter blocks, in order, with their sizes (the covariance's index layout).
BLOCKS: tuple[tuple[str, int], ...] = (
    ("bias_dps", 3),
    ("g_sensitivity_dps_per_mps2", 9),
    ("sensitivity_matrix", 9),  # P = M^-1, row-major
    ("bias_temp_coeff_dps_per_c", 3),
    ("bias_supply_coeff_dps_per_v", 3),
    ("scale_temp_coeff_per_c", 3),
    ("scale_supply_coeff_per_v", 3),
)
VECTOR_NAMES = (
    "bias_dps",
    "bias_temp_coeff_dps_per_c",
    "bias_supply_coeff_dps_per_v",
    "scale_temp_coeff_per_c",
    "scale_supply_coeff_per_v",
)
MATRIX_NAMES = ("matrix", "g_sensitivity_dps_per_mps2")


def _offsets() -> dict[str, slice]:
    out: dict[str, slice] = {}
    i = 0
    for name, n in BLOCKS:
        out[name] = slice(i, i + n)
        i += n
    return out


_SLICE = _offsets()
_N_FULL = sum(n for _, n in BLOCKS)
_N_STATIC = 21  # b, G, P only


@dataclass(frozen=True)
class Window:
    """Mean outputs over one window; u_rate_dps is the k=1 uncertainty of each axis's mean.

    table_rate_dps is 0 for a window at rest; otherwise the part turns at that rate about
    the axis named by `face` (the face pointing up along the table axis)."""

    face: str  # "+x" ... "-z"
    table_rate_dps: float
    rate_dps: tuple[float, float, float]
    u_rate_dps: tuple[float, float, float]
    accel_mps2: tuple[float, float, float]
    temp_c: float
    supply_v: float
    condition: str = ""
    start_s: float = math.nan  # fixture time of the window (raw.h5 /segments), when known
    end_s: float = math.nan
    # the part's bias instability (deg/s, each axis): its wander is shared between windows
    # close in time (procedures/analysis/bias_wander.py); 0: the windows' own u_rate_dps only
    bias_instability_dps: float = 0.0
    rate_random_walk_dps_per_sqrt_s: float = 0.0  # the same for the bias's random walk

    def __post_init__(self) -> None:
        for name in ("rate_dps", "u_rate_dps", "accel_mps2"):
            v = tuple(float(x) for x in np.asarray(getattr(self, name), dtype=float).reshape(3))
            object.__setattr__(self, name, v)
        values = [*self.rate_dps, *self.u_rate_dps, *self.accel_mps2, self.temp_c,
                  self.supply_v, self.table_rate_dps]
        if not all(math.isfinite(x) for x in values):
            raise AnalysisError(
                f"window at face {self.face} holds NaN or infinite values: measure it again"
            )
        if min(self.u_rate_dps) <= 0:
            raise AnalysisError(f"window at face {self.face} needs positive u_rate_dps")
        if not (self.bias_instability_dps >= 0 and self.rate_random_walk_dps_per_sqrt_s >= 0):
            raise AnalysisError(f"window at face {self.face}: bias_instability_dps and "
                                "rate_random_walk_dps_per_sqrt_s must be >= 0")


def up_vector(face: str) -> FloatArray:
    name = str(face).strip().lower()
    if len(name) != 2 or name[0] not in "+-" or name[1] not in "xyz":
        raise AnalysisError(f"face {face!r} is not one of +x, -x, +y, -y, +z, -z")
    e = np.zeros(3)
    e["xyz".index(name[1])] = 1.0 if name[0] == "+" else -1.0
    return e


@dataclass(frozen=True)
class ThreeAxisCalibration:
    """The fitted calibration and the covariance of its parameters (k=1)."""

    bias_dps: FloatArray
    matrix: FloatArray  # M, rows the output axes
    g_sensitivity_dps_per_mps2: FloatArray
    bias_temp_coeff_dps_per_c: FloatArray
    bias_supply_coeff_dps_per_v: FloatArray
    scale_temp_coeff_per_c: FloatArray
    scale_supply_coeff_per_v: FloatArray
    u_k1: dict[str, FloatArray]  # k=1 uncertainty of each element, same shapes
    chi2: float
    dof: int
    temp_supply_fitted: bool
    reference_temperature_c: float = REFERENCE_TEMPERATURE_C
    reference_supply_v: float = REFERENCE_SUPPLY_V
    notes: tuple[str, ...] = field(default_factory=tuple)
    # the windows' mean die temperature and supply: without temperature and supply terms,
    # b and M are the part's at these (not at the reference)
    mean_temp_c: float = REFERENCE_TEMPERATURE_C
    mean_supply_v: float = REFERENCE_SUPPLY_V

    def value(self, name: str) -> FloatArray:
        return np.asarray(getattr(self, name), dtype=np.float64)

    def uncertainty_k2(self, name: str) -> FloatArray:
        return 2.0 * self.u_k1[name]

    def misalignment(self) -> FloatArray:
        """Off-diagonal of M normalised by its row's diagonal (rad, small angle)."""
        m = self.matrix
        out = m / np.diag(m)[:, None]
        np.fill_diagonal(out, 0.0)
        return np.asarray(out)

    def scale_error(self) -> FloatArray:
        """Per-axis scale error of the raw output, 1/M_ii - 1 (fraction)."""
        return np.asarray(1.0 / np.diag(self.matrix) - 1.0)

    def as_calibration_dict(self) -> dict[str, object]:
        """The three-axis `calibration` block of record.json (values with k=2 uncertainties)."""
        out: dict[str, object] = {"axes": 3}
        for name in (*VECTOR_NAMES, *MATRIX_NAMES):
            out[name] = {
                "value": self.value(name).tolist(),
                "uncertainty_k2": self.uncertainty_k2(name).tolist(),
            }
        out["reference_temperature_c"] = self.reference_temperature_c
        out["reference_supply_v"] = self.reference_supply_v
        out["temp_supply_fitted"] = self.temp_supply_fitted
        out["mean_die_temperature_c"] = self.mean_temp_c
        out["mean_supply_v"] = self.mean_supply_v
        out["fit_chi2"] = self.chi2
        out["fit_dof"] = self.dof
        return out


def _arrays(windows: Sequence[Window], t0_c: float, v0_v: float) -> dict[str, FloatArray]:
    return {
        "raw": np.array([w.rate_dps for w in windows], dtype=np.float64),
        "u": np.array([w.u_rate_dps for w in windows], dtype=np.float64),
        "acc": np.array([w.accel_mps2 for w in windows], dtype=np.float64),
        "w": np.array([w.table_rate_dps * up_vector(w.face) for w in windows]),
        "dt": np.array([w.temp_c - t0_c for w in windows], dtype=np.float64),
        "dv": np.array([w.supply_v - v0_v for w in windows], dtype=np.float64),
    }


def _unpack(p: FloatArray) -> dict[str, FloatArray]:
    out = {name: p[_SLICE[name]] for name, _ in BLOCKS if _SLICE[name].stop <= len(p)}
    for name, _ in BLOCKS:
        out.setdefault(name, np.zeros(3))
    return out


def _model(p: FloatArray, d: dict[str, FloatArray]) -> tuple[FloatArray, FloatArray]:
    """Predicted raw (n, 3) and the Jacobian (n*3, len(p)), rows window-major."""
    q = _unpack(p)
    g = q["g_sensitivity_dps_per_mps2"].reshape(3, 3)
    pm = q["sensitivity_matrix"].reshape(3, 3)
    dt, dv = d["dt"][:, None], d["dv"][:, None]
    scale = 1.0 + q["scale_temp_coeff_per_c"] * dt + q["scale_supply_coeff_per_v"] * dv
    ws = d["w"] * scale  # (n, 3): D w
    bias = (q["bias_dps"] + q["bias_temp_coeff_dps_per_c"] * dt
            + q["bias_supply_coeff_dps_per_v"] * dv)
    pred = ws @ pm.T + bias + d["acc"] @ g.T
    n = len(dt)
    jac = np.zeros((n, 3, len(p)))
    eye = np.eye(3)
    for i in range(3):
        jac[:, i, _SLICE["bias_dps"].start + i] = 1.0
        jac[:, i, _SLICE["g_sensitivity_dps_per_mps2"].start + 3 * i:
            _SLICE["g_sensitivity_dps_per_mps2"].start + 3 * i + 3] = d["acc"]
        jac[:, i, _SLICE["sensitivity_matrix"].start + 3 * i:
            _SLICE["sensitivity_matrix"].start + 3 * i + 3] = ws
        if len(p) > _N_STATIC:
            jac[:, i, _SLICE["bias_temp_coeff_dps_per_c"]] = eye[i] * dt
            jac[:, i, _SLICE["bias_supply_coeff_dps_per_v"]] = eye[i] * dv
            jac[:, i, _SLICE["scale_temp_coeff_per_c"]] = pm[i] * d["w"] * dt
            jac[:, i, _SLICE["scale_supply_coeff_per_v"]] = pm[i] * d["w"] * dv
    return pred, jac.reshape(n * 3, len(p))


def _check_design(d: dict[str, FloatArray]) -> None:
    at_rest = ~np.any(d["w"] != 0.0, axis=1)
    if not np.any(at_rest) and not np.any(~at_rest):
        raise AnalysisError("no windows given: measure at rest and on table rates in each face")
    gravity = np.column_stack([np.ones(len(d["acc"])), d["acc"] / 9.80665])
    sv = np.linalg.svd(gravity, compute_uv=False)
    if len(sv) < 4 or sv[-1] < 0.05 * sv[0]:
        raise AnalysisError(
            "the accelerometer readings do not separate bias from g-sensitivity: measure at "
            "rest in all six faces (gravity along +x, -x, +y, -y, +z and -z)"
        )
    turned = {int(np.argmax(np.abs(w))) for w in d["w"][~at_rest]}
    missing = [("xyz")[i] for i in range(3) if i not in turned]
    if missing:
        raise AnalysisError(
            f"no table-rate window about axis {', '.join(missing)}: turn the part with that "
            "axis up and measure at +r and -r"
        )


def fit_three_axis(
    windows: Sequence[Window],
    reference_temperature_c: float = REFERENCE_TEMPERATURE_C,
    reference_supply_v: float = REFERENCE_SUPPLY_V,
) -> ThreeAxisCalibration:
    """Fit b, M, G (and per-axis temperature/supply coefficients when the windows span
    temperature and supply) to windows from the cube's faces; raises AnalysisError when
    the windows cannot separate them (the message says which measurement is missing)."""
    d = _arrays(windows, reference_temperature_c, reference_supply_v)
    _check_design(d)
    with_tv = bool(np.ptp(d["dt"]) >= _MIN_SPREAD_C and np.ptp(d["dv"]) >= _MIN_SPREAD_V)
    n_par = _N_FULL if with_tv else _N_STATIC
    p = np.zeros(n_par)
    p[_SLICE["sensitivity_matrix"]] = np.eye(3).ravel()
    y = d["raw"].ravel()
    white = _whitener(windows)  # rows window-major, as y and the Jacobian
    y_w = white(y)
    for _ in range(_MAX_ITERATIONS):
        pred, jac = _model(p, d)
        jac_w = white(jac)
        a = jac_w.T @ jac_w
        if np.linalg.cond(a) > 1e13:
            raise AnalysisError(
                "the windows do not separate bias, g-sensitivity and scale: measure at rest in "
                "all six faces and on +r/-r plateaus with x, y and z up (and, for the "
                "temperature and supply coefficients, with each axis up at every condition)"
            )
        step = np.linalg.solve(a, jac_w.T @ (y_w - white(pred.ravel())))
        p = p + step
        if np.max(np.abs(step)) < 1e-12:
            break
    pred, jac = _model(p, d)
    jac_w = white(jac)
    cov = np.asarray(np.linalg.inv(jac_w.T @ jac_w), dtype=np.float64)
    chi2 = float(np.sum((y_w - white(pred.ravel())) ** 2))
    cal = _result(p, cov, chi2, len(y) - n_par, with_tv, reference_temperature_c,
                  reference_supply_v)
    return replace(cal, mean_temp_c=float(np.mean(d["dt"]) + reference_temperature_c),
                   mean_supply_v=float(np.mean(d["dv"]) + reference_supply_v))


def _whitener(windows: Sequence[Window]) -> Callable[[FloatArray], FloatArray]:
    """L^-1 applied to rows (window-major, three axes each), L L^T the windows' covariance:
    each window's own u_rate_dps on the diagonal, plus the bias wander each axis's windows
    share (bias_wander.py; windows without times share none)."""
    u = np.array([w.u_rate_dps for w in windows], dtype=np.float64)  # (n, 3)
    bi = max(w.bias_instability_dps for w in windows)
    rrw = max(w.rate_random_walk_dps_per_sqrt_s for w in windows)
    start = np.array([w.start_s for w in windows], dtype=np.float64)
    end = np.array([w.end_s for w in windows], dtype=np.float64)
    timed = np.isfinite(start) & np.isfinite(end)
    if (bi <= 0 and rrw <= 0) or not np.any(timed):
        return lambda rows: rows / u.ravel().reshape((-1,) + (1,) * (rows.ndim - 1))
    n = len(windows)
    shared = np.zeros((n, n))
    idx_t = np.flatnonzero(timed)
    shared[np.ix_(idx_t, idx_t)] = window_mean_covariance(start[timed], end[timed], bi, rrw)
    full = np.zeros((3 * n, 3 * n))
    for axis in range(3):
        idx = np.arange(n) * 3 + axis
        full[np.ix_(idx, idx)] = shared + np.diag(u[:, axis] ** 2)
    chol = np.linalg.cholesky(full)

    def apply(rows: FloatArray) -> FloatArray:
        return np.asarray(solve_triangular(chol, rows, lower=True), dtype=np.float64)

    return apply


def _result(
    p: FloatArray, cov: FloatArray, chi2: float, dof: int, with_tv: bool,
    t0_c: float, v0_v: float,
) -> ThreeAxisCalibration:
    q = _unpack(p)
    pm = q["sensitivity_matrix"].reshape(3, 3)
    m = np.asarray(np.linalg.inv(pm), dtype=np.float64)
    sp = _SLICE["sensitivity_matrix"]
    jm = -np.kron(m, m.T)  # d vec_r(M) / d vec_r(P)
    cov_m = jm @ cov[sp, sp] @ jm.T
    u: dict[str, FloatArray] = {"matrix": np.sqrt(np.diag(cov_m)).reshape(3, 3)}
    for name, n in BLOCKS:
        if name == "sensitivity_matrix":
            continue
        s = _SLICE[name]
        v = np.sqrt(np.diag(cov[s, s])) if s.stop <= len(p) else np.full(n, math.nan)
        u[name] = v.reshape(3, 3) if n == 9 else v
    notes = () if with_tv else (
        "one temperature and supply only: temperature and supply coefficients not fitted "
        "(b and M are the part's at the measured die temperature and supply)",
    )
    return ThreeAxisCalibration(
        bias_dps=q["bias_dps"].copy(),
        matrix=m,
        g_sensitivity_dps_per_mps2=q["g_sensitivity_dps_per_mps2"].reshape(3, 3).copy(),
        bias_temp_coeff_dps_per_c=q["bias_temp_coeff_dps_per_c"].copy(),
        bias_supply_coeff_dps_per_v=q["bias_supply_coeff_dps_per_v"].copy(),
        scale_temp_coeff_per_c=q["scale_temp_coeff_per_c"].copy(),
        scale_supply_coeff_per_v=q["scale_supply_coeff_per_v"].copy(),
        u_k1=u,
        chi2=chi2,
        dof=dof,
        temp_supply_fitted=with_tv,
        reference_temperature_c=t0_c,
        reference_supply_v=v0_v,
        notes=notes,
    )


def window_from_samples(
    face: str,
    table_rate_dps: float,
    rate_xyz_dps: ArrayLike,
    accel_xyz_mps2: ArrayLike,
    temp_c: float,
    supply_v: float,
    u_rate_dps: ArrayLike,
    condition: str = "",
) -> Window:
    """A Window from (n, 3) samples; u_rate_dps (3,) is the mean's k=1 uncertainty, which the
    caller takes from the part's noise model (white noise alone understates it)."""
    rate = np.asarray(rate_xyz_dps, dtype=np.float64).reshape(-1, 3)
    acc = np.asarray(accel_xyz_mps2, dtype=np.float64).reshape(-1, 3)
    if len(rate) < 2 or len(acc) < 1:
        raise AnalysisError(f"window at face {face} holds fewer than two samples: dwell longer")
    return Window(
        face=face,
        table_rate_dps=float(table_rate_dps),
        rate_dps=vec3(rate.mean(axis=0)),
        u_rate_dps=vec3(u_rate_dps),
        accel_mps2=vec3(acc.mean(axis=0)),
        temp_c=float(temp_c),
        supply_v=float(supply_v),
        condition=condition,
    )


def vec3(values: ArrayLike) -> tuple[float, float, float]:
    v = np.asarray(values, dtype=np.float64).reshape(3)
    return (float(v[0]), float(v[1]), float(v[2]))
