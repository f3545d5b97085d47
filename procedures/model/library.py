"""Library of generic candidate terms built from a run's own variables, beyond the catalog.

A library term adds `coeff * f(x)` to the output, f a product of factors of the base
variables (at most three, total degree at most three), or a pair of table-angle harmonics:

| token | factor | base variable |
| --- | --- | --- |
| `w` | rate (deg/s) | rate |
| `dT` | die temperature - 25 C | temperature |
| `dTdt` | d(die temperature)/dt (C/s), smoothed over `DTDT_SMOOTH_S` | temperature_rate |
| `dTdtlag<tau>s` | dTdt low-passed causally, first order, over tau (C/s) | temperature_rate |
| `dTdir` | play state of the die temperature, -1 cooled .. +1 heated | temperature_direction |
| `dV` | supply - 5.0 V | supply |
| `sgnw` | sign(rate) | rate |
| `absw` | abs(rate) | rate |
| `exp<tau>s` | exp(-t / tau), t since power-on | time |
| `angleh<k>` | cos(k angle), sin(k angle) as one term (amplitude, phase) | angle |

A term's id spells its definition, `lib_` + factors joined by `_`, a power as a digit after
the token (`lib_w_dT2` = w * dT^2, `lib_dTdt`, `lib_w_exp300s`, `lib_angleh2`), so a model
file holding it needs nothing else to be read back (`spec()` parses the id). Terms equal to a
catalog effect (dT, dV, w dT, w dV, w^2, w^3, |w|, exp(-t/tau), the first angle harmonic)
are not in the library: the catalog effect keeps its id.

`dTdtlag<tau>s` is the rate at a sensing element that follows the on-chip sensor first order
with time constant tau (`ELEMENT_LAG_S`): sensor - element = tau x dTdtlag exactly, the
element starting at the sensor's temperature at power-on. A bias or scale that follows the
element's temperature while the record carries the sensor's shows as tau x (temperature law)
x dTdtlag. After power-on, where the self-heating die's rate is highest and the element has
not yet fallen behind, the instantaneous dTdt overstates the lag (an exp(-t/30 s) term was
then named as well, to take it back). It enters two terms, `lib_dTdtlag20s` and
`lib_w_dTdtlag20s`, the lagged variants of `lib_dTdt` and `lib_w_dTdt`; of a term and its
variant the data fit better is named when they look alike (marginality.parsimonious).

`dTdir` is the direction of the die's temperature history (hysteresis between heating and
cooling): a play (backlash) operator of half-width `PLAY_HALF_WIDTH_C` run over the
smoothed die temperature in time order, its state (temperature - play) / half-width; it
starts at 0 and reaches +1 after a rise of 2 half-widths (-1 after such a fall). It enters
two terms: `lib_dTdir` (a bias that differs between heating and cooling, +-coeff) and
`lib_w_dTdir` (the same for the scale factor).
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from procedures.model import cross_axis
from procedures.model.effect_spec import EffectSpec
from procedures.model.lag import contiguous_runs
from procedures.model.trajectory import FloatArray, Trajectory

PREFIX = "lib_"
DTDT_SMOOTH_S = 10.0  # moving-average window of the die temperature before differencing
EXP_TAUS_S = (30.0, 100.0, 300.0, 1000.0)  # time constants of the exponential terms
MAX_HARMONIC = 4
PLAY_HALF_WIDTH_C = 1.0  # half-width of the play operator of the temperature direction
ELEMENT_LAG_S = 20  # time constant of the lagged rate's terms (s): a typical sensing element's


@dataclass(frozen=True)
class _Factor:
    variable: str  # pinned regressor vocabulary (effect_spec.REGRESSOR_VOCABULARY)
    label: str
    unit: str


FACTORS: dict[str, _Factor] = {
    "w": _Factor("rate", "rate", "deg/s"),
    "dTdt": _Factor("temperature_rate", "d(die temperature)/dt", "C/s"),
    "dTdir": _Factor("temperature_direction",
                     "direction of the die temperature (-1 cooled .. +1 heated)", ""),
    "dT": _Factor("temperature", "(die temperature - 25 C)", "C"),
    "dV": _Factor("supply", "(supply - 5.0 V)", "V"),
    "sgnw": _Factor("rate", "sign(rate)", ""),
    "absw": _Factor("rate", "|rate|", "deg/s"),
}
_TOKEN = re.compile(r"^(?:(?P<f>dTdir|dTdt|dT|dV|sgnw|absw|w)(?P<p>[23]?)|exp(?P<tau>\d+)s"
                    r"|dTdtlag(?P<lag>\d+)s)$")
_HARMONIC = re.compile(r"^angleh(?P<k>[1-9])$")
# exponent tuples (w, dT, dTdt, dV) of the catalog's polynomial effects and the base scale
_CATALOG_MONOMIALS = {(1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 0, 1), (1, 1, 0, 0), (1, 0, 0, 1),
                      (2, 0, 0, 0), (3, 0, 0, 0)}


def is_library_id(effect_id: str) -> bool:
    return effect_id.startswith(PREFIX)


def _parse(effect_id: str) -> list[tuple[str, int]] | int:
    """Factors [(token, power)] of a product term, or the harmonic number of an angle term."""
    if not is_library_id(effect_id):
        raise ValueError(f"{effect_id!r} is not a library term (ids start with {PREFIX!r})")
    body = effect_id[len(PREFIX):]
    if m := _HARMONIC.match(body):
        k = int(m["k"])
        if k > MAX_HARMONIC:
            raise ValueError(f"library term {effect_id!r}: harmonics 1 to {MAX_HARMONIC} only")
        return k
    factors: list[tuple[str, int]] = []
    for tok in body.split("_"):
        m = _TOKEN.match(tok)
        if m is None:
            raise ValueError(
                f"library term {effect_id!r}: unknown factor {tok!r}; factors are "
                f"{', '.join(FACTORS)} with an optional power 2 or 3, exp<tau>s, or a term "
                "angleh<k>"
            )
        if m["tau"] is not None or m["lag"] is not None:
            tau = int(m["tau"] or m["lag"])
            if not 1 <= tau <= 100000:
                raise ValueError(f"library term {effect_id!r}: time constant 1 to 1e5 s")
            factors.append((tok, 1))
        else:
            factors.append((m["f"], int(m["p"] or 1)))
    if sum(p for _, p in factors) > 3 or len({t for t, _ in factors}) != len(factors):
        raise ValueError(
            f"library term {effect_id!r}: at most third order, each factor once"
        )
    return factors


def _factor_info(tok: str) -> _Factor:
    if tok.startswith("dTdtlag"):
        return _Factor("temperature_rate",
                       f"d(die temperature)/dt lagged {tok[7:-1]} s (at the element)", "C/s")
    if tok.startswith("exp"):
        return _Factor("time", f"exp(-t / {tok[3:-1]} s)", "")
    return FACTORS[tok]


@lru_cache(maxsize=512)
def spec(effect_id: str) -> EffectSpec:
    """The effect spec of a library term (parameters, regressors, formula), from its id."""
    if cross_axis.is_cross_id(effect_id):
        return cross_axis.spec(effect_id)
    parsed = _parse(effect_id)
    if isinstance(parsed, int):
        k = parsed
        what = "the table angle" if k == 1 else f"{k} x the table angle"
        return EffectSpec(
            effect_id,
            {"amplitude_dps": "deg/s", "phase_deg": "deg"},
            f"bias varies with {what} (harmonic {k} of the table turn)",
            "table angle",
            n_columns=2,
            regressors=("angle",),
            formula=(f"bias varying with {what}: amplitude {{amplitude_dps:.4g}} deg/s, "
                     "phase {phase_deg:.3g} deg"),
        )
    labels, units, variables = [], [], []
    for tok, p in parsed:
        f = _factor_info(tok)
        labels.append(f.label + (f"^{p}" if p > 1 else ""))
        if f.unit:
            units.append(f.unit + (f"^{p}" if p > 1 else ""))
        variables.append(f.variable)
    regressors = tuple(dict.fromkeys(sorted(variables)))
    rate_only_once = [t for t, p in parsed if t == "w" and p == 1] and len(parsed) > 1
    if rate_only_once:  # w * g(x): a scale factor that depends on g
        rest = [lb for (t, _), lb in zip(parsed, labels, strict=True) if t != "w"]
        rest_units = [u for u in units if u != "deg/s"]
        unit = f"per ({' '.join(rest_units)})" if rest_units else ""
        text = f"scale factor proportional to {' x '.join(rest)}"
    else:
        unit = f"deg/s per ({' '.join(units)})" if units else "deg/s"
        text = f"bias proportional to {' x '.join(labels)}"
    return EffectSpec(
        effect_id,
        {"coeff": unit or "1"},
        text,
        " x ".join(labels),
        regressors=regressors,
        formula=f"{text}: {{coeff:.4g}} {unit}".rstrip(),
    )


def candidate_ids() -> tuple[str, ...]:
    """The library searched by the workflow: products of w, dT, dTdt, dV up to third order
    (the catalog's own left out), sign(w), |w| dT, rate x warm-up exponentials, angle
    harmonics 2 to 4, the temperature direction (hysteresis) as a bias and a scale, and the
    element-lagged rate as a bias and a scale."""
    toks = ("w", "dT", "dTdt", "dV")
    out: list[str] = []
    for powers in itertools.product(range(4), repeat=4):
        if not 1 <= sum(powers) <= 3 or powers in _CATALOG_MONOMIALS:
            continue
        parts = [t + (str(p) if p > 1 else "") for t, p in zip(toks, powers, strict=True) if p]
        out.append(PREFIX + "_".join(parts))
    out += [PREFIX + "sgnw", PREFIX + "absw_dT", PREFIX + "absw_dV"]
    out += [PREFIX + "dTdir", PREFIX + "w_dTdir"]
    out += [f"{PREFIX}dTdtlag{ELEMENT_LAG_S}s", f"{PREFIX}w_dTdtlag{ELEMENT_LAG_S}s"]
    out += [f"{PREFIX}w_exp{int(t)}s" for t in EXP_TAUS_S]
    out += [f"{PREFIX}angleh{k}" for k in range(2, MAX_HARMONIC + 1)]
    return tuple(out)


SPAN_FRACTION = 0.01  # a factor's power varying less than this apart from its lower powers


def spanned_ids(traj: Trajectory, ids: tuple[str, ...] | None = None) -> tuple[str, ...]:
    """The library terms whose every factor the data span: factor^p is not (to
    SPAN_FRACTION of its size) a combination of 1, factor, ..., factor^(p-1) over the
    record. Two supply levels, for example, do not span dV^2 (constant) nor dV^3 (~ dV); a
    constant supply does not span dV. On one axis of a three-axis part the terms that
    couple it to the other axes (cross_axis.py) join the library where the data span them."""
    ids = (*candidate_ids(), *cross_axis.candidate_ids(traj)) if ids is None else ids
    if _last_spanned and _last_spanned[0][0] is traj and _last_spanned[0][1] == ids:
        return _last_spanned[0][2]
    verdict: dict[tuple[str, int], bool] = {}
    out = []
    for e in ids:
        if cross_axis.is_cross_id(e):
            if e in cross_axis.candidate_ids(traj):
                out.append(e)
            continue
        parsed = _parse(e)
        if isinstance(parsed, int):
            out.append(e)
            continue
        ok = True
        for tok, p in parsed:
            if (tok, p) not in verdict:
                verdict[(tok, p)] = _spans_factor(tok, p, traj)
            ok = ok and verdict[(tok, p)]
        if ok:
            out.append(e)
    _last_spanned[:] = [(traj, ids, tuple(out))]
    return tuple(out)


_last_spanned: list[tuple[Trajectory, tuple[str, ...], tuple[str, ...]]] = []


DIRECTION_REACHED = 0.9  # |state| the temperature direction must reach on both sides


def _spans_factor(tok: str, power: int, traj: Trajectory) -> bool:
    """The data span the factor's power; the temperature direction only where the die was
    both heated and cooled (its state reaching +-DIRECTION_REACHED): on a record only ever
    heated it rises from 0 to +1 over the first degrees and stays there, which a warm-up
    drift or the bias explain as well (a hysteresis is seen only from both sides)."""
    x = _factor_values(tok, traj)
    if tok == "dTdir" and not (x.max() >= DIRECTION_REACHED and x.min() <= -DIRECTION_REACHED):
        return False
    return _spans(x, power)


def _spans(x: FloatArray, power: int) -> bool:
    scale = float(np.max(np.abs(x)))
    if scale == 0:
        return False
    u = x / scale
    target = u**power
    lower = np.stack([u**k for k in range(power)], axis=1)
    coef = np.linalg.lstsq(lower, target, rcond=None)[0]
    resid = target - lower @ coef
    return bool(np.linalg.norm(resid) > SPAN_FRACTION * np.linalg.norm(target))


_last_rate: list[tuple[Trajectory, FloatArray]] = []  # the last record's, reused by its terms


def temperature_rate_c_per_s(traj: Trajectory) -> FloatArray:
    """d(die temperature)/dt: the temperature smoothed over DTDT_SMOOTH_S (centred moving
    average within each contiguous stretch of samples), then differenced."""
    if _last_rate and _last_rate[0][0] is traj:
        return _last_rate[0][1]
    out = _temperature_rate(traj)
    _last_rate[:] = [(traj, out)]
    return out


def _temperature_rate(traj: Trajectory, lag_s: float = 0.0) -> FloatArray:
    """Over stretches joined across gaps shorter than BRIDGE_GAP_S (the die's temperature
    goes on through a gap of left-out samples): the temperature on a regular grid, smoothed,
    differenced, read back at the samples. Smoothed within each contiguous stretch instead,
    the rate sagged towards the stretch's ends (the average held at the edge): on a ramp whose
    supply alternates every sweep (eol-ramp) a stretch is a minute long, so a sixth of the
    record carried a wrong rate, a bias with the rate was taken for wander and not named."""
    from scipy.ndimage import uniform_filter1d  # slow to import: on first use

    out = np.zeros(traj.n)
    t = traj.time_s
    for a, b in _bridged_runs(t):
        if b - a < 3:
            continue
        dt = float(np.median(np.diff(t[a:b])))
        grid = np.arange(t[a], t[b - 1] + 0.5 * dt, dt)
        width = min(max(int(round(DTDT_SMOOTH_S / dt)), 1), grid.size)
        smooth = uniform_filter1d(np.interp(grid, t[a:b], traj.temp_c[a:b]), size=width,
                                  mode="nearest")
        rate = np.gradient(smooth, grid)
        if lag_s > 0:
            on = float(traj.time_since_power_on_s[a])  # the rate held since power-on
            rate = _low_pass(rate, dt, lag_s, float(rate[0]) * -math.expm1(-on / lag_s))
        out[a:b] = np.interp(t[a:b], grid, rate)
    return out


def lagged_temperature_rate(traj: Trajectory, lag_s: float) -> FloatArray:
    """dTdt low-passed causally (first order, time constant `lag_s`) on the same grid: the
    rate of an element at the sensor's temperature at power-on; each stretch (split at gaps
    longer than BRIDGE_GAP_S) starts as if its first rate had held since power-on."""
    return _temperature_rate(traj, lag_s)


def _low_pass(x: FloatArray, dt_s: float, tau_s: float, start: float) -> FloatArray:
    """y' = (x - y) / tau sampled every dt_s, exact for x held over each step; y(0) = start."""
    from scipy.signal import lfilter  # slow to import: on first use

    a = math.exp(-dt_s / tau_s)
    y, _ = lfilter([1.0 - a], [1.0, -a], x, zi=[a * start])
    return np.asarray(y, dtype=float)


BRIDGE_GAP_S = 30.0  # gaps in the sampling up to this long are bridged for the rate


def _bridged_runs(time_s: FloatArray) -> list[tuple[int, int]]:
    runs = contiguous_runs(time_s)
    out = [runs[0]] if runs else []
    for a, b in runs[1:]:
        if time_s[a] - time_s[out[-1][1] - 1] <= BRIDGE_GAP_S:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return out


def _smoothed_temperature(traj: Trajectory) -> FloatArray:
    """The die temperature, centred moving average over DTDT_SMOOTH_S within each
    contiguous stretch of samples (stretches under 3 samples kept as they are)."""
    # scipy.ndimage (slow to import): loaded on first use
    from scipy.ndimage import uniform_filter1d

    out = np.array(traj.temp_c, dtype=float)
    for a, b in contiguous_runs(traj.time_s):
        if b - a < 3:
            continue
        dt = float(np.median(np.diff(traj.time_s[a:b])))
        width = max(int(round(DTDT_SMOOTH_S / dt)), 1)
        out[a:b] = uniform_filter1d(traj.temp_c[a:b], size=min(width, b - a), mode="nearest")
    return out


def temperature_direction(traj: Trajectory) -> FloatArray:
    """The play-operator state of the smoothed die temperature, -1 (cooled) .. +1 (heated):
    the play follows the temperature at PLAY_HALF_WIDTH_C behind it, in time order over the
    whole record (gaps included: the part's thermal history goes on), starting at 0."""
    return play_state(_smoothed_temperature(traj), PLAY_HALF_WIDTH_C)


def play_state(temp_c: FloatArray, half_width_c: float) -> FloatArray:
    """(temp - play) / half-width of a play (backlash) operator, play(0) = temp(0)."""
    out = np.empty(temp_c.size)
    if temp_c.size == 0:
        return out
    play = float(temp_c[0])
    for i, t in enumerate(temp_c.tolist()):
        if t - play > half_width_c:
            play = t - half_width_c
        elif play - t > half_width_c:
            play = t + half_width_c
        out[i] = (t - play) / half_width_c
    return out


_last_factors: list[tuple[Trajectory, dict[str, FloatArray]]] = []  # the last record's


def _factor_values(tok: str, traj: Trajectory) -> FloatArray:
    """A factor's per-sample values; each computed once per record (the last one's kept)."""
    if not (_last_factors and _last_factors[0][0] is traj):
        _last_factors[:] = [(traj, {})]
    cache = _last_factors[0][1]
    if tok not in cache:
        cache[tok] = _compute_factor(tok, traj)
    return cache[tok]


def _compute_factor(tok: str, traj: Trajectory) -> FloatArray:
    w = traj.ref_rate_dps
    if tok.startswith("exp"):
        return np.exp(-traj.time_since_power_on_s / float(tok[3:-1]))
    if tok == "dTdt":
        return temperature_rate_c_per_s(traj)
    if tok.startswith("dTdtlag"):
        return lagged_temperature_rate(traj, float(tok[7:-1]))
    if tok == "dTdir":
        return temperature_direction(traj)
    compute = {"w": lambda: w, "dT": lambda: traj.dtemp_c, "dV": lambda: traj.dsupply_v,
               "sgnw": lambda: np.sign(w), "absw": lambda: np.abs(w)}
    return compute[tok]()


def columns(effect_id: str, traj: Trajectory) -> FloatArray:
    """Regressors (n, 1) of a product term, (n, 2) of an angle harmonic (or of a cross-axis
    drift term)."""
    if cross_axis.is_cross_id(effect_id):
        return cross_axis.columns(effect_id, traj)
    parsed = _parse(effect_id)
    if isinstance(parsed, int):
        a = parsed * np.deg2rad(traj.ref_angle_deg)
        return np.stack([np.cos(a), np.sin(a)], axis=1)
    col = np.ones(traj.n)
    for tok, p in parsed:
        col = col * _factor_values(tok, traj) ** p
    return col[:, None]


def to_params(
    effect_id: str, coefs: FloatArray, cov: FloatArray
) -> tuple[dict[str, float], dict[str, float]]:
    if cross_axis.is_cross_id(effect_id):
        return cross_axis.to_params(effect_id, coefs, cov)
    c = [float(v) for v in coefs]
    if len(c) == 1:
        return {"coeff": c[0]}, {"coeff": math.sqrt(max(float(cov[0, 0]), 0.0))}
    amp = math.hypot(c[0], c[1])
    phase = math.degrees(math.atan2(c[1], c[0]))
    if amp > 0:
        j_amp = np.array(c) / amp
        j_ph = np.array([-c[1], c[0]]) / amp**2
        s_amp = math.sqrt(max(float(j_amp @ cov @ j_amp), 0.0))
        s_ph = math.degrees(math.sqrt(max(float(j_ph @ cov @ j_ph), 0.0)))
    else:
        s_amp, s_ph = math.sqrt(max(float(cov[0, 0]), 0.0)), 180.0
    return {"amplitude_dps": amp, "phase_deg": phase}, {"amplitude_dps": s_amp, "phase_deg": s_ph}


def to_coefficients(effect_id: str, params: Mapping[str, float]) -> FloatArray:
    if cross_axis.is_cross_id(effect_id):
        return cross_axis.to_coefficients(effect_id, params)
    s = spec(effect_id)
    missing = [p for p in s.params if p not in params]
    if missing:
        raise ValueError(f"term {effect_id}: parameters {missing} are missing")
    if s.n_columns == 2:
        ph = math.radians(params["phase_deg"])
        return np.array([params["amplitude_dps"] * math.cos(ph),
                         params["amplitude_dps"] * math.sin(ph)])
    return np.array([params["coeff"]])
