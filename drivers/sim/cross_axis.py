"""Effects of the bench's three-axis part that couple its axes beyond the first-order model
(issue 29), in the part frame: the bench's own physics, apart from the station's model.

    raw_j += sum_{k != j} C_jk dT w_k        a cross-coupling that drifts with temperature
    raw_j += sum_{k != j} Q_jk a_k^2          a g-squared cross term

dT is the sensing element's temperature - 25 C, w the true rate (deg/s), a the true specific
force (m/s^2). The station's fit (scale and misalignment M, linear g-sensitivity G, a scale
temperature coefficient per axis) holds neither: the misalignment it fits is constant, and G
is linear in a. Both matrices are 0 on the diagonal and 0 unless a part's config sets them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def cross_axis_output(
    rate_xyz_dps: FloatArray,
    accel_xyz_mps2: FloatArray,
    d_t: FloatArray,
    cross_temp_coeff_per_c: FloatArray,
    g2_cross_dps_per_mps2_sq: FloatArray,
) -> FloatArray:
    """(n, 3) deg/s the two cross-axis effects add to the raw output; `d_t` is (n,) or
    (n, 1), the matrices (3, 3) with zero diagonals."""
    c = np.asarray(cross_temp_coeff_per_c, dtype=float)
    q = np.asarray(g2_cross_dps_per_mps2_sq, dtype=float)
    c = c - np.diag(np.diag(c))
    q = q - np.diag(np.diag(q))
    d_t = np.asarray(d_t, dtype=float).reshape(-1, 1)
    out: FloatArray = (rate_xyz_dps @ c.T) * d_t + (accel_xyz_mps2**2) @ q.T
    return out
