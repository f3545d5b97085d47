"""Generic terms a simulated part may carry beyond the catalog effects (the bench's own code).

A part's `effects:` map in config/sim/*.yaml takes, besides the catalog ids, the generic
terms of an extended model.yaml (`station discrepancy` writes them) under the same ids and
parameters, so a learned model can be copied into a part entry as it is:

    effects:
      lib_dTdt: {coeff: 0.9}                              # bias = 0.9 * d(die temp)/dt
      lib_w_dT_dV: {coeff: 2.0e-4}                        # bias = 2e-4 * w * dT * dV
      lib_angleh2: {amplitude_dps: 0.02, phase_deg: 40}   # bias = 0.02 cos(2 angle - 40 deg)

The id spells the term: `lib_` + factors joined by `_`, each factor a token with an optional
power 2 or 3; at most third order, each factor once. Tokens: `w` (rate, deg/s), `dT` (die
temperature - 25 C), `dTdt` (d(die temperature)/dt, C/s), `dTdir` (the direction of the die
temperature's history, -1 cooled .. +1 heated: the state of a play operator of half-width
`DIRECTION_HALF_WIDTH_C` on the die temperature), `dTdtlag<tau>s` (the rate of a
temperature that follows the die first order with time constant tau, 1 to 100000 s, set to
the die's at power-on: (die - that temperature) / tau), `dV` (supply - 5.0 V), `sgnw`
(sign of the rate), `absw` (|rate|), `exp<tau>s` (exp(-t/tau), t since power-on, tau 1 to
100000 s). `lib_angleh<k>` (k 1 to 4) is `amplitude_dps * cos(k * angle - phase_deg)` of
the table angle. The term is added to the part's deterministic output (before its sensor
lag, after the catalog effects).

This module is the bench's physics, written apart from the station's model
(procedures/model/library.py), as the rest of the bench is.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

PREFIX = "lib_"
MAX_TERMS = 16  # generic terms one part may carry
MAX_HARMONIC = 4
DIRECTION_HALF_WIDTH_C = 1.0  # the play operator of `dTdir`
_TOKEN = re.compile(r"^(?:(?P<f>dTdir|dTdt|dT|dV|sgnw|absw|w)(?P<p>[23]?)|exp(?P<tau>\d+)s"
                    r"|dTdtlag(?P<lag>\d+)s)$")
_HARMONIC = re.compile(r"^angleh(?P<k>[1-9])$")
PRODUCT_PARAMS = frozenset({"coeff"})
HARMONIC_PARAMS = frozenset({"amplitude_dps", "phase_deg"})


def is_generic(effect_id: str) -> bool:
    return effect_id.startswith(PREFIX)


@dataclass(frozen=True)
class PartInputs:
    """What a generic term may depend on, at the samples of one output chunk."""

    rate_dps: FloatArray
    angle_deg: FloatArray
    dtemp_c: FloatArray
    temp_rate_c_per_s: float
    dsupply_v: float
    since_power_on_s: FloatArray
    temp_direction: float = 0.0  # -1 cooled .. +1 heated (`dTdir`)
    lagged_rates: Mapping[float, float] | None = None  # tau -> C/s (`dTdtlag<tau>s`)


@dataclass(frozen=True)
class GenericTerm:
    effect_id: str
    factors: tuple[tuple[str, int], ...]  # (token, power); empty for a harmonic
    harmonic: int  # k of an angle harmonic, 0 for a product
    coeff: float  # product coefficient, or the harmonic's amplitude (deg/s)
    phase_rad: float = 0.0

    def value_dps(self, x: PartInputs) -> FloatArray:
        if self.harmonic:
            return self.coeff * np.cos(self.harmonic * np.radians(x.angle_deg) - self.phase_rad)
        out = np.full(x.rate_dps.shape, self.coeff)
        for tok, power in self.factors:
            out = out * _factor(tok, x) ** power
        return out


def _factor(tok: str, x: PartInputs) -> FloatArray:
    if tok.startswith("exp"):
        return np.exp(-np.maximum(x.since_power_on_s, 0.0) / float(tok[3:-1]))
    n = x.rate_dps.shape
    if tok.startswith("dTdtlag"):
        return np.full(n, (x.lagged_rates or {}).get(float(tok[7:-1]), 0.0))
    values = {
        "w": x.rate_dps,
        "dT": x.dtemp_c,
        "dTdt": np.full(n, x.temp_rate_c_per_s),
        "dTdir": np.full(n, x.temp_direction),
        "dV": np.full(n, x.dsupply_v),
        "sgnw": np.sign(x.rate_dps),
        "absw": np.abs(x.rate_dps),
    }
    return values[tok]


def parse_id(effect_id: str) -> tuple[tuple[tuple[str, int], ...], int]:
    """(factors, harmonic) of a generic term id; ValueError saying what is allowed."""
    if not is_generic(effect_id):
        raise ValueError(f"{effect_id!r} is not a generic term (ids start with {PREFIX!r})")
    body = effect_id[len(PREFIX) :]
    if m := _HARMONIC.match(body):
        k = int(m["k"])
        if k > MAX_HARMONIC:
            raise ValueError(f"term {effect_id!r}: angle harmonics 1 to {MAX_HARMONIC} only")
        return (), k
    factors: list[tuple[str, int]] = []
    for tok in body.split("_"):
        m = _TOKEN.match(tok)
        if m is None:
            raise ValueError(
                f"term {effect_id!r}: unknown factor {tok!r}; factors are w, dT, dTdt, dTdir, "
                "dV, sgnw, absw with an optional power 2 or 3, exp<tau>s, dTdtlag<tau>s, or a "
                "term angleh<k>"
            )
        if m["tau"] is not None or m["lag"] is not None:
            if not 1 <= int(m["tau"] or m["lag"]) <= 100_000:
                raise ValueError(f"term {effect_id!r}: time constant must be 1 to 100000 s")
            factors.append((tok, 1))
        else:
            factors.append((m["f"], int(m["p"] or 1)))
    if sum(p for _, p in factors) > 3 or len({t for t, _ in factors}) != len(factors):
        raise ValueError(f"term {effect_id!r}: at most third order, each factor once")
    return tuple(factors), 0


def check_term(effect_id: str, params: Mapping[str, float]) -> None:
    """ValueError naming the term and the parameters it takes, if `params` do not fit."""
    _, harmonic = parse_id(effect_id)
    wanted = HARMONIC_PARAMS if harmonic else PRODUCT_PARAMS
    if set(params) != wanted:
        raise ValueError(
            f"term {effect_id!r} takes exactly the parameter(s) {sorted(wanted)}, "
            f"got {sorted(params)}"
        )


def build_terms(effects: Mapping[str, Mapping[str, float]]) -> tuple[GenericTerm, ...]:
    """The generic terms among a part's effects (catalog ids are left to the part model)."""
    out = []
    for effect_id, params in effects.items():
        if not is_generic(effect_id):
            continue
        check_term(effect_id, params)
        factors, harmonic = parse_id(effect_id)
        if harmonic:
            out.append(
                GenericTerm(
                    effect_id,
                    factors,
                    harmonic,
                    float(params["amplitude_dps"]),
                    math.radians(float(params["phase_deg"])),
                )
            )
        else:
            out.append(GenericTerm(effect_id, factors, 0, float(params["coeff"])))
    return tuple(out)


def total_dps(terms: tuple[GenericTerm, ...], x: PartInputs) -> FloatArray:
    out = np.zeros(x.rate_dps.shape)
    for term in terms:
        out = out + term.value_dps(x)
    return out


def lag_taus(terms: tuple[GenericTerm, ...]) -> tuple[float, ...]:
    """The time constants of the lagged rates (`dTdtlag<tau>s`) the terms use."""
    return tuple(sorted({float(tok[7:-1]) for t in terms for tok, _ in t.factors
                         if tok.startswith("dTdtlag")}))
