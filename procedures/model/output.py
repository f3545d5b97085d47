"""The discrepancy result as the pinned JSON (keys listed in docs/discrepancy.md), plus added
detail keys."""

from __future__ import annotations

import math
from typing import Any

from procedures.model import effects as fx
from procedures.model.discrepancy import CandidateTest, DiscrepancyResult
from procedures.model.model_io import model_to_dict
from procedures.model.residuals import BinSummary


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


def _clean(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if isinstance(obj, float):
        return _num(obj)
    if hasattr(obj, "item"):
        return _clean(obj.item())
    return obj


def _bins(summary: dict[str, list[BinSummary]]) -> dict[str, list[dict[str, Any]]]:
    return {
        k: [
            {
                "bin": b.label,
                "n_blocks": b.n_blocks,
                "duration_s": b.duration_s,
                "mean_dps": b.mean_dps,
                "rms_dps": b.rms_dps,
                "floor_dps": b.floor_dps,
                "z": b.z,
            }
            for b in v
        ]
        for k, v in summary.items()
    }


def _candidate(c: CandidateTest) -> dict[str, Any]:
    return {
        "effect": c.effect,
        "regressors": list(fx.check_effect_id(c.effect).regressors),
        "delta_chi2": c.delta_chi2,
        "f_statistic": c.f_statistic,
        "p_value": c.p_value,
        "p_holm": c.p_holm,
        "delta_bic": c.delta_bic,
        "significant": c.significant,
        "parameters": c.parameters,
        "shrinks_gap": c.shrinks_gap,
        "waits_for": list(c.waits_for),
    }


def _couples(effect_id: str) -> dict[str, str]:
    """`couples: "y <- x"` for a term coupling the axes of a three-axis part, else nothing."""
    pair = fx.check_effect_id(effect_id).couples
    return {"couples": f"{pair[0]} <- {pair[1]}"} if pair else {}


def result_to_json(res: DiscrepancyResult) -> dict[str, Any]:
    """Pinned keys: gap_initial_dps, noise_floor_dps, iterations (effect, gap_before_dps,
    gap_after_dps, parameters, evidence), effects_added, gap_final_dps."""
    out: dict[str, Any] = {
        "gap_initial_dps": res.gap_initial_dps,
        "noise_floor_dps": res.noise_floor_dps,
        "iterations": [
            {
                "effect": it.effect,
                "gap_before_dps": it.gap_before_dps,
                "gap_after_dps": it.gap_after_dps,
                "parameters": it.parameters,
                "evidence": it.evidence,
                "regressors": list(it.regressors),
                "formula": it.formula,
                "candidates": [_candidate(c) for c in it.candidates],
                **_couples(it.effect),
            }
            for it in res.iterations
        ],
        "effects_added": res.effects_added,
        "gap_final_dps": res.gap_final_dps,
        # detail beyond the pinned keys
        "gap_final_over_floor": res.gap_final_dps / res.noise_floor_dps,
        "not_separable": list(res.not_separable),
        "not_identifiable": list(res.not_identifiable),
        "final_candidates": [_candidate(c) for c in res.last_candidates],
        "alpha_familywise": res.alpha,
        "noise": {
            "white_dps_rt_s": res.noise.white_dps_rt_s,
            "arw_deg_per_sqrt_h": res.noise.arw_deg_per_sqrt_h,
            "flat_dps": res.noise.floor_dps,
            "bias_instability_deg_per_h": res.noise.bias_instability_deg_per_h,
            "rrw_dps_per_rt_s": res.noise.rrw_dps_per_rt_s,
            "rrw_deg_per_h_per_sqrt_h": res.noise.rrw_deg_per_h_per_sqrt_h,
            "slow_noise_from": res.noise.slow_from,
            "allan_tau_s": res.noise.tau_s.tolist(),
            "allan_adev_dps": res.noise.adev_dps.tolist(),
        },
        "n_blocks": res.blocks.count,
        "initial_model": model_to_dict(res.initial_model),
        "final_model": model_to_dict(res.final_model),
        "residuals_initial": _bins(res.summary_initial),
        "residuals_final": _bins(res.summary_final),
        "notes": list(res.notes),
        "unexplained_structure_remains": res.unexplained_remains,
        "unexplained_structure_message": res.unexplained_message or None,
        "unexplained_structure": [
            {
                "variable": t.variable,
                "f_statistic": t.f_statistic,
                "p_value": t.p_value,
                "delta_chi2": t.delta_chi2,
                "q": t.q,
                "terms": list(t.terms),
            }
            for t in res.unexplained
        ],
        "noise_nuisance_terms": list(res.noise_nuisance_terms),
    }
    return _clean(out)
