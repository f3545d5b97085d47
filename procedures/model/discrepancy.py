"""The model-discrepancy workflow: find the gap, name the effect, add it, refit, repeat.

Each iteration tests every catalog effect not yet in the model by adding it and refitting.
Significance: F test of the whitened chi^2 drop, F = (dchi2 / q) / (chi2_1 / dof_1), with q
the effect's linear coefficients plus its profiled time constant; the family-wise false
alarm rate over all candidates of the iteration is held at `alpha` with Holm's step-down
procedure. Among significant candidates the best is the one with the lowest BIC. If another
significant candidate fits almost the same signature (whitened signature correlation above
`SEPARABLE_CORRELATION`) and its BIC is within `SEPARABLE_DELTA_BIC`, the data cannot tell
them apart: if one of them is the main effect every other one descends from (lib_dTdt and
lib_dTdt_dV), it is named (parsimony, marginality.parsimonious); otherwise they are reported
as not separable and none is added (nor later a look-alike of theirs); the other effects are
still named in turn. A term is named only when it shrinks
the gap, and an interaction only once its main effects are in the model or shown not to
explain the gap (marginality.py).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Collection
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from procedures.model import effects as fx
from procedures.model import library, marginality, structure
from procedures.model.blocks import Blocks, make_blocks
from procedures.model.data import check_rate_varies
from procedures.model.fit import FitResult, Fitter
from procedures.model.gyro_model import GyroModel, zero_params
from procedures.model.lag import contiguous_runs
from procedures.model.noise import NoiseModel, measure_noise
from procedures.model.reml import estimate_slow_noise
from procedures.model.residuals import (
    BinSummary,
    about_mean,
    floor_dps,
    record_gap_dps,
    summarize,
    worst_z,
)
from procedures.model.trajectory import FloatArray, Trajectory

log = logging.getLogger(__name__)

DEFAULT_ALPHA = 0.01
SEPARABLE_CORRELATION = 0.9
SEPARABLE_DELTA_BIC = 10.0
MIN_INDEPENDENT_FRACTION = 1e-3  # below this an effect's regressor is already in the model
MAX_ITERATIONS = 20  # the catalog's ten and the library's terms, each named in turn
CATALOG_ALPHA_SHARE = 0.9  # of the family-wise alpha, spent on the catalog's candidates
UNEXPLAINED_GAP_RATIO = 1.5  # gap above this x floor after the loop: structure remains
# library terms of the die's thermal history held in the full model the bias wander is
# estimated against, like the catalog's effects (issue 29): on one heating-and-cooling ramp
# a bias with the die's rate of change (gradient, the element's lag) or its direction
# (hysteresis) is as slow as the wander, and was taken for it (a hysteresis of 0.03 deg/s
# alone: named on 1 of 4 eol-ramp folders without these terms, 3 of 4 with them)
THERMAL_WANDER_TERMS = ("lib_dTdt", "lib_w_dTdt", "lib_dTdir")


@dataclass(frozen=True)
class CandidateTest:
    effect: str
    delta_chi2: float
    q: int
    f_statistic: float
    p_value: float
    p_holm: float
    bic: float
    delta_bic: float  # BIC of the candidate minus BIC of the current model (negative: better)
    significant: bool
    parameters: dict[str, float]
    uncertainties: dict[str, float]
    fit: FitResult | None = None
    # the candidate's fit shrinks the gap by more than noise alone would (judged only for
    # significant candidates)
    shrinks_gap: bool = False
    # main effects it waits for (marginality.py): significant, not yet in the model
    waits_for: tuple[str, ...] = ()

    @property
    def named_candidate(self) -> bool:
        """May be named in this iteration: significant, shrinks the gap, waits for nothing."""
        return self.significant and self.shrinks_gap and not self.waits_for


@dataclass(frozen=True)
class Iteration:
    effect: str
    gap_before_dps: float
    gap_after_dps: float
    parameters: dict[str, float]
    uncertainties: dict[str, float]
    evidence: dict[str, Any]
    candidates: tuple[CandidateTest, ...]
    residual_before_dps: FloatArray
    residual_after_dps: FloatArray
    regressors: tuple[str, ...] = ()  # base variables the term depends on (pinned vocabulary)
    formula: str = ""  # readable formula with the fitted values


@dataclass(frozen=True)
class DiscrepancyResult:
    initial_model: GyroModel
    final_model: GyroModel
    noise: NoiseModel
    blocks: Blocks
    sigma_block_dps: FloatArray
    gap_initial_dps: float
    noise_floor_dps: float
    iterations: tuple[Iteration, ...]
    gap_final_dps: float
    residual_initial_dps: FloatArray
    residual_final_dps: FloatArray
    summary_initial: dict[str, list[BinSummary]]
    summary_final: dict[str, list[BinSummary]]
    not_separable: tuple[dict[str, Any], ...] = ()
    not_identifiable: tuple[str, ...] = ()
    last_candidates: tuple[CandidateTest, ...] = ()
    alpha: float = DEFAULT_ALPHA
    notes: tuple[str, ...] = field(default_factory=tuple)
    # library terms held in the fixed effects when the bias wander was estimated
    noise_nuisance_terms: tuple[str, ...] = ()
    # when the gap stays above UNEXPLAINED_GAP_RATIO x floor: base variables ranked by how
    # strongly the final residual shows against them (strongest first)
    unexplained: tuple[structure.VariableTest, ...] = ()

    @property
    def effects_added(self) -> list[str]:
        return [it.effect for it in self.iterations]

    @property
    def unexplained_remains(self) -> bool:
        return self.gap_final_dps > UNEXPLAINED_GAP_RATIO * self.noise_floor_dps

    @property
    def unexplained_message(self) -> str:
        if not self.unexplained_remains:
            return ""
        return structure.describe(list(self.unexplained),
                                  self.gap_final_dps / self.noise_floor_dps)


def bic(fit: FitResult) -> float:
    return fit.chi2 + fit.n_params * math.log(fit.n_blocks)


def holm(p_values: list[float], weights: list[float] | None = None) -> list[float]:
    """Holm step-down adjusted p-values (family-wise error control); with `weights` the
    weighted Holm procedure (Holm 1979): hypothesis i spends a share w_i of alpha, each step
    compares p_i / w_i with alpha / (sum of the weights not yet rejected)."""
    m = len(p_values)
    w = np.ones(m) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    ratio = np.asarray(p_values, dtype=float) / w
    order = np.argsort(ratio)
    adjusted = np.empty(m)
    running = 0.0
    remaining = 1.0
    for i in order:
        running = max(running, min(1.0, ratio[i] * remaining))
        adjusted[i] = running
        remaining -= w[i]
    return adjusted.tolist()


def holm_weights(effects: list[str]) -> list[float]:
    """Catalog candidates share CATALOG_ALPHA_SHARE of alpha, library terms the rest: the
    catalog holds what the physics expects and keeps its power, the library widens the
    search without diluting it; the family-wise rate over both together stays alpha."""
    n_lib = sum(library.is_library_id(e) for e in effects)
    n_cat = len(effects) - n_lib
    if n_lib == 0 or n_cat == 0:
        return [1.0] * len(effects)
    return [(1 - CATALOG_ALPHA_SHARE) / n_lib if library.is_library_id(e)
            else CATALOG_ALPHA_SHARE / n_cat for e in effects]


def _candidate(fitter: Fitter, current: FitResult, effect_id: str) -> tuple[FitResult, float]:
    trial = current.model.with_effect(effect_id, zero_params(effect_id))
    fit = fitter.fit(trial, profile=[effect_id])
    return fit, max(current.chi2 - fit.chi2, 0.0)


def test_candidates(
    fitter: Fitter, current: FitResult, alpha: float, use_library: bool = True
) -> tuple[list[CandidateTest], list[str]]:
    """Add each missing catalog effect and library term in turn; F test, Holm adjustment
    over catalog and library together, BIC. Library terms the data do not span (or that the
    current model already spans) are left out silently; catalog effects so left out are
    returned as not identifiable."""
    pool = [*fx.CATALOG, *(library.spanned_ids(fitter.traj) if use_library else ())]
    missing = [e for e in pool if e not in current.model.effects]
    base_structure = {e: fx.nonlinear_of(e, p) for e, p in current.model.effects.items()}
    raw: list[tuple[str, FitResult, float, int, float, float]] = []
    not_identifiable = []
    for e in missing:
        if fitter.column_rank_gain(base_structure, e) < MIN_INDEPENDENT_FRACTION:
            if not library.is_library_id(e):
                not_identifiable.append(e)
            continue
        fit, dchi2 = _candidate(fitter, current, e)
        q = fit.n_params - current.n_params
        dof = max(fit.dof, 1)
        f_stat = (dchi2 / q) / max(fit.chi2 / dof, 1e-300)
        p = float(stats.f.sf(f_stat, q, dof))
        raw.append((e, fit, dchi2, q, f_stat, p))
    adjusted = holm([r[5] for r in raw], holm_weights([r[0] for r in raw])) if raw else []
    bic0 = bic(current)
    tests = []
    for (e, fit, dchi2, q, f_stat, p), p_adj in zip(raw, adjusted, strict=True):
        params = dict(fit.model.effects[e])
        unc = _uncertainties_of(fit.model, e)
        tests.append(
            CandidateTest(
                effect=e,
                delta_chi2=dchi2,
                q=q,
                f_statistic=f_stat,
                p_value=p,
                p_holm=p_adj,
                bic=bic(fit),
                delta_bic=bic(fit) - bic0,
                significant=p_adj <= alpha,
                parameters=params,
                uncertainties=unc,
                fit=fit,
            )
        )
    tests.sort(key=lambda c: c.bic)
    return tests, not_identifiable


def run_discrepancy(
    traj: Trajectory,
    model: GyroModel,
    alpha: float = DEFAULT_ALPHA,
    max_block_s: float = 10.0,
    max_iterations: int = MAX_ITERATIONS,
    use_library: bool = True,
) -> DiscrepancyResult:
    """Fit, find the gap, name effects one at a time until none is significant.

    The dense algebra here is many small (hundreds-square) factorisations, for which a
    multi-threaded BLAS only adds overhead and, on a busy machine, stalls badly (measured
    70x slower on 2 shared cores): BLAS runs single-threaded for the duration.
    """
    with _single_thread_blas():
        return _run(traj, model, alpha, max_block_s, max_iterations, use_library)


def _single_thread_blas() -> AbstractContextManager[object]:
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # optional: without it only the speed differs
        return nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def _signature_correlation(current: FitResult, a: FitResult, b: FitResult) -> float:
    sa = a.fitted_white - current.fitted_white
    sb = b.fitted_white - current.fitted_white
    na, nb = np.linalg.norm(sa), np.linalg.norm(sb)
    if na == 0 or nb == 0:
        return 0.0
    return float(abs(sa @ sb) / (na * nb))


def _centred(fit: FitResult, blocks: Blocks) -> FloatArray:
    """A fit's block residuals about their duration-weighted mean, as the gap and the floor
    see them (residuals.py)."""
    return about_mean(fit.residual_dps, blocks.duration_s)


def _shrinks(blocks: Blocks, before: FloatArray, after: FloatArray, q: int,
             floor: float) -> bool:
    """The gap squared falls by more than q columns of noise alone would take out of it
    (about q / n_blocks of the floor squared): a significant drop of the whitened chi^2
    that leaves the gap as it was, or larger, explains nothing of it."""
    g0 = record_gap_dps(before, blocks.duration_s)
    g1 = record_gap_dps(after, blocks.duration_s)
    return g0**2 - g1**2 > max(q, 1) * floor**2 / blocks.count


def _judge(tests: list[CandidateTest], current: FitResult, blocks: Blocks,
           noise: NoiseModel) -> list[CandidateTest]:
    """Each candidate with whether it shrinks the gap and the main effects it waits for.
    A main effect that is significant but does not shrink the gap has been shown not to
    explain it, so it holds no interaction back."""
    floor = floor_dps(noise.floor_per_block_dps(blocks), blocks.duration_s)
    explains = {
        c.effect: c.significant and c.fit is not None
        and _shrinks(blocks, current.residual_dps, c.fit.residual_dps, c.q, floor)
        for c in tests
    }
    in_model = set(current.model.effects)
    return [replace(c, shrinks_gap=explains[c.effect],
                    waits_for=marginality.waiting_for(c.effect, in_model, explains))
            for c in tests]


def _choose(
    fitter: Fitter, current: FitResult, tests: list[CandidateTest], blocks: Blocks,
    set_aside: Collection[str] = (),
) -> _Chosen | dict[str, Any] | None:
    """The effect to name (lowest BIC among those that may be named) and the model with it,
    every time constant refitted together; the not-separable report when a look-alike is
    as good and neither descends from the other (of a main effect and its interaction the
    main effect is named: marginality.parsimonious); None when nothing may be named. A
    candidate whose refit no longer shrinks the gap is passed over for the next. Effects
    set aside (reported not separable earlier) are not named, nor a candidate whose
    signature looks like one of theirs."""
    aside = [c.fit for c in tests if c.effect in set_aside and c.fit is not None]
    eligible = [
        c for c in tests
        if c.named_candidate and c.effect not in set_aside and c.fit is not None
        and all(_signature_correlation(current, c.fit, a) < SEPARABLE_CORRELATION
                for a in aside)
    ]
    floor = floor_dps(fitter.noise.floor_per_block_dps(blocks), blocks.duration_s)
    passed: set[str] = set()  # a main effect passed over takes its look-alikes with it
    for i, best in enumerate(eligible):
        if best.effect in passed:
            continue
        rivals = _look_alikes(current, best, eligible[i + 1:])
        preferred_over: tuple[str, ...] = ()
        if rivals:
            group = [best, *[r for r, _ in rivals]]
            main = marginality.parsimonious([c.effect for c in group])
            if main is None:
                return _not_separable(best, rivals)
            preferred_over = tuple(c.effect for c in group if c.effect != main)
            best = next(c for c in group if c.effect == main)
        assert best.fit is not None
        new = fitter.fit(best.fit.model, local=True)  # every time constant refitted together
        if _shrinks(blocks, current.residual_dps, new.residual_dps, best.q, floor):
            return _Chosen(best, new, preferred_over)
        log.info("%s passed over: refitted, it does not shrink the gap", best.effect)
        passed.update({best.effect, *preferred_over})
    return None


@dataclass(frozen=True)
class _Chosen:
    """The candidate to name, the model with it refitted, and the look-alike interactions
    it was named before (the marginality principle)."""

    best: CandidateTest
    new: FitResult
    preferred_over: tuple[str, ...] = ()


def _look_alikes(current: FitResult, best: CandidateTest, others: list[CandidateTest]
                 ) -> list[tuple[CandidateTest, float]]:
    """The candidates (after `best` in BIC order) with almost its signature (correlation at
    least SEPARABLE_CORRELATION) and a BIC within SEPARABLE_DELTA_BIC of its own."""
    assert best.fit is not None
    rivals = []
    for other in others:
        assert other.fit is not None
        corr = _signature_correlation(current, best.fit, other.fit)
        if corr >= SEPARABLE_CORRELATION and other.bic - best.bic < SEPARABLE_DELTA_BIC:
            rivals.append((other, corr))
    return rivals


def _not_separable(best: CandidateTest, rivals: list[tuple[CandidateTest, float]]
                   ) -> dict[str, Any]:
    return {
        "effects": [best.effect, *[r.effect for r, _ in rivals]],
        "delta_bic": [round(r.bic - best.bic, 3) for r, _ in rivals],
        "signature_correlation": [round(c, 4) for _, c in rivals],
        "reason": (
            "each explains the gap about equally well with almost the same "
            "residual signature; the data (e.g. the rate set) cannot tell them "
            "apart, so none was added"
        ),
    }


def _run(
    traj: Trajectory,
    model: GyroModel,
    alpha: float = DEFAULT_ALPHA,
    max_block_s: float = 10.0,
    max_iterations: int = MAX_ITERATIONS,
    use_library: bool = True,
) -> DiscrepancyResult:
    check_rate_varies(traj.ref_rate_dps, traj.source)
    blocks = make_blocks(traj, max_block_s=max_block_s)
    noise, nuisance = measure_record_noise(traj, blocks, model, alpha, use_library)
    fitter = Fitter(traj, blocks, noise)
    initial = fitter.fit(model)
    found = _search(fitter, initial, blocks, alpha, max_iterations, use_library)
    return _result(traj, model, fitter, initial, found, alpha, nuisance)


@dataclass
class _Search:
    """Where the naming loop got to: the model so far, the effects named, those it could not
    tell apart or identify, and the last iteration's candidates."""

    current: FitResult
    iterations: list[Iteration] = field(default_factory=list)
    not_separable: list[dict[str, Any]] = field(default_factory=list)
    not_identifiable: list[str] = field(default_factory=list)
    tests: list[CandidateTest] = field(default_factory=list)


def _search(
    fitter: Fitter,
    initial: FitResult,
    blocks: Blocks,
    alpha: float,
    max_iterations: int,
    use_library: bool,
) -> _Search:
    """Name effects one at a time until none may be named (or `max_iterations`)."""
    found = _Search(initial)
    if max_iterations == 0:
        found.tests, found.not_identifiable = test_candidates(fitter, initial, alpha, use_library)
    set_aside: set[str] = set()  # reported not separable: neither is named, nor a look-alike
    for _ in range(max_iterations):
        current = found.current
        tests, found.not_identifiable = test_candidates(fitter, current, alpha, use_library)
        tests = found.tests = _judge(tests, current, blocks, fitter.noise)
        chosen = _choose(fitter, current, tests, blocks, set_aside)
        if isinstance(chosen, dict):
            # the look-alikes are set aside; the part's other effects are still named in turn
            found.not_separable.append(chosen)
            set_aside.update(chosen["effects"])
            continue
        if chosen is None:
            break
        best, new = chosen.best, chosen.new
        named = _iteration(fitter, _Naming(current, new, best, tests, chosen.preferred_over),
                           alpha)
        found.iterations.append(named)
        log.info("named %s: gap %.4g -> %.4g", best.effect, named.gap_before_dps,
                 named.gap_after_dps)
        found.current = new
    return found


def _uncertainties_of(model: GyroModel, effect: str) -> dict[str, float]:
    """The uncertainties of one effect's parameters, by parameter name."""
    return {
        k.split(".", 1)[1]: v
        for k, v in model.uncertainties.items()
        if k.startswith(effect + ".")
    }


@dataclass(frozen=True)
class _Naming:
    """An effect named: the model before (`current`) and with it (`new`), the candidate named
    (`best`), and all the candidates of that iteration."""

    current: FitResult
    new: FitResult
    best: CandidateTest
    tests: list[CandidateTest]
    # look-alike interactions of `best` that fitted about as well (named: the main effect)
    preferred_over: tuple[str, ...] = ()


def _iteration(fitter: Fitter, naming: _Naming, alpha: float) -> Iteration:
    """The record of an effect named."""
    blocks = fitter.blocks
    current, new, best, tests = naming.current, naming.new, naming.best, naming.tests
    return Iteration(
        effect=best.effect,
        gap_before_dps=record_gap_dps(current.residual_dps, blocks.duration_s),
        gap_after_dps=record_gap_dps(new.residual_dps, blocks.duration_s),
        parameters=dict(new.model.effects[best.effect]),
        uncertainties=_uncertainties_of(new.model, best.effect),
        evidence=_evidence(fitter, naming, alpha),
        candidates=tuple(tests),
        residual_before_dps=_centred(current, blocks),
        residual_after_dps=_centred(new, blocks),
        regressors=fx.check_effect_id(best.effect).regressors,
        formula=fx.formula_of(best.effect, new.model.effects[best.effect]),
    )


def _evidence(fitter: Fitter, naming: _Naming, alpha: float) -> dict[str, Any]:
    """Why it was named: its tests, the runner-up, and the residual pattern it removed."""
    blocks = fitter.blocks
    current, new, best, tests = naming.current, naming.new, naming.best, naming.tests
    significant = [c for c in tests if c.named_candidate]
    sigma_now = fitter.noise.floor_per_block_dps(blocks)
    summary_before = summarize(blocks, _centred(current, blocks), sigma_now)
    summary_after = summarize(blocks, _centred(new, blocks), sigma_now)
    zb, za = worst_z(summary_before), worst_z(summary_after)
    pattern = max(zb, key=lambda k: zb[k] - za[k])
    later = significant[significant.index(best) + 1:]  # those passed over are not rivals
    later = [c for c in later if c.effect not in naming.preferred_over]
    runner = later[0] if later else None
    parsimony = ({"preferred_over": list(naming.preferred_over),
                  "rule": _parsimony_rule(best.effect, naming.preferred_over)}
                 if naming.preferred_over else {})
    return {
        **parsimony,
        "delta_chi2": round(best.delta_chi2, 3),
        "f_statistic": round(best.f_statistic, 3),
        "p_value": best.p_value,
        "p_holm": best.p_holm,
        "alpha_familywise": alpha,
        "n_candidates": len(tests),
        "delta_bic": round(best.delta_bic, 3),
        "runner_up": (
            {"effect": runner.effect, "delta_bic_vs_best": round(runner.bic - best.bic, 3)}
            if runner
            else None
        ),
        "uncertainties": best.uncertainties,
        "pattern": {
            "variable": pattern,
            "worst_z_before": round(zb[pattern], 2),
            "worst_z_after": round(za[pattern], 2),
            "expected": fx.check_effect_id(best.effect).pattern,
        },
    }


def _parsimony_rule(named: str, over: tuple[str, ...]) -> str:
    """Why `named` was named before its look-alikes `over` (marginality.parsimonious)."""
    same = marginality.instant_form(named)
    if all(marginality.instant_form(e) == same for e in over):
        return ("a term and its element-lagged variant: the one of lower BIC is named")
    return "marginality: of look-alikes, the main effect is named"


def _result(
    traj: Trajectory,
    model: GyroModel,
    fitter: Fitter,
    initial: FitResult,
    found: _Search,
    alpha: float,
    nuisance: list[str],
) -> DiscrepancyResult:
    blocks = fitter.blocks
    current = found.current
    noise = fitter.noise
    sigma = noise.floor_per_block_dps(blocks)
    floor = floor_dps(sigma, blocks.duration_s)
    gap_final = record_gap_dps(current.residual_dps, blocks.duration_s)
    unexplained: tuple[structure.VariableTest, ...] = ()
    if gap_final > UNEXPLAINED_GAP_RATIO * floor:
        unexplained = tuple(structure.unexplained_structure(fitter, current))
    final_model = GyroModel(
        name=_model_name(model.name, [it.effect for it in found.iterations]),
        bias_dps=current.model.bias_dps,
        scale=current.model.scale,
        effects=current.model.effects,
        uncertainties=current.model.uncertainties,
    )
    return DiscrepancyResult(
        initial_model=initial.model,
        final_model=final_model,
        noise=noise,
        blocks=blocks,
        sigma_block_dps=sigma,
        gap_initial_dps=record_gap_dps(initial.residual_dps, blocks.duration_s),
        noise_floor_dps=floor,
        iterations=tuple(found.iterations),
        gap_final_dps=gap_final,
        residual_initial_dps=_centred(initial, blocks),
        residual_final_dps=_centred(current, blocks),
        summary_initial=summarize(blocks, _centred(initial, blocks), sigma),
        summary_final=summarize(blocks, _centred(current, blocks), sigma),
        not_separable=tuple(found.not_separable),
        not_identifiable=tuple(found.not_identifiable),
        last_candidates=tuple(found.tests),
        alpha=alpha,
        notes=traj.notes,
        noise_nuisance_terms=tuple(nuisance),
        unexplained=unexplained,
    )


def measure_record_noise(
    traj: Trajectory,
    blocks: Blocks,
    model: GyroModel,
    alpha: float = DEFAULT_ALPHA,
    use_library: bool = True,
) -> tuple[NoiseModel, list[str]]:
    """The record's noise: white level from the Allan deviation of the starting model's
    residual in constant-input windows; slow wander (flat level, rate random walk) by REML
    from the block residuals of the full model (every catalog effect but the lag, and the
    library terms significant on top of it), so structure a candidate explains is not taken
    for bias wander. Returns the noise model and those library terms."""
    white_only = NoiseModel(1.0, 0.0, np.zeros(0), np.zeros(0))
    first = Fitter(traj, blocks, white_only).fit(model)
    allan = measure_noise(traj.gyro_dps - first.model.predict(traj), traj.time_s, blocks)
    full = model
    # sensor_lag enters linearised (a lag tau shifts the output by -tau * d(rate)/dt, exact
    # to first order for a lag much shorter than the rate changes): low-passing the whole
    # design upsets the restricted likelihood, and leaving the lag out would let its
    # signature in the transitions be taken for bias wander
    # (also when the starting model holds a lag: its profiled tau would low-pass the design)
    full = replace(full, effects={e: p for e, p in full.effects.items() if e != "sensor_lag"})
    for e in fx.CATALOG:
        if e not in full.effects and e != "sensor_lag":
            full = full.with_effect(e, zero_params(e))
    if use_library:  # the thermal terms too, so a heat-and-cool cycle's is not wander
        thermal = library.spanned_ids(traj, THERMAL_WANDER_TERMS)
        full = structure.with_terms(full, [e for e in thermal if e not in full.effects])
    accel = blocks.mean(_rate_change_dps2(traj))
    noise = _reml(traj, blocks, allan, full, accel)
    nuisance: list[str] = []
    if use_library:
        # structure outside the catalog: found against the first estimate, then the wander
        # is estimated again with it in the fixed effects
        fitter = Fitter(traj, blocks, noise)
        nuisance = structure.nuisance_terms(fitter, fitter.fit(full), alpha)
        if nuisance:
            noise = _reml(traj, blocks, allan, structure.with_terms(full, nuisance), accel)
    log.info("slow noise (REML, full model%s): F %.3g deg/s, K %.3g deg/s/sqrt(s)",
             f" + {', '.join(nuisance)}" if nuisance else "", noise.floor_dps,
             noise.rrw_dps_per_rt_s)
    return noise, nuisance


def _reml(
    traj: Trajectory, blocks: Blocks, allan: NoiseModel, full: GyroModel, accel: FloatArray
) -> NoiseModel:
    fitter = Fitter(traj, blocks, allan)
    design = fitter.design(fitter.fit(full).model)
    if np.any(accel != 0):
        design = np.column_stack([design, -accel])
    return estimate_slow_noise(allan, blocks, design, fitter.y_block)


def _rate_change_dps2(traj: Trajectory) -> FloatArray:
    """d(reference rate)/dt per sample, zero across gaps in the sampling."""
    out = np.zeros(traj.n)
    for a, b in contiguous_runs(traj.time_s):
        if b - a > 2:
            out[a:b] = np.gradient(traj.ref_rate_dps[a:b], traj.time_s[a:b])
    return out


def _model_name(start: str, added: list[str]) -> str:
    return "+".join([start, *added]) if added else start
