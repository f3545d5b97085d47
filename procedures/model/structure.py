"""Structure the candidates explain, kept out of the noise; and what is left unexplained.

Two uses of the candidate pool (catalog + library) beyond naming:

* `nuisance_terms`: the library terms that explain significant structure on top of the full
  catalog model (Holm over the library at the workflow's alpha, two rounds). The bias wander
  is then estimated with them in the fixed effects, so an effect outside the catalog is not
  taken for noise and the floor stays honest.
* `unexplained_structure`: after the loop, for each base variable of the pinned vocabulary,
  the F test of every candidate depending on it added at once to the final model: the
  variables ranked by how strongly the residual pattern shows against them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import stats

from procedures.model import effects as fx
from procedures.model import library
from procedures.model.effect_spec import REGRESSOR_VOCABULARY
from procedures.model.fit import FitResult, Fitter
from procedures.model.gyro_model import GyroModel, zero_params

NUISANCE_ROUNDS = 2
MIN_INDEPENDENT_FRACTION = 1e-3


@dataclass(frozen=True)
class VariableTest:
    variable: str
    terms: tuple[str, ...]
    delta_chi2: float
    q: int
    f_statistic: float
    p_value: float


def _holm_significant(p_values: list[float], alpha: float) -> list[bool]:
    m = len(p_values)
    out = [False] * m
    for rank, i in enumerate(np.argsort(p_values)):
        if p_values[i] * (m - rank) > alpha:
            break
        out[i] = True
    return out


def _structure(model: GyroModel) -> dict[str, dict[str, float]]:
    return {e: fx.nonlinear_of(e, p) for e, p in model.effects.items()}


def _f_test(chi2_0: float, chi2_1: float, q: int, dof: int) -> tuple[float, float]:
    f_stat = (max(chi2_0 - chi2_1, 0.0) / q) / max(chi2_1 / max(dof, 1), 1e-300)
    return f_stat, float(stats.f.sf(f_stat, q, max(dof, 1)))


def nuisance_terms(fitter: Fitter, full: FitResult, alpha: float) -> list[str]:
    """Library terms significant on top of the full model (single-column solves: no
    profiling), added in rounds until none is left."""
    chosen: list[str] = []
    spanned = library.spanned_ids(fitter.traj)
    structure = _structure(full.model)
    chi2_0 = full.chi2
    for _round in range(NUISANCE_ROUNDS):
        pool = [e for e in spanned if e not in structure]
        pool = [e for e in pool
                if fitter.column_rank_gain(structure, e) >= MIN_INDEPENDENT_FRACTION]
        if not pool:
            break
        n_base = fitter.solve(structure).theta.size
        p_values = []
        for e in pool:
            sol = fitter.solve({**structure, e: {}})
            q = sol.theta.size - n_base
            p_values.append(_f_test(chi2_0, sol.chi2, q, fitter.blocks.count - sol.theta.size)[1])
        new = [e for e, s in zip(pool, _holm_significant(p_values, alpha), strict=True) if s]
        if not new:
            break
        chosen += new
        structure.update({e: {} for e in new})
        chi2_0 = fitter.solve(structure).chi2
    return chosen


def with_terms(model: GyroModel, terms: list[str]) -> GyroModel:
    out = model
    for e in terms:
        out = out.with_effect(e, zero_params(e))
    return out


def _terms_of(variable: str, present: Mapping[str, object], spanned: tuple[str, ...]
              ) -> list[str]:
    pool = [e for e in fx.CATALOG if e != "sensor_lag"] + list(spanned)
    return [e for e in pool
            if e not in present and variable in fx.check_effect_id(e).regressors]


def unexplained_structure(fitter: Fitter, current: FitResult) -> list[VariableTest]:
    """Each base variable's candidates added at once to the current model, F-tested; the
    variables ranked, strongest pattern first (lowest p, then largest F)."""
    structure = _structure(current.model)
    base = fitter.solve(structure)
    rank0 = int(np.linalg.matrix_rank(fitter.whiten(base.x_block)))
    out = []
    spanned = library.spanned_ids(fitter.traj)
    for v in REGRESSOR_VOCABULARY:
        terms = [e for e in _terms_of(v, structure, spanned)
                 if fitter.column_rank_gain(structure, e) >= MIN_INDEPENDENT_FRACTION]
        if not terms:
            continue
        trial = {**structure, **{e: fx.nonlinear_of(e, zero_params(e)) for e in terms}}
        sol = fitter.solve(trial)
        q = int(np.linalg.matrix_rank(fitter.whiten(sol.x_block))) - rank0
        if q <= 0:
            continue
        f_stat, p = _f_test(base.chi2, sol.chi2, q, fitter.blocks.count - rank0 - q)
        out.append(VariableTest(v, tuple(terms), max(base.chi2 - sol.chi2, 0.0), q, f_stat, p))
    out.sort(key=lambda t: (t.p_value, -t.f_statistic))
    return out


def describe(tests: list[VariableTest], gap_over_floor: float) -> str:
    """One line for the console, the JSON and the PDF."""
    ranked = ", ".join(
        f"{t.variable} (F {t.f_statistic:.3g}, p {t.p_value:.2g})" for t in tests[:3]
    )
    strongest = ranked or "no single base variable"
    return (
        f"unexplained structure remains: the gap is {gap_over_floor:.2f} x the noise floor "
        f"after the named effects; the residual pattern is strongest against {strongest}"
    )

