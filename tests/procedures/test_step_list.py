"""The step list at load: registry, loops, settings and declared measurements, with file:line;
and the old section form converted or refused."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from common.yaml_input import ConfigError
from procedures.loading.config import check_procedure_for_product, load_procedure, load_product
from procedures.loading.legacy_procedure import convert, load_section_procedure
from procedures.runtime.conditions import Condition
from procedures.steps.registry import STEP_GROUP, Declared, StepSettings, step_types
from station.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "config" / "procedures"
OLD = ROOT / "tests" / "data" / "old_form"
PRODUCT = ROOT / "config" / "products" / "gyr130.yaml"


def _write(tmp_path: Path, steps: list, name: str = "p.yaml", **top: object) -> Path:
    data = {
        "name": "t",
        "product": str(PRODUCT),
        "conditions": {"temperatures_c": [25.0, 45.0], "supplies_v": [4.75, 5.25]},
        **top,
        "steps": steps,
    }
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _error(path: Path) -> str:
    with pytest.raises(ConfigError) as info:
        load_procedure(path)
    return str(info.value)


def _line(path: Path, needle: str) -> int:
    return next(i + 1 for i, t in enumerate(path.read_text().splitlines()) if needle in t)


def test_every_registered_step_type_is_complete() -> None:
    types = step_types()
    for name in ("power_identify", "thermal", "bias", "positions", "rate_table",
                 "stop_method", "fit", "program", "verify", "verify_stop"):
        assert name in types, f"{name} not registered in {STEP_GROUP}"
    for name, cls in types.items():
        assert cls.type_name == name
        assert issubclass(cls.Settings, StepSettings)
        config = cls.Settings.model_config
        assert config.get("extra") == "forbid" and config.get("allow_inf_nan") is False, name
        for d in cls.measurements(_defaults(cls.Settings)):
            assert isinstance(d, Declared) and d.units, (name, d)


def _defaults(settings: type[StepSettings]) -> StepSettings:
    """A Settings instance (required fields filled with a plausible value)."""
    needed = {k: [50.0, -50.0] for k, f in settings.model_fields.items() if f.is_required()}
    return settings.model_validate(needed)


def test_unknown_step_type_names_file_line_and_the_known_ones(tmp_path: Path) -> None:
    path = _write(tmp_path, [{"step": "power_identify"}, {"step": "biass"}])
    msg = _error(path)
    assert f"{path}:{_line(path, 'biass')}: steps.1.step: unknown step type 'biass'" in msg
    assert "known: bias, " in msg and " fit, " in msg


def test_unknown_setting_and_bad_value_name_the_entry(tmp_path: Path) -> None:
    path = _write(tmp_path, [{"step": "power_identify"},
                             {"for_each": "condition",
                              "steps": [{"step": "thermal"},
                                        {"step": "bias", "dwel_s": 30, "wander_factor": -1}]}])
    msg = _error(path)
    assert f"{path}:{_line(path, 'dwel_s')}: field steps.1.steps.1.dwel_s (step bias): " \
        "unknown field; allowed here: allan, dwell_s" in msg
    assert f"{path}:{_line(path, 'wander_factor')}: field steps.1.steps.1.wander_factor " \
        "(step bias): Input should be greater than or equal to 0" in msg


def test_loops_are_checked(tmp_path: Path) -> None:
    bad = [
        ({"for_each": "temperature", "steps": [{"step": "bias"}]},
         "for_each: 'temperature': only 'condition' is known"),
        ({"repeat": 0, "steps": [{"step": "bias"}]}, "repeat: 0: give a whole number 1..100"),
        ({"repeat": "twice", "steps": [{"step": "bias"}]}, "repeat: 'twice'"),
        ({"repeat": 2}, "repeat loop without 'steps:'"),
        ({"repeat": 2, "steps": []}, "expected a non-empty list of steps"),
        ({"repeat": 2, "step": "bias"}, "give exactly one of step, for_each, repeat"),
        ({"for_each": "condition", "steps": [{"for_each": "condition",
                                             "steps": [{"step": "bias"}]}]},
         "cannot be nested"),
        ({"repeat": 2, "steps": [{"step": "bias"}], "times": 3}, "unknown field 'times'"),
    ]
    for i, (loop, expected) in enumerate(bad):
        path = _write(tmp_path, [{"step": "power_identify"}, loop], name=f"l{i}.yaml")
        msg = _error(path)
        assert expected in msg and f"{path}:" in msg, (loop, msg)


def test_repeat_and_for_each_expand_with_their_place(tmp_path: Path) -> None:
    path = _write(tmp_path, [
        {"step": "power_identify"},
        {"for_each": "condition", "steps": [
            {"step": "thermal"}, {"step": "bias", "dwell_s": 5},
            {"repeat": 2, "steps": [{"step": "stop_method", "timeout_s": 120}]}]},
        {"step": "fit", "source": "stop_method"},
    ])
    proc, _ = load_procedure(path)
    plan = proc.plan(start_temp_c=45.0)  # the chamber is nearest 45 C: start there
    names = [(s.name, s.condition, s.place.repeat) for s in plan]
    assert names[:6] == [("power_identify", "", 0), ("thermal", "T45_V4.75", 0),
                         ("bias", "T45_V4.75", 0), ("stop_method", "T45_V4.75", 0),
                         ("stop_method", "T45_V4.75", 1), ("thermal", "T45_V5.25", 0)]
    assert len(plan) == 1 + 4 * 4 + 1
    stops = [s for s in plan if s.name == "stop_method"]
    assert all(s.policy.timeout_s == 120 for s in stops)
    biases = [s for s in plan if s.name == "bias"]
    assert [b.place.condition_index for b in biases] == [0, 1, 2, 3]
    assert biases[1].place.previous == Condition(45.0, 4.75)
    assert biases[0].settings.dwell_s == 5


def test_a_step_needs_what_an_earlier_step_provides(tmp_path: Path) -> None:
    path = _write(tmp_path, [{"step": "power_identify"}, {"step": "program"},
                             {"step": "fit", "source": "stop_method"}])
    msg = _error(path)
    assert f"{path}:{_line(path, 'step: program')}: steps.1: step program needs fit from an " \
        "earlier step (fit, ramp_calibration)" in msg


def _check(tmp_path: Path, path: Path, product_text: str) -> list[str]:
    product_path = tmp_path / "product.yaml"
    product_path.write_text(product_text)
    proc, loaded = load_procedure(path)
    product, product_file = load_product(product_path)
    return check_procedure_for_product(proc, loaded, product, product_file)


def test_a_measurement_without_a_product_limit_is_refused_unless_informational(
    tmp_path: Path,
) -> None:
    text = PRODUCT.read_text()
    without = "\n".join(t for t in text.splitlines()
                        if not t.strip().startswith("bias_instability_deg_per_h:"))
    shipped = SHIPPED / "eol-rate-table.yaml"
    with pytest.raises(ConfigError) as info:
        _check(tmp_path, shipped, without)
    assert f"{shipped}:{_line(shipped, 'step: bias')}: step bias (steps.1.steps.1) measures " \
        "'bias_instability_deg_per_h' but the product file" in str(info.value)
    data = yaml.safe_load(shipped.read_text())
    data["product"] = str(PRODUCT)
    data["steps"][1]["steps"][1]["informational"] = ["bias_instability_deg_per_h"]
    path = tmp_path / "informational.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    assert _check(tmp_path, path, without) == []


def test_a_product_limit_never_measured_is_listed(tmp_path: Path) -> None:
    warnings = _check(tmp_path, SHIPPED / "eol-stop-method.yaml", PRODUCT.read_text())
    never = sorted(w.split("'")[1] for w in warnings)
    assert never == ["asymmetry", "nonlinearity_pct_fs", "raw_scale_error"]
    assert _check(tmp_path, SHIPPED / "eol-rate-table.yaml", PRODUCT.read_text()) == []


def test_the_old_section_form_is_refused_with_the_command_that_converts_it() -> None:
    path = OLD / "eol-rate-table.yaml"
    msg = _error(path)
    assert msg.startswith(f"{path}:1: this procedure is in the old section form")
    assert f"station procedure convert {path} -o NEW.yaml" in msg


@pytest.mark.parametrize("name", ["eol-rate-table.yaml", "eol-stop-method.yaml"])
def test_the_shipped_files_are_their_old_form_converted(name: str) -> None:
    """Same step types, places, settings and policies as the old file converted."""
    old, _ = load_section_procedure(OLD / name)
    converted = convert(old)
    converted["product"] = str(PRODUCT)
    shipped, _ = load_procedure(SHIPPED / name)
    from procedures.loading.config import ProcedureConfig

    again = ProcedureConfig.model_validate(converted)
    assert [(e.type_name, e.settings, e.policy, e.path) for e in again.entries()] == [
        (e.type_name, e.settings, e.policy, e.path) for e in shipped.entries()
    ]
    for key in ("conditions", "chamber", "stream", "output_rate_hz"):
        assert getattr(again, key) == getattr(shipped, key), key


def test_station_procedure_convert(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    old = tmp_path / "old.yaml"
    old.write_text((OLD / "eol-stop-method.yaml").read_text().replace(
        "../../../config/products/gyr130.yaml", str(PRODUCT)))
    new = tmp_path / "new.yaml"
    assert main(["procedure", "convert", str(old), "-o", str(new)]) == 0
    proc, _ = load_procedure(new)
    assert [e.type_name for e in proc.entries()] == [
        "power_identify", "thermal", "bias", "stop_method", "fit", "program", "verify_stop"]
    assert proc.settings_of("stop_method").repeats == 3
    assert proc.settings_of("thermal").stability_timeout_s == 2400
    capsys.readouterr()
    assert main(["procedure", "convert", str(new)]) == 2  # already a list
    assert "already a list of steps" in capsys.readouterr().err
    assert main(["procedure", "convert", str(old)]) == 0  # printed
    assert "step: verify_stop" in capsys.readouterr().out


def test_docs_hold_every_step_type_as_generated() -> None:
    """docs/procedures.md's step tables are the registry's (regenerate with
    `python -m procedures.steps.reference docs/procedures.md`)."""
    from procedures.steps.reference import BEGIN, END, reference_markdown

    doc = (ROOT / "docs" / "procedures.md").read_text()
    block = BEGIN + doc.split(BEGIN, 1)[1].split(END, 1)[0] + END + "\n"
    assert block == reference_markdown()
    for name, cls in step_types().items():
        section = block.split(f"### `{name}`\n", 1)[1].split("\n### ", 1)[0]
        assert all(f"| `{f}` |" in section for f in cls.Settings.model_fields), name
