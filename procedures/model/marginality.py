"""The marginality principle for the candidates: an interaction waits for its main effects.

An interaction is a product of factors of two or more different variables (w dT, dTdt dV,
w dTdt dV, |w| dT, w exp(-t/tau)); a power (dT^2, w^3) is held to the same hierarchy (dT^2
waits for dT, w^3 for w^2). Fitted before its main effects, a term takes for itself
structure they would explain (on a part with several effects, a bias ~ d(die
temperature)/dt x (supply - 5.0 V) was named where a warm-up drift and the supply
coefficient belonged, at -15 deg/s per (C/s V)). So an interaction is a candidate for
naming only once each of its main effects is in the model, or has been shown not to explain
the gap (tested in the same iteration and not significant, or not testable there: the data
or the model already span it).

The main effects of a product are the products left when the power of one of its factors
is lowered by one (so w dTdt dV waits for dTdt dV, w dV and w dTdt; w dT^2 for dT^2 and
w dT: the polynomial hierarchy), named as the workflow names them: the
catalog's id where the catalog holds the term (w dT is scale_temperature, dT
bias_temperature, w^2 k2_quadratic, |w| scale_asymmetry, exp(-t/tau) warmup_drift), the
scale for w alone and the bias for a constant (always in the model), else the library id.
A single factor (dT, dTdt, sign(w), w^2 over w) and the angle harmonics wait for nothing.

The same principle settles look-alikes (`parsimonious`): where a term and an interaction
descending from it explain the gap about equally well with almost the same signature (lib_dTdt
and lib_dTdt_dV2 on a record whose temperature moves only at one supply), the main effect is
named, the simpler explanation; terms of which none descends from the others stay not
separable. A term and its element-lagged variant (the die's rate read at the sensor or at a
sensing element that follows it, dTdt or dTdtlag20s: lib_w_dTdt and lib_w_dTdtlag20s) are
one effect of the same variables in two forms: of look-alike variants, the one the data fit
better (the lower BIC, the first given) stands for both.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from functools import lru_cache

from procedures.model import cross_axis, library

IN_EVERY_MODEL = "scale"  # w alone: every model has a scale
# as library.candidate_ids spells ids
_TOKEN_ORDER = ("w", "dT", "dTdt", "dV", "sgnw", "absw", "dTdir")
# monomials the catalog holds, by their factors (token -> power)
_CATALOG_TERMS: dict[frozenset[tuple[str, int]], str] = {
    frozenset({("w", 1)}): IN_EVERY_MODEL,
    frozenset({("dT", 1)}): "bias_temperature",
    frozenset({("dV", 1)}): "bias_supply",
    frozenset({("w", 1), ("dT", 1)}): "scale_temperature",
    frozenset({("w", 1), ("dV", 1)}): "scale_supply",
    frozenset({("w", 2)}): "k2_quadratic",
    frozenset({("w", 3)}): "k3_cubic",
    frozenset({("absw", 1)}): "scale_asymmetry",
}
# catalog interactions, by their factors (the library's own are parsed from their ids)
_CATALOG_FACTORS: dict[str, tuple[tuple[str, int], ...]] = {
    "scale_temperature": (("w", 1), ("dT", 1)),
    "scale_supply": (("w", 1), ("dV", 1)),
    "k2_quadratic": (("w", 2),),
    "k3_cubic": (("w", 3),),
}


def _term_id(factors: Collection[tuple[str, int]]) -> str:
    """The id the workflow gives the product of these factors."""
    key = frozenset(factors)
    if key in _CATALOG_TERMS:
        return _CATALOG_TERMS[key]
    exps = [t for t, _ in factors if t.startswith("exp")]
    if exps and len(factors) == 1:
        return "warmup_drift"  # exp(-t/tau) alone: the catalog's, with its tau fitted
    ordered = sorted(factors, key=lambda f: (_TOKEN_ORDER.index(f[0])
                                             if f[0] in _TOKEN_ORDER else len(_TOKEN_ORDER)))
    return library.PREFIX + "_".join(t + (str(p) if p > 1 else "") for t, p in ordered)


def _factors(effect_id: str) -> tuple[tuple[str, int], ...]:
    if effect_id in _CATALOG_FACTORS:
        return _CATALOG_FACTORS[effect_id]
    if not library.is_library_id(effect_id) or cross_axis.is_cross_id(effect_id):
        return ()  # a cross-axis term's constant column travels with it: it waits for none
    parsed = library._parse(effect_id)  # noqa: SLF001 - the ids' own grammar
    return () if isinstance(parsed, int) else tuple(parsed)


@lru_cache(maxsize=1024)
def main_effects(effect_id: str) -> tuple[str, ...]:
    """The terms a product waits for (empty for a single factor or an angle harmonic); the
    bias and the scale, in every model, are left out."""
    factors = _factors(effect_id)
    out = []
    for tok, p in factors:  # one factor's power lowered by one (w dT^2: dT^2 and w dT)
        rest = [(t, q) for t, q in factors if t != tok] + ([(tok, p - 1)] if p > 1 else [])
        if not rest:
            continue  # a single factor: its parent is the bias, in every model
        term = _term_id(rest)
        if term != IN_EVERY_MODEL and term not in out:
            out.append(term)
    return tuple(out)


def waiting_for(
    effect_id: str, in_model: Collection[str], significant: Mapping[str, bool]
) -> tuple[str, ...]:
    """The main effects of `effect_id` that hold it back in this iteration: not in the
    model and significant among this iteration's candidates. A main effect not among them
    was not testable here (the data or the model span it) and holds nothing back."""
    return tuple(m for m in main_effects(effect_id)
                 if m not in in_model and significant.get(m, False))


@lru_cache(maxsize=1024)
def ancestors(effect_id: str) -> frozenset[str]:
    """Every term `effect_id` descends from through main effects (its main effects, theirs,
    and so on): lib_dTdt_dV2 descends from lib_dTdt_dV, bias_supply, lib_dV2 and lib_dTdt."""
    out: set[str] = set()
    todo = list(main_effects(effect_id))
    while todo:
        term = todo.pop()
        if term not in out:
            out.add(term)
            todo.extend(main_effects(term))
    return frozenset(out)


def instant_form(effect_id: str) -> str:
    """The term with the element-lagged rate read at the sensor instead (lib_w_dTdtlag20s:
    lib_w_dTdt); any other term as it is."""
    if not library.is_library_id(effect_id):
        return effect_id
    return library.PREFIX + "_".join(
        "dTdt" if tok.startswith("dTdtlag") else tok
        for tok in effect_id[len(library.PREFIX):].split("_"))


def parsimonious(look_alikes: Sequence[str]) -> str | None:
    """Of terms that explain the gap about equally well with almost the same signature, in
    BIC order (best first), the one to name by the marginality principle: the single term
    from which every other one descends (lib_dTdt among lib_dTdt, lib_dTdt_dV, lib_dTdt_dV2),
    a term and its element-lagged variant counting as one, the better fit standing for both.
    None when the look-alikes are genuinely different terms (k2_quadratic and
    scale_asymmetry; lib_dTdt and warmup_drift): more than one of them descends from none of
    the others."""
    best_variant: dict[str, str] = {}
    for e in look_alikes:
        best_variant.setdefault(instant_form(e), e)
    group = set(best_variant)
    roots = [e for e in best_variant if not ancestors(e) & group]
    return best_variant[roots[0]] if len(roots) == 1 else None
