"""Library terms that couple the axes of a three-axis part (issue 29), searched only on one
axis of a three-axis run folder (a Trajectory with `axis` and `axis_variables`, loaded by
run_folder_xyz.load_axis); a single-axis record never gets them.

On axis j, from another axis k:

| id | columns | what |
| --- | --- | --- |
| `lib_<j>from<k>_w_dT` | w_k, w_k dT | a cross-coupling (misalignment) drifting with temperature |
| `lib_<j>from<k>_a2` | a_x, a_y, a_z, a_k^2 | a g-squared cross term: bias with a_k^2 |

w_k is the reference rate along axis k, a_k the accelerometer's reading along k, dT the die
temperature - 25 C. The run's own fit took out a constant cross-coupling P_jk w_k; when the
true one drifts with dT, that fit absorbed its average, so the drift term carries the
constant column w_k with it (parameter `offset`, what the fit left) and `coeff` is the drift
per C. Likewise the g-squared term carries the linear a_x, a_y, a_z (`offset_x` ..., the
row of linear g-sensitivity the fit left): the procedure turns the cube to both faces along
k at one condition only, to one face per axis at the others, where the fit's linear row G_j
took up much of the even a_k^2 (with a_k^2 alone the coefficient came out at 0.66 of the
truth on two parts, with a_k and a_k^2 at 0.91). Each id
names the axes it couples (`lib_yfromx_w_dT`: couples y <- x), and so does its spec
(`couples`, the regressors `rate_x` ..., the formula).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from functools import lru_cache

import numpy as np

from procedures.model.effect_spec import EffectSpec
from procedures.model.trajectory import FloatArray, Trajectory

AXES = ("x", "y", "z")
SPAN_FRACTION = 0.01  # as library.SPAN_FRACTION: a column must vary this much on its own
_ID = re.compile(r"^lib_(?P<j>[xyz])from(?P<k>[xyz])_(?P<kind>w_dT|a2)$")


def is_cross_id(effect_id: str) -> bool:
    return _ID.match(effect_id) is not None


def _parse(effect_id: str) -> tuple[str, str, str]:
    m = _ID.match(effect_id)
    if m is None or m["j"] == m["k"]:
        raise ValueError(f"{effect_id!r} is not a cross-axis term (lib_<j>from<k>_w_dT or "
                         "lib_<j>from<k>_a2, j and k two different axes of x, y, z)")
    return m["j"], m["k"], m["kind"]


@lru_cache(maxsize=64)
def spec(effect_id: str) -> EffectSpec:
    j, k, kind = _parse(effect_id)
    if kind == "w_dT":
        return EffectSpec(
            effect_id,
            {"coeff": "per C", "offset": "1"},
            f"couples {j} <- {k}: the rate along {k} into axis {j}, a cross-coupling that "
            "drifts with the die temperature",
            f"rate along {k} x (die temperature - 25 C)",
            n_columns=2,
            regressors=(f"rate_{k}", "temperature"),
            formula=(f"couples {j} <- {k}: cross-coupling drifting with die temperature - "
                     "25 C: {coeff:.4g} per C (constant part the run's fit left: "
                     "{offset:.3g})"),
            couples=(j, k),
        )
    return EffectSpec(
        effect_id,
        {"coeff": "deg/s per (m/s^2)^2",
         **{f"offset_{a}": "deg/s per m/s^2" for a in AXES}},
        f"couples {j} <- {k}: a bias on axis {j} with the square of the specific force along "
        f"{k} (g-squared cross term)",
        f"(specific force along {k})^2",
        n_columns=4,
        regressors=(f"accel_{k}",),
        formula=(f"couples {j} <- {k}: bias proportional to (specific force along {k})^2: "
                 "{coeff:.4g} deg/s per (m/s^2)^2 (linear g-sensitivity the run's fit "
                 "left: {offset_x:.3g}, {offset_y:.3g}, {offset_z:.3g} deg/s per m/s^2)"),
        couples=(j, k),
    )


def columns(effect_id: str, traj: Trajectory) -> FloatArray:
    """[w_k, w_k dT] of a drift term, [a_x, a_y, a_z, a_k^2] of a g-squared term."""
    j, k, kind = _parse(effect_id)
    if traj.axis != j or f"rate_{k}" not in traj.axis_variables:
        raise ValueError(f"{effect_id} couples axis {j} to axis {k} of a three-axis part; this "
                         f"record is {'axis ' + traj.axis if traj.axis else 'a single-axis one'}"
                         ": leave the term out of its model")
    if kind == "w_dT":
        w = traj.axis_variables[f"rate_{k}"]
        return np.stack([w, w * traj.dtemp_c], axis=1)
    a = [traj.axis_variables[f"accel_{c}"] for c in AXES]
    return np.stack([*a, traj.axis_variables[f"accel_{k}"] ** 2], axis=1)


def to_params(effect_id: str, coefs: FloatArray, cov: FloatArray
              ) -> tuple[dict[str, float], dict[str, float]]:
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    names = _column_params(effect_id)
    return ({n: float(c) for n, c in zip(names, coefs, strict=True)},
            {n: float(v) for n, v in zip(names, sd, strict=True)})


def to_coefficients(effect_id: str, params: Mapping[str, float]) -> FloatArray:
    names = _column_params(effect_id)
    missing = [n for n in names if n not in params]
    if missing:
        raise ValueError(f"term {effect_id}: parameters {missing} are missing")
    return np.array([params[n] for n in names])


def _column_params(effect_id: str) -> tuple[str, ...]:
    """The parameters in the order of the term's columns."""
    if _parse(effect_id)[2] == "w_dT":
        return ("offset", "coeff")
    return (*(f"offset_{a}" for a in AXES), "coeff")


def candidate_ids(traj: Trajectory) -> tuple[str, ...]:
    """The cross-axis terms of a trajectory's axis that its data span: none on a single-axis
    record (no `axis`)."""
    if traj.axis not in AXES:
        return ()
    if _last_candidates and _last_candidates[0][0] is traj:
        return _last_candidates[0][1]
    out = []
    for k in AXES:
        if k == traj.axis:
            continue
        for kind in ("w_dT", "a2"):
            e = f"lib_{traj.axis}from{k}_{kind}"
            if _spanned(columns(e, traj)):
                out.append(e)
    _last_candidates[:] = [(traj, tuple(out))]
    return tuple(out)


_last_candidates: list[tuple[Trajectory, tuple[str, ...]]] = []  # the last record's


def _spanned(x: FloatArray) -> bool:
    """The term's own (last) column varies apart from a constant and the columns before it
    (what the run's fit left) by more than SPAN_FRACTION of its size; those are not 0."""
    if any(float(np.linalg.norm(c)) == 0 for c in x.T):
        return False
    own = x[:, -1]
    lower = np.column_stack([np.ones(x.shape[0]), x[:, :-1]])
    resid = own - lower @ np.linalg.lstsq(lower, own, rcond=None)[0]
    return bool(np.linalg.norm(resid) > SPAN_FRACTION * np.linalg.norm(own))
