"""The hand-turned multi-position method for three-axis gyros (Ferraris et al. 1995), no I/O.

A session holds six static faces (x_p: the part's +x axis points up, so the accelerometer
reads +g along x; x_a: -x up; likewise y and z) and one rotation of a known angle about each
axis (x_rot about x, made in the x_p face, and so on). With the product's convention
(docs/three-axis.md)

    raw = S w + b + G a + noise,   S = M^-1,   correction  w_hat = M (raw - b - G a)

the estimates are (docs/multi-position.md has the derivation and the uncertainty method):

- G from the face pairs: the gyro's mean difference between opposite faces against the
  accelerometer's mean difference, G = (U_p - U_a) (A_p - A_a)^-1 (columns x, y, z), so a
  face that is not quite level is allowed for; without an accelerometer G is not estimated;
- b = mean of the six face means - G x mean of the six accelerometer means (without an
  accelerometer the G a terms cancel between opposite faces);
- S from the rotations: column j = (integral of raw - b - G a over rotation j) / angle; without
  an accelerometer the offset subtracted is the mean of the face the rotation was made in
  (b + G a there); M = S^-1.

Uncertainties: every input the estimates are built from (the face means, the rotation
integrals, the rotation angles) gets a standard uncertainty from a noise model fitted per
channel to the static faces (the Allan deviation at the section's length, as bias.py does);
they are propagated through the estimator's Jacobian (numerical, central differences),
inputs independent. The three pairs of opposite faces each give the bias; their spread is a
chi-square on 6 degrees of freedom, and a bias that moved during the session (p < PAIRS_P)
widens u(b) by the Birge ratio with a warning. The earth's rate (at most 0.0042 deg/s) is not
separated from the bias.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import chi2 as chi2_dist

from procedures.analysis.allan import NoiseModel, fit_noise_model, overlapping_adev
from procedures.analysis.errors import AnalysisError

FACES = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")
ROTATIONS = ("x_rot", "y_rot", "z_rot")
SECTIONS = (*FACES, *ROTATIONS)
AXES = ("x", "y", "z")
STANDARD_GRAVITY_MPS2 = 9.80665
MIN_FACE_SAMPLES = 16
MIN_ROTATION_SAMPLES = 4
MAX_FACE_TILT_DEG = 30.0  # a face's gravity further from its axis than this: misnamed section
MAX_ANGLE_ERROR = 0.5  # |measured / expected - 1| beyond this: wrong sign, section or angle
MOVING_FACE_RATIO = 5.0  # a face's gyro scatter this many times the faces' median: moving
WARN_CROSS_AXIS = 0.05  # rotation seen this much on another axis: a wobbly hand rotation
PAIRS_P = 1e-3  # the face pairs disagree on the bias below this chi-square p (as stop_method)


@dataclass(frozen=True)
class MultiPositionResult:
    """Ferraris estimates with standard (k=1) uncertainties; `*_k2` are 2 x those."""

    bias_dps: NDArray[np.float64]  # (3,) b
    u_bias_dps: NDArray[np.float64]
    matrix: NDArray[np.float64]  # (3, 3) M, w_hat = M (raw - b - G a)
    u_matrix: NDArray[np.float64]
    g_sensitivity_dps_per_mps2: NDArray[np.float64] | None  # (3, 3) G; None without accel
    u_g_sensitivity_dps_per_mps2: NDArray[np.float64] | None
    rotation_integrals_deg: NDArray[np.float64]  # (3, 3) column j: rotation j minus offsets
    rotation_deg: float
    sample_rate_hz: float
    warnings: tuple[str, ...]
    # each pair of opposite faces gives the bias on its own; their spread against their noise:
    # chi-square on 6 degrees of freedom, and the Birge ratio u(b) was widened by (None: not)
    pairs_chi2: float | None = None
    pairs_dof: int = 6
    bias_birge_ratio: float | None = None

    @property
    def u_bias_dps_k2(self) -> NDArray[np.float64]:
        return 2.0 * self.u_bias_dps

    @property
    def u_matrix_k2(self) -> NDArray[np.float64]:
        return 2.0 * self.u_matrix

    @property
    def u_g_sensitivity_dps_per_mps2_k2(self) -> NDArray[np.float64] | None:
        u = self.u_g_sensitivity_dps_per_mps2
        return None if u is None else 2.0 * u

    @property
    def scale_matrix(self) -> NDArray[np.float64]:
        """S = M^-1: the part's response to a true rate (raw = S w + ...)."""
        return np.asarray(np.linalg.inv(self.matrix), dtype=np.float64)


@dataclass(frozen=True)
class _Summary:
    """The numbers the estimator is built from, and their standard uncertainties."""

    face_gyro: NDArray[np.float64]  # (3, 6) mean per face, columns in FACES order
    rot_gyro: NDArray[np.float64]  # (3, 3) integral over rotation j (deg), column j
    angle_deg: NDArray[np.float64]  # (3,) the rotation angles
    rot_time_s: NDArray[np.float64]  # (3,) exact (sample count / rate)
    face_accel: NDArray[np.float64] | None  # (3, 6)
    rot_accel: NDArray[np.float64] | None  # (3, 3) integral (m/s^2 x s)

    def vector(self) -> NDArray[np.float64]:
        parts = [self.face_gyro.ravel(), self.rot_gyro.ravel(), self.angle_deg]
        if self.face_accel is not None and self.rot_accel is not None:
            parts += [self.face_accel.ravel(), self.rot_accel.ravel()]
        return np.concatenate(parts)

    def from_vector(self, x: NDArray[np.float64]) -> _Summary:
        has_accel = self.face_accel is not None
        return _Summary(
            face_gyro=x[0:18].reshape(3, 6),
            rot_gyro=x[18:27].reshape(3, 3),
            angle_deg=x[27:30],
            rot_time_s=self.rot_time_s,
            face_accel=x[30:48].reshape(3, 6) if has_accel else None,
            rot_accel=x[48:57].reshape(3, 3) if has_accel else None,
        )


def analyze_multi_position(
    gyro_dps: ArrayLike,
    sections: Mapping[str, tuple[int, int]],
    sample_rate_hz: float,
    rotation_deg: float = 360.0,
    u_rotation_deg: float = 0.0,
    accel_mps2: ArrayLike | None = None,
) -> MultiPositionResult:
    """b, M and (with an accelerometer) G of a three-axis gyro from a hand-turned session.

    `gyro_dps` and `accel_mps2` are (n, 3) arrays; `sections` maps each name of SECTIONS to
    (start, end) sample indices, end exclusive. `rotation_deg` is the angle of each rotation
    by the right-hand rule about the axis (positive: counter-clockwise seen from above the
    face it is made in); `u_rotation_deg` its standard uncertainty (how well a hand stops).
    """
    gyro = _channels(gyro_dps, "gyro_dps")
    accel = None if accel_mps2 is None else _channels(accel_mps2, "accel_mps2")
    if accel is not None and accel.shape != gyro.shape:
        raise AnalysisError(
            f"accel_mps2 has {accel.shape[0]} samples but gyro_dps has {gyro.shape[0]}"
        )
    fs, angle, u_angle = _check_numbers(sample_rate_hz, rotation_deg, u_rotation_deg)
    spans = check_sections(sections, gyro.shape[0])
    warnings = _moving_faces(gyro, spans)
    if accel is not None:
        _check_faces(accel, spans)
    summary, u_summary = _summarise(gyro, accel, spans, fs, angle, u_angle)
    estimate = _solve(summary)
    _check_rotations(estimate.rotation_integrals_deg, angle, warnings)
    jac = _jacobian(summary, u_summary)
    u_out = np.sqrt(np.einsum("ij,ij->i", jac, jac))
    has_g = estimate.g is not None
    chi2 = _pairs_chi2(summary, u_summary, estimate)
    birge = _birge_ratio(chi2, warnings)
    u_bias = u_out[0:3] if birge is None else u_out[0:3] * birge
    return MultiPositionResult(
        bias_dps=estimate.b,
        u_bias_dps=u_bias,
        matrix=estimate.m,
        u_matrix=u_out[3:12].reshape(3, 3),
        g_sensitivity_dps_per_mps2=estimate.g,
        u_g_sensitivity_dps_per_mps2=u_out[12:21].reshape(3, 3) if has_g else None,
        rotation_integrals_deg=estimate.rotation_integrals_deg,
        rotation_deg=angle,
        sample_rate_hz=fs,
        warnings=tuple(warnings),
        pairs_chi2=chi2,
        bias_birge_ratio=birge,
    )


def _check_numbers(
    sample_rate_hz: float, rotation_deg: float, u_rotation_deg: float
) -> tuple[float, float, float]:
    fs = float(sample_rate_hz)
    if not math.isfinite(fs) or fs <= 0:
        raise AnalysisError(f"sample_rate_hz must be a positive finite number, got {fs!r}")
    angle = float(rotation_deg)
    if not math.isfinite(angle) or angle == 0:
        raise AnalysisError(f"rotation_deg must be a finite non-zero angle, got {angle!r}")
    u_angle = float(u_rotation_deg)
    if not math.isfinite(u_angle) or not 0 <= u_angle < abs(angle):
        raise AnalysisError(
            f"u_rotation_deg must be from 0 to below |rotation_deg|, got {u_angle!r}"
        )
    return fs, angle, u_angle


def _channels(values: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise AnalysisError(f"{name} must be an (n, 3) array (x, y, z), got shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        row, col = (int(i[0]) for i in np.nonzero(bad))
        raise AnalysisError(
            f"{name} holds NaN or infinite values (first at sample {row}, axis {AXES[col]}): "
            "repair or remove those samples"
        )
    return arr


def check_sections(sections: Mapping[str, tuple[int, int]], n_samples: int) -> dict[str, slice]:
    """Each section as a slice; AnalysisError naming a missing, unknown or bad section."""
    missing = [s for s in SECTIONS if s not in sections]
    if missing:
        raise AnalysisError(
            f"section(s) {', '.join(missing)} missing; the method needs all of "
            f"{', '.join(SECTIONS)}"
        )
    unknown = sorted(set(sections) - set(SECTIONS))
    if unknown:
        raise AnalysisError(
            f"unknown section(s) {', '.join(unknown)}; the names are {', '.join(SECTIONS)}"
        )
    spans: dict[str, slice] = {}
    for name in SECTIONS:
        start, end = (int(v) for v in sections[name])
        least = MIN_FACE_SAMPLES if name in FACES else MIN_ROTATION_SAMPLES
        if not 0 <= start < end <= n_samples:
            raise AnalysisError(
                f"section {name}: start {start}, end {end} is outside the record's samples "
                f"0..{n_samples} (end exclusive) or not start < end; fix its indices"
            )
        if end - start < least:
            raise AnalysisError(
                f"section {name} has {end - start} samples; at least {least} are needed"
            )
        spans[name] = slice(start, end)
    return spans


def _check_faces(accel: NDArray[np.float64], spans: dict[str, slice]) -> None:
    """Each face's gravity within MAX_FACE_TILT_DEG of its named axis, else a misnamed face."""
    for k, face in enumerate(FACES):
        mean = accel[spans[face]].mean(axis=0)
        norm = float(np.linalg.norm(mean))
        expected = np.zeros(3)
        expected[k // 2] = 1.0 if k % 2 == 0 else -1.0
        cos_tilt = float(np.clip(mean @ expected / norm, -1, 1)) if norm else -1.0
        tilt = math.degrees(math.acos(cos_tilt))
        if tilt > MAX_FACE_TILT_DEG:
            seen = int(np.argmax(np.abs(mean)))
            sign = "+" if mean[seen] > 0 else "-"
            raise AnalysisError(
                f"section {face}: the accelerometer reads gravity along {sign}{AXES[seen]} "
                f"({tilt:.0f} deg from the {'+' if k % 2 == 0 else '-'}{AXES[k // 2]} this face "
                "needs); the section is misnamed or its indices cover another face: fix them"
            )


def _moving_faces(gyro: NDArray[np.float64], spans: dict[str, slice]) -> list[str]:
    """A warning for each face whose gyro scatter is far above the others': not static."""
    spread = np.array([float(gyro[spans[f]].std(axis=0).max()) for f in FACES])
    typical = float(np.median(spread))
    return [
        f"section {face} is not static: its gyro scatter {spread[k]:.3g} deg/s is "
        f"{spread[k] / typical:.0f} x the faces' typical {typical:.3g} deg/s; it may hold part "
        "of a turn: cut it to the time the part lay still"
        for k, face in enumerate(FACES)
        if typical > 0 and spread[k] > MOVING_FACE_RATIO * typical
    ]


def _noise_models(
    data: NDArray[np.float64], spans: dict[str, slice], fs: float
) -> list[NoiseModel]:
    """One noise model per channel from the static faces, each face's mean removed."""
    residual = np.concatenate([data[spans[f]] - data[spans[f]].mean(axis=0) for f in FACES])
    models = []
    for col in range(3):
        y = residual[:, col]
        if not np.any(y):
            models.append(NoiseModel())  # noise-free (simulated) data
            continue
        models.append(fit_noise_model(overlapping_adev(y, fs, "octave")).model)
    return models


def _summarise(
    gyro: NDArray[np.float64],
    accel: NDArray[np.float64] | None,
    spans: dict[str, slice],
    fs: float,
    angle: float,
    u_angle: float,
) -> tuple[_Summary, _Summary]:
    """The estimator's inputs and, in the same layout, their standard uncertainties."""

    def reduce(
        data: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], ...]:
        models = _noise_models(data, spans, fs)
        face = np.column_stack([data[spans[f]].mean(axis=0) for f in FACES])
        rot = np.column_stack([data[spans[r]].sum(axis=0) / fs for r in ROTATIONS])
        face_t = np.array([(spans[f].stop - spans[f].start) / fs for f in FACES])
        rot_t = np.array([(spans[r].stop - spans[r].start) / fs for r in ROTATIONS])
        u_face = np.array([[m.adev_dps(t) for t in face_t] for m in models], dtype=np.float64)
        u_rot = np.array([[t * m.adev_dps(t) for t in rot_t] for m in models], dtype=np.float64)
        return face, rot, u_face, u_rot, rot_t

    g_face, g_rot, u_g_face, u_g_rot, rot_t = reduce(gyro)
    a_face = a_rot = u_a_face = u_a_rot = None
    if accel is not None:
        a_face, a_rot, u_a_face, u_a_rot, _ = reduce(accel)
    angles = np.full(3, angle)
    value = _Summary(g_face, g_rot, angles, rot_t, a_face, a_rot)
    u = _Summary(u_g_face, u_g_rot, np.full(3, u_angle), rot_t, u_a_face, u_a_rot)
    return value, u


@dataclass(frozen=True)
class _Estimate:
    b: NDArray[np.float64]
    m: NDArray[np.float64]
    g: NDArray[np.float64] | None
    rotation_integrals_deg: NDArray[np.float64]

    def vector(self) -> NDArray[np.float64]:
        parts = [self.b, self.m.ravel()]
        if self.g is not None:
            parts.append(self.g.ravel())
        return np.concatenate(parts)


def _solve(s: _Summary) -> _Estimate:
    """The Ferraris estimator (module notes) on one set of inputs."""
    up, down = s.face_gyro[:, 0::2], s.face_gyro[:, 1::2]  # columns x, y, z
    g: NDArray[np.float64] | None = None
    if s.face_accel is not None and s.rot_accel is not None:
        d_accel = s.face_accel[:, 0::2] - s.face_accel[:, 1::2]
        g = np.asarray(np.linalg.solve(d_accel.T, (up - down).T).T, dtype=np.float64)
        b = s.face_gyro.mean(axis=1) - g @ s.face_accel.mean(axis=1)
        offsets = np.outer(b, s.rot_time_s) + g @ s.rot_accel
    else:
        b = s.face_gyro.mean(axis=1)
        offsets = up * s.rot_time_s  # the face each rotation is made in: b + G a there
    integrals = s.rot_gyro - offsets
    scale = integrals / s.angle_deg
    try:
        m = np.asarray(np.linalg.inv(scale), dtype=np.float64)
    except np.linalg.LinAlgError:
        raise AnalysisError(
            "the three rotations do not span three axes (their integrals are linearly "
            "dependent): check that x_rot, y_rot and z_rot are about different axes"
        ) from None
    return _Estimate(b=b, m=m, g=g, rotation_integrals_deg=integrals)


def _jacobian(value: _Summary, u: _Summary) -> NDArray[np.float64]:
    """d(estimates)/d(inputs) x u(inputs): rows are outputs; its row norms are their u."""
    x0 = value.vector()
    ux = u.vector()
    n_out = _solve(value).vector().size
    jac = np.zeros((n_out, x0.size))
    for i in np.flatnonzero(ux > 0):
        h = 1e-3 * ux[i]
        xp, xm = x0.copy(), x0.copy()
        xp[i] += h
        xm[i] -= h
        diff = _solve(value.from_vector(xp)).vector() - _solve(value.from_vector(xm)).vector()
        jac[:, i] = diff / (2 * h) * ux[i]
    return jac


def _pairs_chi2(value: _Summary, u: _Summary, estimate: _Estimate) -> float | None:
    """Chi-square of the bias from each pair of opposite faces about their mean, b."""
    pair = (value.face_gyro[:, 0::2] + value.face_gyro[:, 1::2]) / 2
    var_pair = (u.face_gyro[:, 0::2] ** 2 + u.face_gyro[:, 1::2] ** 2) / 4
    if estimate.g is not None and value.face_accel is not None and u.face_accel is not None:
        pair = pair - estimate.g @ (value.face_accel[:, 0::2] + value.face_accel[:, 1::2]) / 2
        var_accel = (u.face_accel[:, 0::2] ** 2 + u.face_accel[:, 1::2] ** 2) / 4
        var_pair = var_pair + estimate.g**2 @ var_accel
    u_pair = np.sqrt(var_pair)
    if not np.all(u_pair > 0):
        return None  # noise-free data: nothing to judge the spread against
    return float(np.sum(((pair - estimate.b[:, None]) / u_pair) ** 2))


def _birge_ratio(chi2: float | None, warnings: list[str]) -> float | None:
    """sqrt(chi2 / 6) with a warning when the face pairs disagree (p < PAIRS_P), else None."""
    if chi2 is None or chi2_dist.sf(chi2, 6) >= PAIRS_P:
        return None
    birge = math.sqrt(chi2 / 6)
    warnings.append(
        f"the three pairs of opposite faces disagree on the bias (chi-square {chi2:.3g} on "
        f"6 degrees of freedom): the bias moved during the session (warm-up, drift) or a "
        f"face was not still; u(b) is widened by the Birge ratio {birge:.3g}. Warm the part "
        "up first and record the session without pauses"
    )
    return birge


def _check_rotations(
    integrals: NDArray[np.float64], angle: float, warnings: list[str]
) -> None:
    for j, name in enumerate(ROTATIONS):
        ratio = float(integrals[j, j]) / angle
        if abs(ratio - 1) > MAX_ANGLE_ERROR:
            hint = (
                f"if the part turned the other way, give the angle as {-angle:g} deg "
                "(right-hand rule about the axis)"
                if abs(ratio + 1) <= MAX_ANGLE_ERROR
                else "check that the section holds the whole rotation and the angle is right"
            )
            raise AnalysisError(
                f"section {name}: the gyro integrates to {float(integrals[j, j]):+.1f} deg about "
                f"{AXES[j]}, expected {angle:+g} deg; {hint}"
            )
        for i in range(3):
            share = float(integrals[i, j]) / angle
            if i != j and abs(share) > WARN_CROSS_AXIS:
                warnings.append(
                    f"section {name}: {100 * abs(share):.0f} % of the rotation appears on the "
                    f"{AXES[i]} axis; a rotation that far off the part's axis reads as "
                    "misalignment: turn the part against a straight edge and re-record"
                )
