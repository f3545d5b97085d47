"""Parsimony between look-alikes (issue 29): where a main effect and an interaction that
descends from it explain the gap about equally well with almost the same signature, the main
effect is named (the marginality principle, marginality.parsimonious) instead of refusing
both as not separable; look-alikes of which none descends from another (k2_quadratic and
scale_asymmetry, tests/model/test_discrepancy_synth.py; lib_dTdt and lib_dT2 below) stay not
separable.

The record: a bias in proportion to d(die temperature)/dt (tests/model/synth_gyro.py
`bias_temperature_rate`) on RAMPED with three supplies, where the die's temperature moves
only at the outer supplies, so d(die temperature)/dt x (supply - 5 V)^2 is 0.0625 x
d(die temperature)/dt: signature correlation 1.00, BIC 4.5 above lib_dTdt's."""

from __future__ import annotations

from dataclasses import replace

import pytest
from helpers_model import as_trajectory
from synth_gyro import RAMPED, generate, realistic_part

from procedures.model import discrepancy as d
from procedures.model import marginality
from procedures.model.blocks import make_blocks
from procedures.model.fit import Fitter
from procedures.model.gyro_model import first_order_model
from procedures.model.output import result_to_json

THREE_SUPPLIES = replace(RAMPED, supplies_v=(4.75, 5.0, 5.25))
SEED = 21


def test_the_main_effect_of_look_alikes_is_the_one_named() -> None:
    assert marginality.parsimonious(["lib_dTdt_dV", "lib_dTdt"]) == "lib_dTdt"
    assert marginality.parsimonious(["lib_dTdt", "lib_dTdt_dV2", "lib_dTdt_dV"]) == "lib_dTdt"
    assert marginality.parsimonious(["scale_temperature", "bias_temperature"]) == (
        "bias_temperature")
    assert marginality.parsimonious(["lib_w_dTdir", "lib_dTdir"]) == "lib_dTdir"
    assert {"lib_dTdt_dV", "lib_dV2", "lib_dTdt", "bias_supply"} == set(
        marginality.ancestors("lib_dTdt_dV2"))


def test_a_term_and_its_element_lagged_variant_count_as_one_the_better_fit_named() -> None:
    """lib_w_dTdt and lib_w_dTdtlag20s: the same variables, the die's rate at the sensor or
    at an element 20 s behind it; the first given (the lower BIC) is named, and a variant
    descends from the other's main effect as the term itself does."""
    assert marginality.instant_form("lib_w_dTdtlag20s") == "lib_w_dTdt"
    assert marginality.instant_form("lib_w_dTdt") == "lib_w_dTdt"
    assert marginality.parsimonious(["lib_w_dTdtlag20s", "lib_w_dTdt"]) == "lib_w_dTdtlag20s"
    assert marginality.parsimonious(["lib_w_dTdt", "lib_w_dTdtlag20s"]) == "lib_w_dTdt"
    assert marginality.parsimonious(["lib_dTdtlag20s", "lib_dTdt", "lib_dTdt_dV"]) == (
        "lib_dTdtlag20s")
    assert marginality.main_effects("lib_w_dTdtlag20s") == ("lib_dTdtlag20s",)
    assert marginality.parsimonious(["lib_w_dTdtlag20s", "warmup_drift"]) is None


def test_genuinely_different_look_alikes_stay_not_separable() -> None:
    assert marginality.parsimonious(["k2_quadratic", "scale_asymmetry"]) is None
    assert marginality.parsimonious(["lib_dTdt", "warmup_drift"]) is None
    assert marginality.parsimonious(["lib_dTdt", "lib_dTdt_dV", "lib_dT2"]) is None


@pytest.fixture(scope="module")
def candidates():
    part = realistic_part().with_effect("bias_temperature_rate")
    traj = as_trajectory(generate(part, SEED, THREE_SUPPLIES))
    blocks = make_blocks(traj)
    noise, _ = d.measure_record_noise(traj, blocks, first_order_model())
    fitter = Fitter(traj, blocks, noise)
    current = fitter.fit(first_order_model())
    tests, _ = d.test_candidates(fitter, current, d.DEFAULT_ALPHA)
    judged = {c.effect: c for c in d._judge(tests, current, blocks, noise)}  # noqa: SLF001
    return fitter, current, blocks, judged


def test_choose_names_the_main_effect_or_refuses_genuinely_different_terms(candidates
                                                                           ) -> None:
    """On the same fits: lib_dTdt with its look-alike interaction lib_dTdt_dV2 (held back
    by nothing, as when its direct main effects do not explain the gap): lib_dTdt named,
    the interaction reported as passed over; with lib_dT2 made as good a look-alike
    (correlation 0.97, its BIC set within 10), the three are not separable."""
    fitter, current, blocks, judged = candidates
    main, inter = judged["lib_dTdt"], replace(judged["lib_dTdt_dV2"], waits_for=())
    assert main.named_candidate and inter.named_candidate
    assert d._signature_correlation(current, main.fit, inter.fit) >= d.SEPARABLE_CORRELATION
    assert abs(inter.bic - main.bic) < d.SEPARABLE_DELTA_BIC
    for order in ([main, inter], [inter, main]):  # whichever has the lower BIC
        chosen = d._choose(fitter, current, order, blocks)  # noqa: SLF001
        assert isinstance(chosen, d._Chosen)  # noqa: SLF001
        assert chosen.best.effect == "lib_dTdt"
        assert chosen.preferred_over == ("lib_dTdt_dV2",)
    other = replace(judged["lib_dT2"], waits_for=(), bic=main.bic + 1.0)
    assert d._signature_correlation(current, main.fit, other.fit) >= d.SEPARABLE_CORRELATION
    refused = d._choose(fitter, current, [main, other, inter], blocks)  # noqa: SLF001
    assert isinstance(refused, dict)
    assert set(refused["effects"]) == {"lib_dTdt", "lib_dT2", "lib_dTdt_dV2"}


def test_the_iteration_says_which_look_alike_the_main_effect_was_named_before(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Through the workflow, with the interactions' waiting switched off (so that the
    look-alike interaction is a candidate as well): lib_dTdt is named first, its evidence
    names lib_dTdt_dV2 as passed over by the marginality rule, in the JSON too."""
    monkeypatch.setattr(marginality, "waiting_for", lambda *_: ())
    part = realistic_part().with_effect("bias_temperature_rate")
    res = d.run_discrepancy(as_trajectory(generate(part, SEED, THREE_SUPPLIES)),
                            first_order_model())
    assert res.effects_added[:1] == ["lib_dTdt"], (res.effects_added, res.not_separable)
    evidence = res.iterations[0].evidence
    assert "lib_dTdt_dV2" in evidence["preferred_over"]
    assert evidence["rule"].startswith("marginality")
    assert result_to_json(res)["iterations"][0]["evidence"]["preferred_over"] == (
        evidence["preferred_over"])
    assert res.iterations[0].regressors == ("temperature_rate",)
