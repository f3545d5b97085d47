"""What a run folder can show of a part's hidden thermal effects (issue 29): each effect's
size on the folder's own history against the workflow's own test, and whether the workflow
is expected to name it.

The bench's truth (drivers/sim/thermal_physics.py, drivers/sim/gyro.py) is evaluated on the
folder's die temperature (the sensor's, as recorded) with the part's draws: the element
follows the sensor first order over tau from power-on; the part's bias and scale laws act on
the element's temperature; the gradient bias on the element's rate; the hysteresis on a play
of the element's temperature. Grouped by the base variables a folder can tell apart:

- `lag (scale)`, (`rate`, `temperature_rate`): scale x scale_tc x w x (element - sensor);
- `rate bias`, (`temperature_rate`): bias_tc x (element - sensor) + the gradient bias (the
  lag's bias law and the gradient look alike: both a bias with the element's rate);
- `hysteresis`, (`temperature_direction`): +-h/2 by the play state.

An effect's size is z = sqrt(lambda), lambda the whitened chi^2 its signal alone leaves after
the first-order model is fitted to it with the folder's own blocks and noise (the workflow's
bias wander included): the noncentrality of the workflow's F test of a one-column term that
fits it exactly (what the test of that term sees of it, on top of the starting model). Also
its gap: the duration-weighted rms of that residual over the blocks, against the floor.

Expected (the workflow should name it): z at least `z_expected`, the noncentrality at which a
one-column library term is significant with probability POWER at the first step of the
workflow's weighted Holm procedure, alpha x (1 - CATALOG_ALPHA_SHARE) / (library terms
tested). The first step is the strictest, so an effect above it is named with at least that
probability by the test; POWER is chosen before any result (0.9, the usual design power).
Below it an effect may be named or not: the folder does not decide it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import optimize, stats

from procedures.model import library
from procedures.model.discrepancy import CATALOG_ALPHA_SHARE, DiscrepancyResult
from procedures.model.fit import Fitter
from procedures.model.gyro_model import first_order_model
from procedures.model.residuals import record_gap_dps
from procedures.model.trajectory import FloatArray, Trajectory

POWER = 0.9


@dataclass(frozen=True)
class PartTruth:
    """A part's drawn thermal effects and the first-order laws the element carries."""

    tau_s: float
    gradient_dps_per_c_per_min: float
    hysteresis_dps: float
    hysteresis_width_c: float
    bias_temp_coeff_dps_per_c: float
    scale: float
    scale_temp_coeff_per_c: float


@dataclass(frozen=True)
class EffectSize:
    name: str
    regressors: tuple[str, ...]
    z: float  # sqrt of the noncentrality of the workflow's test
    gap_over_floor: float  # rms over the blocks of what the first-order model leaves / floor
    expected: bool  # z >= the threshold: the workflow should name it


def element_temperature(traj: Trajectory, tau_s: float) -> FloatArray:
    """The element's temperature at the samples: first order over tau_s behind the sensor
    (linear between grid points, gaps interpolated: the die goes on), equal at the start."""
    if tau_s <= 0:
        return traj.temp_c.copy()
    from scipy.signal import lfilter

    t = traj.time_s
    dt = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1] + 0.5 * dt, dt)
    sensor = np.interp(grid, t, traj.temp_c)
    a = math.exp(-dt / tau_s)
    g = tau_s / dt * (1.0 - a)  # first-order hold: exact for a sensor linear over each step
    b0, b1 = 1.0 - g, g - a
    element, _ = lfilter([b0, b1], [1.0, -a], sensor, zi=[(b1 + a) * sensor[0]])
    return np.asarray(np.interp(t, grid, element), dtype=float)


def signals(traj: Trajectory, p: PartTruth) -> list[tuple[str, tuple[str, ...], FloatArray]]:
    """(name, base variables, deg/s per sample) of each thermal effect the part has."""
    element = element_temperature(traj, p.tau_s)
    behind = element - traj.temp_c
    rate = -behind / p.tau_s if p.tau_s > 0 else library.temperature_rate_c_per_s(traj)
    out: list[tuple[str, tuple[str, ...], FloatArray]] = []
    if p.tau_s > 0 and p.scale_temp_coeff_per_c:
        out.append(("lag (scale)", ("rate", "temperature_rate"),
                    p.scale * p.scale_temp_coeff_per_c * traj.ref_rate_dps * behind))
    bias = p.bias_temp_coeff_dps_per_c * behind + 60.0 * p.gradient_dps_per_c_per_min * rate
    if p.tau_s > 0 or p.gradient_dps_per_c_per_min:
        out.append(("rate bias", ("temperature_rate",), bias))
    if p.hysteresis_dps:
        state = library.play_state(element, p.hysteresis_width_c)
        out.append(("hysteresis", ("temperature_direction",), 0.5 * p.hysteresis_dps * state))
    return out


def z_expected(res: DiscrepancyResult) -> float:
    """The z at which a one-column library term is significant with probability POWER at the
    first step of the workflow's Holm procedure over the folder's first candidates."""
    first = res.iterations[0].candidates if res.iterations else res.last_candidates
    return threshold_z(res.alpha, max(sum(library.is_library_id(c.effect) for c in first), 1))


def threshold_z(alpha: float, n_library: int) -> float:
    """sqrt of the noncentrality at which chi^2_1 passes the first Holm step of one of
    n_library library terms (alpha x (1 - CATALOG_ALPHA_SHARE) / n_library) with
    probability POWER."""
    crit = float(stats.chi2.isf(alpha * (1 - CATALOG_ALPHA_SHARE) / n_library, 1))
    lam = optimize.brentq(lambda x: float(stats.ncx2.sf(crit, 1, x)) - POWER, 1e-6, 1e4)
    return math.sqrt(lam)


def sizes(traj: Trajectory, res: DiscrepancyResult, p: PartTruth) -> list[EffectSize]:
    """Each effect's z and gap against the folder's own floor (see the module's docstring)."""
    threshold = z_expected(res)
    out = []
    for name, regs, signal in signals(traj, p):
        fitter = Fitter(replace(traj, gyro_dps=signal), res.blocks, res.noise)
        fit = fitter.fit(first_order_model())
        z = math.sqrt(max(fit.chi2, 0.0))
        gap = record_gap_dps(fit.residual_dps, res.blocks.duration_s) / res.noise_floor_dps
        out.append(EffectSize(name, regs, z, gap, z >= threshold))
    return out
