"""Nonlinearity and asymmetry from a ramp's plateaus, as procedures/analysis/rate_table.py
defines them at one condition.

The ramp's fit (procedures/analysis/ramp_fit.py) describes every plateau by the first-order
laws in temperature and supply, the die's rate and the hysteresis. Each plateau's output is
carried to the reference point by taking those laws away and keeping the straight line at
the reference (b0 + s0 ref) plus the plateau's residual; the plateaus of one commanded rate
are then averaged (the ramp visits each rate many times, at many temperatures: their mean
is the part's output at that rate at the reference point), and that rate set is fitted as
the rate table's is (`fit_rate_table`): nonlinearity = the largest residual from the line
over K x FS, asymmetry = (K+ - K-) / mean K, with their uncertainties. A rate's uncertainty
is the larger of its plateaus' stated one and their scatter about their mean."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from procedures.analysis.errors import AnalysisError
from procedures.analysis.ramp_fit import RampFit, RampPlateaus
from procedures.analysis.rate_table import RateTableFit, fit_rate_table

F64 = NDArray[np.float64]


def at_reference(p: RampPlateaus, fit: RampFit) -> F64:
    """Each plateau's output at the reference point: the line there plus its residual."""
    co = fit.coefficients
    return np.asarray(co.bias_dps + co.scale * p.ref_dps + fit.residual_dps, dtype=np.float64)


def _group(commanded: F64, ref: F64, u_ref: F64, y: F64, u_y: F64
           ) -> tuple[list[float], list[float], list[float], list[float]]:
    """Per commanded rate: mean reference, its u, mean output, its u (stated or scatter)."""
    out: tuple[list[float], list[float], list[float], list[float]] = ([], [], [], [])
    for rate in np.unique(commanded):
        sel = commanded == rate
        n = int(sel.sum())
        stated = math.sqrt(float(np.mean(u_y[sel] ** 2)) / n)
        scatter = float(np.std(y[sel], ddof=1)) / math.sqrt(n) if n > 1 else 0.0
        out[0].append(float(np.mean(ref[sel])))
        out[1].append(math.sqrt(float(np.sum(u_ref[sel] ** 2))) / n)
        out[2].append(float(np.mean(y[sel])))
        out[3].append(max(stated, scatter))
    return out


def ramp_linearity(p: RampPlateaus, commanded_dps: ArrayLike, fit: RampFit,
                   full_scale_dps: float) -> RateTableFit:
    """The rate table's line fit over the ramp's rate set at the reference point (see the
    module docstring); AnalysisError when the plateaus do not match their commands."""
    cmd = np.asarray(commanded_dps, dtype=np.float64)
    if cmd.size != p.ref_dps.size or fit.residual_dps.size != p.ref_dps.size:
        raise AnalysisError(
            f"{cmd.size} commanded rates, {p.ref_dps.size} plateaus and "
            f"{fit.residual_dps.size} residuals: one of each per plateau"
        )
    ref, u_ref, y, u_y = _group(cmd, p.ref_dps, p.u_ref_dps, at_reference(p, fit), p.u_out_dps)
    return fit_rate_table(ref, u_ref, y, u_y, full_scale_dps)
