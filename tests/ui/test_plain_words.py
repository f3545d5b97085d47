"""Plain words and the message catalog (station/ui/plain_words.py, station/ui/catalog.py)."""

from __future__ import annotations

import importlib.metadata
import re
from pathlib import Path
from typing import Any

import pytest

from procedures.runtime.limits import LIMIT_NAMES
from procedures.steps.registry import STEP_GROUP
from station.ui import catalog, plain_words
from station.ui.plain_words import failure_phrase, step_phrases

STATIC = Path(catalog.__file__).parent / "static"


def render(phrase: Any, language: str = "en") -> str:
    """The page's t(): a phrase with its nested phrases, in one language."""
    messages = catalog.load(language)
    text = messages[phrase["key"]]  # a KeyError here is a key missing from the catalog

    def fill(m: re.Match[str]) -> str:
        value = phrase["params"].get(m.group(1))
        if isinstance(value, dict):
            return render(value, language)
        text = str(value or "")
        if re.fullmatch(r"[-+]?\d+\.\d+", text):  # as the page writes a decimal number
            return text.replace(".", messages["number.decimal"])
        return text

    return re.sub(r" +", " ", re.sub(r"\{(\w+)\}", fill, text)).strip()


def words(phrases: list[Any], language: str = "en") -> str:
    return ", ".join(render(p, language) for p in phrases)


def test_steps_and_conditions_in_plain_words() -> None:
    assert words(step_phrases("thermal", "T45_V5.25")) == "Heating to 45 C, supply 5.25 V"
    assert words(step_phrases("thermal", "T-10_V4.75")) == "Cooling to -10 C, supply 4.75 V"
    assert words(step_phrases("thermal", "T25_V5")) == "Settling at 25 C, supply 5 V"
    assert (
        words(step_phrases("bias", "T45_V5.25")) == "Measuring bias at rest, at 45 C, supply 5.25 V"
    )
    assert words(step_phrases("fit", "")) == "Computing the corrections"
    assert words(step_phrases("new_step", "odd")) == "Step: new step, condition odd"
    german = words(step_phrases("thermal", "T45_V5.25"), "de")
    assert german == "Heizen auf 45 °C, Versorgung 5,25 V"
    # a long step's phase after its words; a phase without words is left out
    assert words(step_phrases("ramp_calibration", "", "cooling")) == (
        "Heating and cooling the parts while the table turns, "
        "now cooling towards the bottom of the span")
    assert words(step_phrases("ramp_calibration", "", "unheard_of")) == (
        "Heating and cooling the parts while the table turns")


def test_failure_reasons_in_plain_words() -> None:
    bias = {"name": "raw_bias_dps", "value": 14.0, "units": "deg/s", "low": -10, "high": 10}
    assert render(failure_phrase(bias)) == "Bias too high: 14.0 deg/s, limit +/-10 deg/s"
    low = {**bias, "value": -12.26}
    assert render(failure_phrase(low)) == "Bias too low: -12.3 deg/s, limit +/-10 deg/s"
    current = {"name": "supply_current_a", "value": 0.05, "units": "A", "low": 0.002, "high": 0.04}
    assert render(failure_phrase(current)) == (
        "Supply current too high: 0.0500 A, limit 0.002 to 0.04 A"
    )
    noise = {"name": "noise_arw_deg_per_sqrt_h", "value": None, "units": "deg/sqrt(h)",
             "low": None, "high": 2.5}
    assert render(failure_phrase(noise)) == (
        "Noise (angle random walk) not measured (limit at most 2.5 deg/sqrt(h))"
    )
    unknown = {"name": "my_new_thing", "value": 3.0, "units": "1", "low": None, "high": 1}
    assert render(failure_phrase(unknown)) == "my new thing too high: 3.00, limit at most 1"
    assert render(failure_phrase(bias), "de") == "Nullpunkt zu hoch: 14,0 deg/s, Grenze +/-10 deg/s"


def test_conditions_parsed() -> None:
    assert plain_words.parse_condition("T45_V5.25") == (45.0, 5.25)
    assert plain_words.parse_condition("T-10") == (-10.0, None)
    assert plain_words.parse_condition("V4.75") == (None, 4.75)
    assert plain_words.parse_condition("warm") == (None, None)


def _keys_used_by_the_page() -> set[str]:
    html = (STATIC / "operator.html").read_text()
    js = (STATIC / "operator.js").read_text() + (STATIC / "chart.js").read_text()
    keys = set(re.findall(r'data-i18n(?:-label)?="([\w.]+)"', html))
    keys |= set(re.findall(r'\bt\("([\w.]*\w)"', js))
    keys |= {k for pair in re.findall(r't\(\w+ \? "([\w.]+)" : "([\w.]+)"\)', js) for k in pair}
    keys |= {f"{prefix}.{v}" for prefix in ("verdict", "state") for v in plain_words.VERDICTS}
    keys |= {"inst.name.rate table", "inst.name.chamber", "inst.name.supply", "number.decimal"}
    return keys


def _shipped_step_types() -> set[str]:
    """The step types this package registers (pyproject's `gyrocal.steps` entry points)."""
    return {
        ep.name
        for ep in importlib.metadata.entry_points(group=STEP_GROUP)
        if ep.value.startswith("procedures.")
    }


def test_every_shipped_step_type_and_limit_reads_as_words() -> None:
    assert {"thermal", "verify_stop", "warm_up"} <= _shipped_step_types()
    for step in _shipped_step_types():
        assert plain_words.step_phrases(step, "")[0] == {"key": f"step.{step}", "params": {}}
    for name in LIMIT_NAMES:
        assert plain_words.measurement_phrase(name) == {"key": f"measure.{name}", "params": {}}
    assert plain_words.measurement_phrase("made_up_x")["key"] == "measure.other"
    assert plain_words.step_phrases("made_up", "")[0]["key"] == "step.other"


def _keys_plain_words_makes() -> set[str]:
    keys = {f"step.{s}" for s in _shipped_step_types()}
    keys |= {f"measure.{m}" for m in LIMIT_NAMES}
    keys |= {f"step.thermal.{h}" for h in ("heat", "cool", "settle")}
    keys |= {"step.other", "step.starting", "measure.other", "value"}
    keys |= {f"cond.{c}" for c in ("both", "temp", "supply", "other")}
    keys |= {f"fail.{f}" for f in ("too_high", "too_low", "out_of_limits", "not_measured")}
    keys |= {f"limit.{x}" for x in ("symmetric", "range", "max", "min", "none")}
    return keys


def test_every_key_in_every_language() -> None:
    languages = catalog.available()
    assert "en" in languages and len(languages) >= 2
    english = set(catalog.load("en"))
    needed = _keys_used_by_the_page() | _keys_plain_words_makes()
    assert needed - english == set(), "keys the screen uses but the catalog lacks"
    for language in languages:
        messages = catalog.load(language)
        assert set(messages) == english, f"{language}.json differs from en.json"
        for key, text in messages.items():
            assert text.strip(), f"{language}.json: {key} is empty"
            placeholders = set(re.findall(r"\{(\w+)\}", text))
            assert placeholders == set(re.findall(r"\{(\w+)\}", catalog.load("en")[key])), key


def test_the_page_has_no_operator_text_outside_the_catalog() -> None:
    """Every visible text in operator.html carries its catalog key."""
    html = (STATIC / "operator.html").read_text()
    body = html.split("<body", 1)[1]
    for m in re.finditer(r"<(\w+)([^>]*)>([^<]+)<", body):
        tag, attrs, text = m.groups()
        if text.strip() and text.strip() != "-" and tag not in ("script", "style"):
            assert "data-i18n" in attrs, f"<{tag}> shows {text.strip()!r} without data-i18n"


@pytest.mark.parametrize(
    ("configured", "requested", "chosen"),
    [
        (None, ["de-DE", "en"], "de"),
        (None, ["fr-FR", "de"], "de"),
        (None, ["fr-FR"], "en"),
        ("en", ["de-DE"], "en"),
        ("de", [], "de"),
        ("xx", ["de"], "en"),
    ],
)
def test_language_chosen(configured: str | None, requested: list[str], chosen: str) -> None:
    assert catalog.choose(configured, requested) == chosen


def test_accept_language_ranked() -> None:
    assert catalog.accept_language("en;q=0.5, de-DE, fr;q=0.8") == ["de-DE", "fr", "en"]
    with pytest.raises(ValueError, match="no message catalog"):
        catalog.load("xx")
